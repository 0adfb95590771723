"""The IDs of the rows of an adjustment's blocks: from the labels `adjust` was given
(`parameter_labels` names: "camera C1 c", "image img03 X0", "point 12 X", "mount rig/C2 X0",
"board board kx"; `adjust_project`
passes the project's) or, without labels, the row numbers (cameras numbered over all models in
`flatten` order: models by name, then rows)."""

import dataclasses
from collections.abc import Hashable

import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._problem._parameters import (
    IMAGE_PARAMETER_NAMES,
    MOUNT_PARAMETER_NAMES,
    POINT_PARAMETER_NAMES,
    WARP_PARAMETER_NAMES,
    Parameters,
    flatten,
    positions_of,
)


@dataclasses.dataclass(frozen=True)
class Ids:
    """The ID of every row of the unknowns' blocks: `cameras` {model: (id per row)},
    `images`, `points`, `mounts` and `boards` (id per row; `images` are frames where there
    are rigs, `mounts` () without rigs, `boards` the rows of the warp block, () without)."""

    cameras: dict[str, tuple[Hashable, ...]]
    images: tuple[Hashable, ...]
    points: tuple[Hashable, ...]
    mounts: tuple[Hashable, ...] = ()
    boards: tuple[Hashable, ...] = ()

    def block(self, name: str) -> tuple[Hashable, ...]:
        """The IDs of the block called "images", "points", "mounts" or "cameras/<model>"."""
        if name.startswith("cameras/"):
            return self.cameras[name.removeprefix("cameras/")]
        return getattr(self, name)


def index_ids(params: Parameters) -> Ids:
    """Row numbers as IDs; cameras numbered over all models in `flatten` order."""
    cameras, start = {}, 0
    for model in sorted(params.cameras):
        n = int(np.shape(params.cameras[model])[0])
        cameras[model], start = tuple(range(start, start + n)), start + n
    mounts = () if params.mounts is None else tuple(range(np.shape(params.mounts)[0]))
    boards = () if params.warp is None else tuple(range(np.shape(params.warp)[0]))
    return Ids(cameras, tuple(range(np.shape(params.images)[0])),
               tuple(range(np.shape(params.points)[0])), mounts, boards)


def ids_from_labels(params: Parameters, labels: list[str]) -> Ids:
    """The IDs in `labels` (one per scalar unknown in `flatten` order, as `parameter_labels`
    writes them: "<kind> <id> <name>"). `ValueError` naming the first label of another form
    or a repeated ID."""
    positions = positions_of(params)
    if len(labels) != flatten(params).size:
        raise ValueError(f"labels: {len(labels)} names for {flatten(params).size} unknowns")

    def block(kind: str, rows: np.ndarray, first_name: str) -> tuple[str, ...]:
        ids = []
        for position in np.asarray(rows).reshape(len(rows), -1)[:, 0].tolist():
            label = labels[position]
            prefix, suffix = f"{kind} ", f" {first_name}"
            if not (label.startswith(prefix) and label.endswith(suffix)
                    and len(label) > len(prefix) + len(suffix)):
                raise ValueError(
                    f"labels[{position}] = {label!r}: expected {prefix}<id>{suffix}"
                    " (the form of jaxba.parameter_labels)")
            ids.append(label[len(prefix):-len(suffix)])
        if len(set(ids)) < len(ids):
            repeated = next(i for i in ids if ids.count(i) > 1)
            raise ValueError(f"labels: the {kind} ID {repeated!r} names two rows")
        return tuple(ids)

    cameras = {
        model: block("camera", rows, CAMERA_MODELS[model].parameter_names[0])
        for model, rows in positions.cameras.items()
    }
    everyone = [cid for ids in cameras.values() for cid in ids]
    if len(set(everyone)) < len(everyone):
        raise ValueError("labels: a camera ID names cameras of two models")
    mounts = () if positions.mounts is None else block(
        "mount", positions.mounts, MOUNT_PARAMETER_NAMES[0])
    boards = () if positions.warp is None else block(
        "board", positions.warp, WARP_PARAMETER_NAMES[0])
    return Ids(cameras, block("image", positions.images, IMAGE_PARAMETER_NAMES[0]),
               block("point", positions.points, POINT_PARAMETER_NAMES[0]), mounts, boards)
