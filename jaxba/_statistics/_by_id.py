"""An adjustment's unknowns and image observations by ID (`Ids`): what `Adjustment.cameras`,
`images`, `points` and `observations` return."""

import dataclasses
from collections.abc import Callable, Iterator, Mapping

import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._models._poses import POSE_MODELS
from .._problem._parameters import (
    POINT_PARAMETER_NAMES,
    WARP_PARAMETER_NAMES,
    flatten,
    positions_of,
)
from ._ids import Ids
from ._observation_statistics import group_statistics, image_point_rows, row_parts

FREE, FIXED, WEIGHTED = "free", "fixed", "weighted"
LISTED_IDS = 5  # valid IDs named by a KeyError


@dataclasses.dataclass(frozen=True)
class Estimate:
    """One adjusted unknown: `value`, its σ (None where fixed or without precision),
    `status` "free", "fixed" or "weighted" (estimated with a prior: control, GNSS/INS, an
    IOP prior) and `unit` where known ("rad" for angles; None: the block's units)."""

    value: float
    sigma: float | None
    status: str
    unit: str | None = None


def _missing(what: str, key, keys) -> KeyError:
    listed = ", ".join(repr(k) for k in list(keys)[:LISTED_IDS])
    more = ", ..." if len(keys) > LISTED_IDS else ""
    return KeyError(f"no {what} {key!r} (there are {len(keys)}: {listed}{more})")


class _Named(Mapping):
    """A mapping by name that names the valid keys when a key is missing."""

    _what = "entry"

    def __init__(self, entries: dict):
        self._entries = entries

    def __getitem__(self, key):
        if key not in self._entries:
            raise _missing(self._what, key, list(self._entries))
        return self._entries[key]

    def __iter__(self) -> Iterator:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._entries!r})"


class Estimates(_Named):
    """The unknowns of one camera or image by parameter name (each an `Estimate`), in the
    model's order; `id` and `model` (the camera or pose model)."""

    _what = "parameter"

    def __init__(self, id, model: str, entries: dict[str, Estimate]):
        super().__init__(entries)
        self.id, self.model = id, model

    def __repr__(self) -> str:
        return f"Estimates({self.id!r}, {self.model!r}, {self._entries!r})"


class PointEstimate(Estimates):
    """An object point: X, Y, Z by name (`Estimate`s, object units), `coordinates` and
    `sigmas` (3,) NumPy (σ NaN where `Estimate.sigma` is None), `covariance` (3, 3) (rows
    of fixed coordinates 0), `status` per
    coordinate and `kind`: "control" (a coordinate fixed or weighted) or "tie"."""

    def __init__(self, id, entries: dict[str, Estimate], covariance: np.ndarray):
        super().__init__(id, "point", entries)
        self.coordinates = np.array([e.value for e in entries.values()])
        self.sigmas = np.array([np.nan if e.sigma is None else e.sigma
                                for e in entries.values()])
        self.covariance = covariance
        self.status = tuple(e.status for e in entries.values())
        self.kind = "tie" if set(self.status) == {FREE} else "control"

    def __repr__(self) -> str:
        return f"PointEstimate({self.id!r}, {self._entries!r}, kind={self.kind!r})"


class ById(_Named):
    """Cameras, images or points of an adjustment by ID; each record made when asked for."""

    def __init__(self, what: str, rows: dict, make: Callable):
        super().__init__(rows)
        self._what, self._make = what, make

    def __getitem__(self, key):
        return self._make(super().__getitem__(key))

    def __repr__(self) -> str:
        return f"ById({self._what}s: {list(self._entries)!r})"


class UnknownTables:
    """The flat values, σ and status of every unknown of an adjustment, and its records."""

    def __init__(self, result, ids: Ids):
        params, problem = result.parameters, result.problem
        self.result, self.ids = result, ids
        self.positions = positions_of(params)
        self.value = flatten(params).astype(float)
        std = flatten(result.precision.std).astype(float)
        free = flatten(problem.free).astype(bool)
        weighted = np.zeros(free.shape, dtype=bool)
        for group in problem.groups:
            weighted[group.prior_positions(self.positions)] = True
        self.status = np.where(~free, FIXED, np.where(weighted, WEIGHTED, FREE))
        self.sigma = np.where(free & np.isfinite(std), std, np.nan)

    def _estimates(self, positions: np.ndarray, names, units) -> dict[str, Estimate]:
        return {
            name: Estimate(
                float(self.value[p]), None if np.isnan(self.sigma[p]) else float(self.sigma[p]),
                str(self.status[p]), unit)
            for name, p, unit in zip(names, np.asarray(positions).tolist(), units)
        }

    def cameras(self) -> ById:
        rows = {cid: (model, row) for model, ids in self.ids.cameras.items()
                for row, cid in enumerate(ids)}

        def make(model_row):
            model, row = model_row
            names = CAMERA_MODELS[model].parameter_names
            cid = self.ids.cameras[model][row]
            positions = self.positions.cameras[model][row]
            return Estimates(cid, model, self._estimates(positions, names, [None] * len(names)))

        return ById("camera", rows, make)

    def images(self) -> ById:
        return self._poses("image", self.positions.images, self.ids.images)

    def mounts(self) -> ById:
        """The rig cameras' relative poses (none without rigs)."""
        positions = self.positions.mounts
        return self._poses("mount", np.zeros((0, 6), int) if positions is None else positions,
                           self.ids.mounts)

    def boards(self) -> ById:
        """The warped boards' kx, ky (object units; none without a warp), model "warp"."""
        positions = self.positions.warp

        def make(row):
            estimates = self._estimates(positions[row], WARP_PARAMETER_NAMES, [None] * 2)
            return Estimates(self.ids.boards[row], "warp", estimates)

        return ById("board", {bid: k for k, bid in enumerate(self.ids.boards)}, make)

    def _poses(self, what: str, positions: np.ndarray, ids) -> ById:
        pose = POSE_MODELS[self.result.problem.pose]
        names = pose.parameter_names
        units = ["rad" if name in pose.angle_names else None for name in names]

        def make(row):
            estimates = self._estimates(positions[row], names, units)
            return Estimates(ids[row], self.result.problem.pose, estimates)

        return ById(what, {iid: k for k, iid in enumerate(ids)}, make)

    def points(self) -> ById:
        def make(row):
            positions = self.positions.points[row]
            estimates = self._estimates(positions, POINT_PARAMETER_NAMES, [None] * 3)
            free = self.status[positions] != FIXED
            covariance = np.zeros((3, 3))
            if free.any():
                covariance = np.asarray(
                    self.result.precision.covariance_of(positions), dtype=float)
            return PointEstimate(self.ids.points[row], estimates, covariance)

        return ById("point", {pid: k for k, pid in enumerate(self.ids.points)}, make)


OBSERVATION_COLUMNS = ("image", "point", "camera", "group", "x", "y", "vx", "vy", "rx", "ry",
                       "wx", "wy", "removed", "outlier")


def observation_columns(result, ids: Ids) -> dict[str, np.ndarray]:
    """The image points of `result` as columns (`OBSERVATION_COLUMNS`, (n,) NumPy each), sorted
    by image as NAME.res: IDs, the group's part (`parts`: "image_points:<camera ID>"), x, y,
    vx, vy in the camera model's image units, redundancy numbers r and normalised residuals w
    (NaN where not computed), removed by data snooping, outlier (removed or |w| above the
    critical value)."""
    rows = image_point_rows(group_statistics(result))
    groups = result.problem.groups
    cameras = np.empty(len(rows.group), dtype=object)
    for k in np.unique(rows.group).tolist():  # image-point groups: one camera model each
        here = rows.group == k
        cameras[here] = np.asarray(ids.cameras[groups[k].model], dtype=object)[rows.camera[here]]
    return {
        "image": np.asarray(ids.images, dtype=object)[rows.image],
        "point": np.asarray(ids.points, dtype=object)[rows.point],
        "camera": cameras,
        "group": row_parts(groups, rows, ids.cameras),
        "x": rows.xy[:, 0], "y": rows.xy[:, 1],
        "vx": rows.v[:, 0], "vy": rows.v[:, 1],
        "rx": rows.r[:, 0], "ry": rows.r[:, 1],
        "wx": rows.w[:, 0], "wy": rows.w[:, 1],
        "removed": rows.removed, "outlier": rows.outlier,
    }


def observation_table(result, ids: Ids):
    """`observation_columns` as a pandas DataFrame where pandas is installed, else the dict."""
    columns = observation_columns(result, ids)
    try:
        import pandas
    except ImportError:
        return columns
    return pandas.DataFrame(columns)
