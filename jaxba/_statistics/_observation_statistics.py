"""Per-observation statistics of an adjustment, by row numbers: residuals v, redundancy
numbers r, normalised residuals w, data-snooping removals and outlier flags of every group,
the image points as one table, and the outliers largest |w| first.

The reports (`jaxba._report._collect`) and the result's tables by ID
(`jaxba._statistics._by_id`) both read them here. Jax is called only to evaluate the residual
of an observation removed by data snooping (its v at the final solution).
"""

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._problem._observations import AbstractObservationGroup, host_query
from ._ids import Ids


@dataclasses.dataclass(frozen=True)
class GroupStatistics:
    """Per-entry statistics of one observation group, arrays shaped like its residuals (n, k).

    `observed`: a real observation before data snooping; `removed`: switched off by data
    snooping; `v`: observed - computed in the observation's units (NaN where not observed;
    removed entries: the residual at the final solution); `r`, `w`: redundancy numbers and
    normalised residuals (NaN where unknown; a removed entry keeps the w it was rejected with);
    `outlier`: removed, or |w| above the critical value.
    """

    group: AbstractObservationGroup
    kind: str
    observed: np.ndarray
    removed: np.ndarray
    v: np.ndarray
    r: np.ndarray
    w: np.ndarray
    outlier: np.ndarray


@dataclasses.dataclass(frozen=True)
class ImagePointRows:
    """The image points of all image-point groups, sorted by image (file order within one).

    `group` (n,): the row's group in `result.problem.groups`, `row` (n,) its row there;
    `camera`, `image`, `point`
    (n,): rows of the camera (within its group's model), image and point blocks; `mount`
    (n,) the row of the mounts block (-1 for groups without rigs); `xy`, `v`
    (n, 2) in the image units of the row's camera model; `r`, `w` (n, 2) NaN where unknown;
    `removed`: rejected by data snooping (v at the final solution, which did not use it);
    `outlier`: removed, or |w| above the critical value on either coordinate.
    """

    group: np.ndarray
    row: np.ndarray
    camera: np.ndarray
    image: np.ndarray
    point: np.ndarray
    mount: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    r: np.ndarray
    w: np.ndarray
    removed: np.ndarray
    outlier: np.ndarray


@dataclasses.dataclass(frozen=True)
class Outlier:
    """A used observation whose |w| exceeds the critical value: `group` (index into
    `result.problem.groups`), `row`, `coordinate` and |w|."""

    group: int
    row: int
    coordinate: int
    abs_w: float


def is_measurement(group: AbstractObservationGroup) -> bool:
    """A group of real measurements (not constraints, such as a free network's inner
    constraints: the group says which it is)."""
    return not group.constraint


def name_rows(ids: Ids, group: AbstractObservationGroup, rows) -> list[dict[str, str]]:
    """The IDs (as text) naming rows `rows` (k,) of `group` (`row_references`: image and
    point, the two points of a distance, the point, image or camera of a parameter
    observation), else the row number."""
    rows = np.asarray(rows, dtype=int)
    references = host_query(group, "row_references")
    if not references:
        return [{"row": str(row)} for row in rows.tolist()]
    columns = {
        label: [str(block_ids[k]) for k in np.asarray(index)[rows].tolist()]
        for label, block, index in references
        for block_ids in [ids.block(block)]
    }
    return [dict(zip(columns, names)) for names in zip(*columns.values())]


def with_coordinate(group: AbstractObservationGroup, ids: dict[str, str], coordinate: int) -> dict:
    """`ids` of a row and the name of its observed coordinate (none where the group names
    none: a distance)."""
    names = host_query(group, "coordinate_names")
    return {**ids, "coordinate": names[coordinate]} if names else ids


def observation_ids(ids: Ids, group, row: int, coordinate: int) -> dict[str, str]:
    """The IDs of one scalar observation: image/point/camera and coordinate, or two points."""
    return with_coordinate(group, name_rows(ids, group, [row])[0], coordinate)


def describe(ids: dict[str, str]) -> str:
    """`image img03 point 12 x`, `point_a 1 point_b 7`: IDs of an observation as text."""
    words = [f"{key} {value}" for key, value in ids.items() if key != "coordinate"]
    return " ".join(words + ([ids["coordinate"]] if "coordinate" in ids else []))


def removed_entries(result) -> list[np.ndarray]:
    """Per group of `result.problem`, (n, k) True on the entries data snooping switched off:
    the rejected coordinate, or its whole row where the group removes rows whole."""
    groups = result.problem.groups
    removed = [np.zeros(np.shape(group.stddev), dtype=bool) for group in groups]
    index = {group.name: k for k, group in enumerate(groups)}
    for rejection in result.rejections:
        k = index[rejection.group]
        columns = slice(None) if groups[k].removed_whole else rejection.coordinate
        removed[k][rejection.row, columns] = True
    return removed


def _unit_residuals(result, group: AbstractObservationGroup) -> np.ndarray:
    """observed - computed of every entry of `group` at the solution (σ set to 1)."""
    unit = eqx.tree_at(lambda g: g.stddev, group, jnp.ones_like(group.stddev))
    return np.asarray(_residuals(unit, result.parameters, result.problem.refraction),
                      dtype=float)


@eqx.filter_jit
def _residuals(group, params, refraction):
    """`group.residuals` as one program (op by op: ~50 small programs per group)."""
    return group.residuals(params, refraction)


def group_statistics(result) -> list[GroupStatistics]:
    """v, r, w and outlier flags of every entry of every observation group of `result` (an
    `Adjustment`)."""
    reliability = result.reliability
    critical = reliability.critical_value if reliability is not None else math.inf
    rejected = {(rej.group, rej.row, rej.coordinate): rej.w for rej in result.rejections}
    statistics = []
    for k, (group, removed) in enumerate(zip(result.problem.groups, removed_entries(result))):
        final = np.isfinite(np.asarray(group.stddev))
        observed = final | removed
        v = np.where(final, np.asarray(result.residuals[k], dtype=float), np.nan)
        if removed.any():
            v = np.where(removed, _unit_residuals(result, group), v)
        if reliability is not None:
            r = np.array(reliability.redundancy_numbers[k], dtype=float)
            w = np.array(reliability.normalised_residuals[k], dtype=float)
        else:
            r, w = np.full(v.shape, np.nan), np.full(v.shape, np.nan)
        r[~final], w[~final] = np.nan, np.nan
        for (name, row, coordinate), size in rejected.items():
            if name == group.name and removed[row, coordinate]:
                w[row, coordinate] = math.copysign(size, v[row, coordinate])  # w has v's sign
        with np.errstate(invalid="ignore"):
            outlier = removed | (np.abs(np.nan_to_num(w, nan=0.0)) > critical)
        statistics.append(GroupStatistics(
            group, host_query(group, "kind"), observed, removed, v, r, w, outlier & observed))
    return statistics


def image_point_rows(statistics: list[GroupStatistics]) -> ImagePointRows:
    """The image points of `group_statistics`, one row per measured point (removed ones
    included), sorted by image."""
    parts = [(k, s) for k, s in enumerate(statistics) if s.kind == "image_points"]
    image = np.concatenate([np.asarray(s.group.image) for _, s in parts] or [np.zeros(0)])
    order = None if np.all(image[1:] >= image[:-1]) else np.argsort(image, kind="stable")

    def stack(get, shape=(0,)):  # in file order, usually by image already: sorted if not
        column = np.concatenate([np.asarray(get(k, s)) for k, s in parts] or [np.zeros(shape)])
        return column if order is None else column[order]

    def index(get):  # fresh arrays: no copy where they are ints already
        return stack(get).astype(int, copy=False)

    return ImagePointRows(
        group=index(lambda k, s: np.full(len(s.v), k)),
        row=index(lambda k, s: np.arange(len(s.v))),
        camera=index(lambda k, s: s.group.camera),
        image=(image if order is None else image[order]).astype(int),
        point=index(lambda k, s: s.group.point),
        mount=index(lambda k, s: np.full(len(s.v), -1) if s.group.mount is None
                    else s.group.mount),
        xy=stack(lambda k, s: np.asarray(s.group.measured, dtype=float), (0, 2)),
        v=stack(lambda k, s: s.v, (0, 2)),
        r=stack(lambda k, s: s.r, (0, 2)),
        w=stack(lambda k, s: s.w, (0, 2)),
        removed=stack(lambda k, s: s.removed[:, 0] | s.removed[:, 1]).astype(bool, copy=False),
        outlier=stack(lambda k, s: s.outlier[:, 0] | s.outlier[:, 1]).astype(bool, copy=False),
    )


def row_parts(groups, rows: ImagePointRows, camera_ids) -> np.ndarray:
    """The part (`AbstractObservationGroup.parts`) of every row of `rows` (n,) object, e.g.
    "image_points:C1"; `groups`: the problem's groups, `camera_ids` {model: IDs}."""
    names, index = row_part_index(groups, rows, camera_ids)
    return np.asarray(names, dtype=object)[index]


def row_part_index(groups, rows: ImagePointRows, camera_ids) -> tuple[tuple[str, ...], np.ndarray]:
    """`row_parts` as (names, index (n,) of every row's part in names): the parts of the
    groups of `rows`, in the order of the groups."""
    names, index = [], np.zeros(len(rows.group), dtype=int)
    found = np.unique(rows.group).tolist()
    for k in found:
        group_names, group_index = host_query(groups[k], "parts", camera_ids)
        group_index = np.asarray(group_index, dtype=int)
        if len(found) == 1:  # every row of that group
            index = group_index[rows.row]
        else:
            here = rows.group == k
            index[here] = len(names) + group_index[rows.row[here]]
        names += group_names
    return tuple(names), index


def outliers(result, statistics: list[GroupStatistics]) -> list[Outlier]:
    """The observations the final solution used whose |w| exceeds the reliability's critical
    value, largest |w| first (none without a reliability)."""
    if result.reliability is None:
        return []
    critical = result.reliability.critical_value
    found = []
    for k, stats in enumerate(statistics):
        with np.errstate(invalid="ignore"):
            large = stats.observed & ~stats.removed & (np.abs(stats.w) > critical)
        rows, coordinates = np.nonzero(large)
        found += [Outlier(k, int(row), int(coordinate), abs(float(stats.w[row, coordinate])))
                  for row, coordinate in zip(rows, coordinates)]
    return sorted(found, key=lambda outlier: -outlier.abs_w)
