"""Gather an adjustment into plain NumPy tables keyed by the project's IDs.

Everything the report writers need, in report units: IOPs in the camera's units (mm based, or
pixels for pixel-unit models such as "opencv"), EOP positions and object points in object
units, angles in decimal degrees, image residuals v = observed - computed in the camera model's
image units (mm, or pixels) and, where the camera has a pixel size, in pixels; redundancy
numbers r, normalised residuals w and outlier flags of every observation; IOP correlations and
point error ellipsoids. Jax is called only to evaluate the residual of an observation removed
by data snooping (its v at the final solution) and for the covariance helpers of `_precision`.
"""

import contextlib
import dataclasses
import functools
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._io._project._build import Project
from .._models._cameras import CAMERA_MODELS
from .._problem._observations import (
    AbstractObservationGroup,
    Distances,
    ImagePoints,
    ParameterObservations,
)
from .._problem._parameters import ANGLE_NAMES, IMAGE_PARAMETER_NAMES, POINT_PARAMETER_NAMES
from .._statistics._adjustment import Adjustment
from .._statistics._derived import camera_correlation, error_ellipsoids, point_covariances

FREE, FIXED, WEIGHTED = "free", "fixed", "weighted"
TIED = "tied to"  # a camera parameter tied to another's ("tied to C1.K1"): its unknown
CONSTANT = "constant"  # a constant of the camera model (e.g. the metrology model's r0), σ 0
MM, PIXEL = "mm", "pixel"  # image units of a camera model (CAMERA_MODELS[model].image_units)
# One character per coordinate, as the σ columns of the input tables: - free, 0 fixed, w weighted.
STATUS_CODE = {FREE: "-", FIXED: "0", WEIGHTED: "w"}


@dataclasses.dataclass(frozen=True)
class ParameterTable:
    """Rows of one kind of unknown: `ids` (n,), `values` and `stds` (n, k), `status` (n, k):
    FREE, FIXED, WEIGHTED or, for a tied camera parameter, "tied to C1.K1" (a list of
    lists, or an object array of str)."""

    names: tuple[str, ...]
    ids: list[str]
    values: np.ndarray
    stds: np.ndarray
    status: list[list[str]] | np.ndarray


@dataclasses.dataclass(frozen=True)
class ImageResiduals:
    """Image residuals of all image-point groups, sorted by image (file order within one).

    `image`, `point` (n,): rows of `project.image_ids` and `project.point_ids`; `group` (n,):
    the index of the row's group in `result.problem.groups`; `image_ids`, `point_ids`,
    `camera_ids` and `units` (n,) object arrays: the IDs, the image's camera and its units.
    `xy` and `v` are (n, 2) in the image units of each row's camera model (`units`: "mm", or
    "pixel" for pixel-unit models such as "opencv"); `v_px` is v in pixels (v divided by the
    pixel size for mm rows, v itself for pixel rows; same axes as xy), NaN for mm cameras
    without a pixel size. `redundancy` (r) and `w` (normalised residuals) are (n, 2), NaN where
    unknown (no reliability computed, or the point was removed; a removed point's w is the one
    it was rejected with, on the rejected coordinate). `removed`: rejected by data snooping (its
    v is the residual at the final solution, which did not use it); `outlier`: removed, or
    |w| above the critical value on either coordinate.
    """

    image: np.ndarray
    point: np.ndarray
    group: np.ndarray
    image_ids: np.ndarray
    point_ids: np.ndarray
    camera_ids: np.ndarray
    units: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    v_px: np.ndarray
    redundancy: np.ndarray
    w: np.ndarray
    removed: np.ndarray
    outlier: np.ndarray


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
class ScalarObservation:
    """One scalar observation of a group other than image points (control, GNSS/INS, ...).

    `ids`: the IDs naming it ({"point", "coordinate"}, {"image", "coordinate"}, {"camera",
    "coordinate"} or {"point_a", "point_b"}); `v` in the observation's units (angles of GNSS/INS
    in decimal degrees).
    """

    kind: str
    group: str
    ids: dict[str, str]
    v: float
    r: float
    w: float
    removed: bool
    outlier: bool


@dataclasses.dataclass(frozen=True)
class ReliabilitySummary:
    """Redundancy numbers and normalised residuals of the observations the solution used."""

    alpha: float
    critical_value: float
    n: int
    redundancy_sum: float
    min_redundancy: float
    mean_redundancy: float
    max_abs_w: float
    max_abs_w_at: str
    n_outliers: int
    groups: dict[str, dict]


_memo: dict | None = None  # (function, id(project), id(result)) -> (project, result, value)


@contextlib.contextmanager
def shared_tables():
    """While open, each table below is gathered once per (project, result) and shared by every
    writer that asks for it (the reports ask for the residuals, the group statistics and the
    point tables several times each). The tables are read-only to their callers."""
    global _memo
    outer = _memo
    _memo = {} if outer is None else outer
    try:
        yield
    finally:
        _memo = outer


def _shared(function):
    """`function(project, result)`, memoised while `shared_tables` is open."""

    @functools.wraps(function)
    def wrapper(project, result):
        if _memo is None:
            return function(project, result)
        key = (function.__name__, id(project), id(result))
        if key not in _memo:  # project and result kept: their ids cannot be reused meanwhile
            _memo[key] = (project, result, function(project, result))
        return _memo[key][2]

    return wrapper


def _status(estimated: bool, weighted: bool) -> str:
    if not estimated:
        return FIXED
    return WEIGHTED if weighted else FREE


def _tied(source: tuple[str, str]) -> str:
    """The status of a tied camera parameter (`CameraSpec.ties`): "tied to C1.K1"; its
    value and σ are its source's."""
    return f"{TIED} {source[0]}.{source[1]}"


def _status_table(estimated, sigma: list[tuple]) -> np.ndarray:
    """`_status` of every entry of a table at once: `estimated` (n, k) bools, `sigma` n tuples
    of k file σ (None free, 0 fixed, > 0 weighted). An (n, k) object array of str."""
    estimated = np.asarray(estimated, dtype=bool)
    with np.errstate(invalid="ignore"):
        weighted = np.array(sigma, dtype=float).reshape(estimated.shape) > 0  # None: NaN
    names = np.array([FIXED, FREE, WEIGHTED], dtype=object)
    return names[estimated * (1 + weighted)]


@_shared
def camera_tables(project: Project, result: Adjustment) -> dict[str, ParameterTable]:
    """One single-row table per camera: every parameter of its model, value and σ, then
    the model's constants (status "constant", σ 0)."""
    tables = {}
    for cid, (model, row) in project.camera_rows.items():
        names = CAMERA_MODELS[model].parameter_names
        camera = project.spec.cameras[cid]
        estimated = np.asarray(project.problem.free.cameras[model])[row]
        constants = [camera.constants[n] for n in CAMERA_MODELS[model].constant_names]
        values = np.asarray(result.parameters.cameras[model])[row]
        stds = np.asarray(result.precision.std.cameras[model])[row]
        tables[cid] = ParameterTable(
            names=tuple(names) + CAMERA_MODELS[model].constant_names,
            ids=[cid],
            values=np.r_[values, constants][None, :],
            stds=np.r_[stds, np.zeros(len(constants))][None, :],
            status=[[_tied(camera.ties[n]) if n in camera.ties
                     else _status(bool(e), n in camera.sigma) for n, e in zip(names, estimated)]
                    + [CONSTANT] * len(constants)],
        )
    return tables


@_shared
def image_table(project: Project, result: Adjustment) -> ParameterTable:
    """EOPs of all images; omega, phi, kappa and their σ in decimal degrees."""
    angles = [IMAGE_PARAMETER_NAMES.index(name) for name in ANGLE_NAMES]
    values = np.array(result.parameters.images, dtype=float)
    stds = np.array(result.precision.std.images, dtype=float)
    values[:, angles] = np.degrees(values[:, angles])
    stds[:, angles] = np.degrees(stds[:, angles])
    sigma = [project.spec.images[iid].eop_sigma for iid in project.image_ids]
    status = _status_table(project.problem.free.images, sigma)
    return ParameterTable(IMAGE_PARAMETER_NAMES, list(project.image_ids), values, stds, status)


@_shared
def point_table(project: Project, result: Adjustment) -> ParameterTable:
    """Object points used by the adjustment (those observed in images or by distances)."""
    sigma = [project.spec.points[pid].sigma for pid in project.point_ids]
    status = _status_table(project.problem.free.points, sigma)
    return ParameterTable(
        POINT_PARAMETER_NAMES,
        list(project.point_ids),
        np.asarray(result.parameters.points, dtype=float),
        np.asarray(result.precision.std.points, dtype=float),
        status,
    )


def is_measurement(group: AbstractObservationGroup) -> bool:
    """A group of real measurements (not constraints, such as a free network's inner
    constraints: the group says which it is)."""
    return not group.constraint


def group_kind(group: AbstractObservationGroup) -> str:
    """"image_points", "control", "gnss_ins", "camera_priors" or "distances"."""
    if isinstance(group, ImagePoints):
        return "image_points"
    if isinstance(group, Distances):
        return "distances"
    if isinstance(group, ParameterObservations):
        return {"points": "control", "images": "gnss_ins"}.get(group.block, "camera_priors")
    return group.name.split(":")[0]


def _coordinate_names(project: Project, group: AbstractObservationGroup) -> tuple[str, ...]:
    if isinstance(group, ImagePoints):
        return ("x", "y")
    if isinstance(group, ParameterObservations):
        if group.block == "points":
            return POINT_PARAMETER_NAMES
        if group.block == "images":
            return IMAGE_PARAMETER_NAMES
        return CAMERA_MODELS[group.block.removeprefix("cameras/")].parameter_names
    return ("distance",)


def _row_ids(project: Project, group, rows) -> list[dict[str, str]]:
    """The IDs naming rows `rows` (k,) of `group`: image and point, the two points of a
    distance, the point, image or camera of a parameter observation, else the row number."""
    rows = np.asarray(rows, dtype=int)
    images = np.asarray(project.image_ids, dtype=object)
    points = np.asarray(project.point_ids, dtype=object)
    if isinstance(group, ImagePoints):
        pairs = zip(images[np.asarray(group.image)[rows]], points[np.asarray(group.point)[rows]])
        return [{"image": image, "point": point} for image, point in pairs]
    if isinstance(group, Distances):
        pairs = zip(points[np.asarray(group.a)[rows]], points[np.asarray(group.b)[rows]])
        return [{"point_a": a, "point_b": b} for a, b in pairs]
    if not isinstance(group, ParameterObservations):
        return [{"row": str(row)} for row in rows.tolist()]
    block_rows = np.asarray(group.rows)[rows]
    if group.block == "points":
        key, names = "point", points[block_rows]
    elif group.block == "images":
        key, names = "image", images[block_rows]
    else:
        model = group.block.removeprefix("cameras/")
        owners = {model_row: cid for cid, model_row in project.camera_rows.items()}
        key, names = "camera", [owners[(model, row)] for row in block_rows.tolist()]
    return [{key: name} for name in names]


def _with_coordinate(project: Project, group, ids: dict[str, str], coordinate: int) -> dict:
    """`ids` of a row and the name of its observed coordinate (none for a distance)."""
    if isinstance(group, Distances):
        return ids
    if isinstance(group, ImagePoints | ParameterObservations):
        return {**ids, "coordinate": _coordinate_names(project, group)[coordinate]}
    return {**ids, "coordinate": str(coordinate)}


def observation_ids(project: Project, group, row: int, coordinate: int) -> dict[str, str]:
    """The IDs of one scalar observation: image/point/camera and coordinate, or two points."""
    return _with_coordinate(project, group, _row_ids(project, group, [row])[0], coordinate)


def _prior_groups(project: Project, result: Adjustment) -> list:
    """The project's groups as built, matched by name to the result's (None if not found)."""
    by_name = {group.name: group for group in project.problem.groups}
    return [by_name.get(group.name) for group in result.problem.groups]


def _unit_residuals(result: Adjustment, group: AbstractObservationGroup) -> np.ndarray:
    """observed - computed of every entry of `group` at the solution (σ set to 1)."""
    unit = eqx.tree_at(lambda g: g.stddev, group, jnp.ones_like(group.stddev))
    return np.asarray(unit.residuals(result.parameters, result.problem.refraction), dtype=float)


@_shared
def group_statistics(project: Project, result: Adjustment) -> list[GroupStatistics]:
    """v, r, w and outlier flags of every entry of every observation group of the result."""
    reliability = result.reliability
    critical = reliability.critical_value if reliability is not None else math.inf
    rejected = {(rej.group, rej.row, rej.coordinate): rej.w for rej in result.rejections}
    statistics = []
    for k, (group, prior) in enumerate(zip(result.problem.groups, _prior_groups(project, result))):
        final = np.isfinite(np.asarray(group.stddev))
        observed = final if prior is None else final | np.isfinite(np.asarray(prior.stddev))
        removed = observed & ~final
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
            group, group_kind(group), observed, removed, v, r, w, outlier & observed))
    return statistics


@_shared
def image_residuals(project: Project, result: Adjustment) -> ImageResiduals:
    """All image residuals, one row per measured image point (removed ones included)."""
    statistics = list(enumerate(group_statistics(project, result)))
    parts = [(k, s) for k, s in statistics if isinstance(s.group, ImagePoints)]

    def stack(get, shape=(0,)):
        return np.concatenate([np.asarray(get(k, s)) for k, s in parts] or [np.zeros(shape)])

    image = stack(lambda k, s: s.group.image).astype(int)
    order = np.argsort(image, kind="stable")
    image = image[order]
    cameras = [project.spec.images[iid].camera for iid in project.image_ids]
    units = [camera_units(project, cid) for cid in cameras]
    pixel_size = np.array([
        (1.0, 1.0) if unit == PIXEL else _pixel_size(project, cid)
        for cid, unit in zip(cameras, units)
    ]).reshape(-1, 2)
    point = stack(lambda k, s: s.group.point).astype(int)[order]
    v = stack(lambda k, s: s.v, (0, 2))[order]
    return ImageResiduals(
        image=image,
        point=point,
        group=stack(lambda k, s: np.full(len(s.v), k)).astype(int)[order],
        image_ids=np.asarray(project.image_ids, dtype=object)[image],
        point_ids=np.asarray(project.point_ids, dtype=object)[point],
        camera_ids=np.asarray(cameras, dtype=object)[image],
        units=np.asarray(units, dtype=object)[image],
        xy=stack(lambda k, s: np.asarray(s.group.measured, dtype=float), (0, 2))[order],
        v=v,
        v_px=v / pixel_size[image],
        redundancy=stack(lambda k, s: s.r, (0, 2))[order],
        w=stack(lambda k, s: s.w, (0, 2))[order],
        removed=stack(lambda k, s: s.removed.any(axis=1)).astype(bool)[order],
        outlier=stack(lambda k, s: s.outlier.any(axis=1)).astype(bool)[order],
    )


@_shared
def other_observations(project: Project, result: Adjustment) -> list[ScalarObservation]:
    """Every scalar observation that is not an image coordinate, group by group.

    GNSS/INS angle residuals are converted to decimal degrees (r and w have no unit).
    """
    observations = []
    for stats in group_statistics(project, result):
        if isinstance(stats.group, ImagePoints) or not is_measurement(stats.group):
            continue
        rows, coordinates = np.nonzero(stats.observed)
        v = stats.v[rows, coordinates]
        if stats.kind == "gnss_ins":
            angles = np.isin(np.asarray(IMAGE_PARAMETER_NAMES)[coordinates], ANGLE_NAMES)
            v = np.where(angles, np.degrees(v), v)
        ids = _row_ids(project, stats.group, rows)
        for k, coordinate in enumerate(coordinates.tolist()):
            observations.append(ScalarObservation(
                kind=stats.kind,
                group=stats.group.name,
                ids=_with_coordinate(project, stats.group, ids[k], coordinate),
                v=float(v[k]),
                r=float(stats.r[rows[k], coordinate]),
                w=float(stats.w[rows[k], coordinate]),
                removed=bool(stats.removed[rows[k], coordinate]),
                outlier=bool(stats.outlier[rows[k], coordinate]),
            ))
    return observations


def rejections(project: Project, result: Adjustment) -> list[dict]:
    """Data-snooping rejections in order of removal: group, IDs, coordinate, w."""
    groups = {group.name: group for group in result.problem.groups}
    return [
        {
            "group": rej.group,
            **observation_ids(project, groups[rej.group], rej.row, rej.coordinate),
            "w": float(rej.w),
        }
        for rej in result.rejections
    ]


def describe(ids: dict[str, str]) -> str:
    """`image img03 point 12 x`, `point_a 1 point_b 7`: IDs of an observation as text."""
    words = [f"{key} {value}" for key, value in ids.items() if key != "coordinate"]
    return " ".join(words + ([ids["coordinate"]] if "coordinate" in ids else []))


@_shared
def reliability_summary(project: Project, result: Adjustment) -> ReliabilitySummary | None:
    """Min/mean/sum of the redundancy numbers and the largest |w|, overall and per group.

    Over the measurements the final solution used (data-snooping rejections and constraint
    groups excluded); None when the result holds no reliability.
    """
    reliability = result.reliability
    if reliability is None:
        return None
    parts, groups, worst = [], {}, (-1.0, "")
    for stats in group_statistics(project, result):
        if not is_measurement(stats.group):
            continue
        used = stats.observed & ~stats.removed
        r, w = stats.r[used], np.abs(stats.w[used])
        finite_w = w[np.isfinite(w)]
        groups[stats.group.name] = {
            "n": int(np.count_nonzero(used)),
            "redundancy_sum": float(np.nansum(r)),
            "min_redundancy": float(np.nanmin(r)) if np.isfinite(r).any() else math.nan,
            "mean_redundancy": float(np.nanmean(r)) if np.isfinite(r).any() else math.nan,
            "max_abs_w": float(finite_w.max()) if finite_w.size else math.nan,
            "n_outliers": int(np.count_nonzero(stats.outlier & used)),
            "n_removed": int(np.count_nonzero(stats.removed)),
        }
        parts.append(r)
        if finite_w.size and finite_w.max() > worst[0]:
            abs_w = np.where(used, np.abs(np.nan_to_num(stats.w, nan=0.0)), -1.0)
            row, coordinate = np.unravel_index(np.argmax(abs_w), abs_w.shape)
            ids = observation_ids(project, stats.group, int(row), int(coordinate))
            worst = (float(finite_w.max()), f"{stats.group.name} {describe(ids)}")
    r = np.concatenate(parts) if parts else np.zeros(0)
    finite = np.isfinite(r)
    return ReliabilitySummary(
        alpha=float(reliability.alpha),
        critical_value=float(reliability.critical_value),
        n=int(r.size),
        redundancy_sum=float(np.sum(r[finite])),
        min_redundancy=float(np.min(r[finite])) if finite.any() else math.nan,
        mean_redundancy=float(np.mean(r[finite])) if finite.any() else math.nan,
        max_abs_w=worst[0] if worst[1] else math.nan,
        max_abs_w_at=worst[1],
        n_outliers=sum(g["n_outliers"] for g in groups.values()),
        groups=groups,
    )


@_shared
def camera_correlations(project: Project, result: Adjustment) -> dict[str, tuple[list, np.ndarray]]:
    """Per camera: the names of its estimated IOPs and their correlation matrix ρ."""
    return {
        cid: camera_correlation(result, model, row)
        for cid, (model, row) in project.camera_rows.items()
    }


@_shared
def point_ellipsoids(project: Project, result: Adjustment):
    """1σ error ellipsoids of the object points: semi-axes (n, 3) descending, object units;
    directions (n, 3, 3) with the unit axis k in column k; `has` (n,) True for points with
    a free (estimated) coordinate."""
    axes, directions = error_ellipsoids(point_covariances(result))
    has = np.asarray(project.problem.free.points).any(axis=1)
    return axes, directions, has


def camera_units(project: Project, camera_id: str) -> str:
    """"mm" or "pixel": the image units of the camera's model."""
    model = project.camera_rows[camera_id][0] if camera_id in project.camera_rows else (
        project.spec.cameras[camera_id].model)
    return CAMERA_MODELS[model].image_units


def project_units(project: Project) -> str:
    """The image units of all used cameras: "mm", "pixel", or "mixed"."""
    units = {camera_units(project, cid) for cid in project.camera_rows}
    return units.pop() if len(units) == 1 else ("mm" if not units else "mixed")


def _pixel_size(project: Project, camera_id: str) -> tuple[float, float]:
    grid = project.pixel_grids.get(camera_id)
    return (math.nan, math.nan) if grid is None else tuple(grid.pixel_size)


def residual_summary(residuals: ImageResiduals, codes: np.ndarray, names: list[str]) -> dict:
    """Per name: n and RMS of vx, vy in mm and in pixels over its rows (those with
    `codes` (n,) == its index) not removed by data snooping (`n_removed` of them were).

    The mm RMS is NaN when a row is in pixels (pixel-unit model), the pixel RMS when a row has
    no pixel size; both are NaN for no rows.
    """
    used, k = ~residuals.removed, len(names)

    def total(weights: np.ndarray) -> np.ndarray:
        return np.bincount(codes[used], weights=weights, minlength=k)

    n = np.bincount(codes[used], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms_mm = np.sqrt([total(residuals.v[used, j] ** 2) / n for j in (0, 1)])
        rms_px = np.sqrt([total(residuals.v_px[used, j] ** 2) / n for j in (0, 1)])
    rms_mm[:, total((residuals.units[used] != MM).astype(float)) > 0] = math.nan
    n_removed = np.bincount(codes[residuals.removed], minlength=k)
    return {
        name: {
            "n": int(n[c]),
            "n_removed": int(n_removed[c]),
            "rms_x_mm": float(rms_mm[0, c]),
            "rms_y_mm": float(rms_mm[1, c]),
            "rms_x_px": float(rms_px[0, c]),
            "rms_y_px": float(rms_px[1, c]),
        }
        for c, name in enumerate(names)
    }


def residual_summaries(residuals: ImageResiduals) -> dict:
    """Overall, per-camera and per-image residual summaries (see `residual_summary`); cameras
    and images with rows only, in the order of the rows (sorted by image)."""
    _, first, image_codes = np.unique(residuals.image, return_index=True, return_inverse=True)
    image_cameras = residuals.camera_ids[first].tolist()
    cameras = list(dict.fromkeys(image_cameras))
    camera_codes = np.array([cameras.index(c) for c in image_cameras], dtype=int).reshape(-1)
    everything = np.zeros(len(residuals.image), dtype=int)
    return {
        "all": residual_summary(residuals, everything, ["all"])["all"],
        "cameras": residual_summary(residuals, camera_codes[image_codes], cameras),
        "images": residual_summary(residuals, image_codes, residuals.image_ids[first].tolist()),
    }


def row_tuples(table: np.ndarray):
    """The rows of `table` (n, m) as tuples of Python numbers, one at a time (the columns are
    converted at once: no list per row for the garbage collector to walk)."""
    return zip(*(column.tolist() for column in np.asarray(table).T))


@_shared
def group_summaries(project: Project, result: Adjustment) -> dict[str, dict]:
    """Per observation group: its number of observations and its part vᵀPv of the total.

    P = σ0² Σ⁻¹ with the a priori σ0 of the project, so vᵀPv = σ0² Σ (v/σ)² over the group's
    real observations; the parts add up to σ̂0² · r.
    """
    prior = project.spec.settings.sigma0
    summaries = {}
    for group, residual in zip(result.problem.groups, result.residuals):
        mask = np.asarray(group.mask())
        sigma = np.where(mask, np.asarray(group.sigma(), dtype=float), 1.0)
        normalised = np.where(mask, np.asarray(residual, dtype=float) / sigma, 0.0)
        summaries[group.name] = {
            "n": int(np.count_nonzero(mask)),
            "vtpv": float(prior**2 * np.sum(normalised**2)),
        }
    return summaries
