"""Gather an adjustment into plain NumPy tables keyed by the project's IDs.

Everything the report writers need, in report units: IOPs in the camera's units (mm based, or
pixels for pixel-unit models such as "opencv"), EOP positions and object points in object
units, angles in decimal degrees, image residuals v = observed - computed in the camera model's
image units (mm, or pixels) and, where the camera has a pixel size, in pixels; redundancy
numbers r, normalised residuals w and outlier flags of every observation; IOP correlations and
point error ellipsoids. The per-observation statistics come by row numbers from
`jaxba._statistics._observation_statistics`; this module names the rows by ID.
"""

import contextlib
import dataclasses
import functools
import math
import threading

import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._problem._observations import named_parts, part_name
from .._problem._parameters import ANGLE_NAMES, IMAGE_PARAMETER_NAMES, POINT_PARAMETER_NAMES
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._derived import (
    camera_covariance,
    correlation_of_free,
    error_ellipsoids,
    point_covariances,
)
from .._statistics._ids import Ids
from .._statistics._observation_statistics import (
    GroupStatistics,
    describe,
    group_statistics as statistics_of_groups,
    image_point_rows,
    is_measurement,
    name_rows,
    observation_ids as ids_of_observation,
    row_part_index,
    with_coordinate,
)
from .._statistics._rigs import composed_pose_sigma, composed_poses
from .._statistics._summary import (
    OutlierSummary,
    VarianceTest,
    datum_description,
    outlier_summary,
    variance_test,
)

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
    the index of the row's group in `result.problem.groups`, `part_index` (n,) the row's part
    there in `parts` (names, "image_points:<camera ID>", `AbstractObservationGroup.parts`);
    `image_ids`, `point_ids`,
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
    parts: tuple[str, ...]
    part_index: np.ndarray
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


# Per thread (reports of several projects may be written at once, one per thread):
# .memo maps (function, id(project), id(result)) -> (project, result, value).
_tables = threading.local()


@contextlib.contextmanager
def shared_tables():
    """While open, each table below is gathered once per (project, result) and shared by every
    writer that asks for it (the reports ask for the residuals, the group statistics and the
    point tables several times each), in this thread. The tables are read-only to their
    callers."""
    outer = getattr(_tables, "memo", None)
    _tables.memo = {} if outer is None else outer
    try:
        yield
    finally:
        _tables.memo = outer


def shared(function):
    """`function(project, result)`, memoised while `shared_tables` is open."""

    @functools.wraps(function)
    def wrapper(project, result):
        memo = getattr(_tables, "memo", None)
        if memo is None:
            return function(project, result)
        key = (function.__name__, id(project), id(result))
        if key not in memo:  # project and result kept: their ids cannot be reused meanwhile
            memo[key] = (project, result, function(project, result))
        return memo[key][2]

    return wrapper


def _status(estimated: bool, weighted: bool) -> str:
    if not estimated:
        return FIXED
    return WEIGHTED if weighted else FREE


def _tied(source: tuple[str, str]) -> str:
    """The status of a tied camera parameter (`CameraSpec.ties`): "tied to C1.K1"; its
    value and σ are its source's."""
    return f"{TIED} {source[0]}.{source[1]}"


def status_table(estimated, sigma: list[tuple]) -> np.ndarray:
    """The status (FIXED, FREE or WEIGHTED) of every entry of a `ParameterTable` at once:
    `estimated` (n, k) bools, `sigma` n tuples of k file σ (None free, 0 fixed, > 0
    weighted). An (n, k) object array of str."""
    estimated = np.asarray(estimated, dtype=bool)
    with np.errstate(invalid="ignore"):
        weighted = np.array(sigma, dtype=float).reshape(estimated.shape) > 0  # None: NaN
    names = np.array([FIXED, FREE, WEIGHTED], dtype=object)
    return names[estimated * (1 + weighted)]


@shared
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


def frame_sigma(project: Project) -> list[tuple]:
    """The GNSS/INS σ (file units: None free, 0 fixed, > 0 weighted) of every row of the
    images block: every image's, or with rigs every frame's."""
    if project.rigs is None:
        return [project.spec.images[iid].eop_sigma for iid in project.image_ids]
    sigma = project.rigs.frame_sigma.copy()
    sigma[:, 3:] = np.degrees(sigma[:, 3:])
    return np.where(np.isfinite(sigma), sigma, np.nan).tolist()


def _composed_image_table(project: Project, result: Adjustment) -> ParameterTable:
    """Every image's pose in a project with rigs: its frame's followed by its camera's in
    the rig (the reference camera's: the frame's), σ propagated from the 12 x 12 covariance
    of both; status the frame's for the reference camera's images, else fixed where frame
    and mount are, free otherwise (its own pose is no unknown)."""
    rigs, params, pose = project.rigs, result.parameters, result.problem.pose
    frames, mounts = rigs.image_frame, rigs.image_mount
    values = np.array(composed_poses(params, pose, frames, mounts))
    stds = np.array([composed_pose_sigma(params, result.precision, pose, f, m)
                     for f, m in zip(frames.tolist(), mounts.tolist())]).reshape(-1, 6)
    free = (np.asarray(project.problem.free.images)[frames]
            | np.asarray(project.problem.free.mounts)[mounts])
    frame_status = status_table(project.problem.free.images, frame_sigma(project))[frames]
    status = np.where(mounts[:, None] == 0, frame_status,
                      np.where(free, FREE, FIXED).astype(object))
    angles = [IMAGE_PARAMETER_NAMES.index(name) for name in ANGLE_NAMES]
    values[:, angles], stds[:, angles] = np.degrees(values[:, angles]), np.degrees(stds[:, angles])
    return ParameterTable(IMAGE_PARAMETER_NAMES, list(project.image_ids), values, stds, status)


@shared
def image_table(project: Project, result: Adjustment) -> ParameterTable:
    """EOPs of all images; omega, phi, kappa and their σ in decimal degrees (with rigs each
    composed from its frame's and its camera's: `_composed_image_table`)."""
    if project.rigs is not None:
        return _composed_image_table(project, result)
    angles = [IMAGE_PARAMETER_NAMES.index(name) for name in ANGLE_NAMES]
    values = np.array(result.parameters.images, dtype=float)
    stds = np.array(result.precision.std.images, dtype=float)
    values[:, angles] = np.degrees(values[:, angles])
    stds[:, angles] = np.degrees(stds[:, angles])
    sigma = [project.spec.images[iid].eop_sigma for iid in project.image_ids]
    status = status_table(project.problem.free.images, sigma)
    return ParameterTable(IMAGE_PARAMETER_NAMES, list(project.image_ids), values, stds, status)


@shared
def point_table(project: Project, result: Adjustment) -> ParameterTable:
    """Object points used by the adjustment (those observed in images or by distances)."""
    free = np.asarray(project.problem.free.points, dtype=bool)
    sigma = ([project.spec.points[pid].sigma for pid in project.point_ids] if free.any()
             else np.zeros(free.shape))  # no point estimated (a calibration's targets): fixed
    status = status_table(free, sigma)
    return ParameterTable(
        POINT_PARAMETER_NAMES,
        list(project.point_ids),
        np.asarray(result.parameters.points, dtype=float),
        np.asarray(result.precision.std.points, dtype=float),
        status,
    )


@shared
def datum_text(project: Project, result: Adjustment) -> str:
    """The one description of the datum that NAME.out and results.json give: a dependent
    relative orientation by the image and coordinates it fixes (its bundle holds only fixed
    EOPs, which `datum_description` would call control), any other by `datum_description`."""
    datum = project.datum
    if datum["kind"] != "dependent":
        return datum_description(result.problem)
    scale = (f"{datum['base_coordinate']} of image {datum['base_image']} fixed (the longest "
             "base: the scale)" if datum["scale"] == "base" else "scale from the distances")
    return (f"dependent relative orientation: {' '.join(datum['fixed'])} of image "
            f"{datum['image']} fixed, {scale}")


@shared
def variance_check(project: Project, result: Adjustment) -> VarianceTest | None:
    """The χ² test of the variance factor (`variance_test`), shared by NAME.out and
    results.json."""
    del project
    return variance_test(result)


@shared
def outlier_check(project: Project, result: Adjustment) -> OutlierSummary | None:
    """|w| above the critical value: `outlier_summary` named by the project's IDs."""
    return outlier_summary(result, project_ids(project), group_statistics(project, result))


def project_ids(project: Project) -> Ids:
    """The project's IDs of the blocks' rows, as an adjustment's `Ids` (shared while
    `shared_tables` is open: the reports ask for them several times)."""
    return _project_ids(project, None)


@shared
def _project_ids(project: Project, result: None) -> Ids:
    del result
    cameras: dict[str, list[str]] = {}
    for cid, (model, row) in sorted(project.camera_rows.items(), key=lambda item: item[1]):
        cameras.setdefault(model, []).append(cid)
    mounts = () if project.rigs is None else tuple(project.rigs.mount_ids)
    return Ids({model: tuple(ids) for model, ids in cameras.items()},
               tuple(project.frame_ids), tuple(project.point_ids), mounts,
               tuple(project.board_ids))


def observation_ids(project: Project, group, row: int, coordinate: int) -> dict[str, str]:
    """The IDs of one scalar observation: image/point/camera and coordinate, or two points."""
    return ids_of_observation(project_ids(project), group, row, coordinate)


@shared
def group_statistics(project: Project, result: Adjustment) -> list[GroupStatistics]:
    """v, r, w and outlier flags of every entry of every observation group of the result
    (`jaxba._statistics._observation_statistics.group_statistics`, shared)."""
    del project
    return statistics_of_groups(result)


@shared
def image_residuals(project: Project, result: Adjustment) -> ImageResiduals:
    """All image residuals, one row per measured image point (removed ones included)."""
    rows = image_point_rows(group_statistics(project, result))
    image = rows.image
    if project.rigs is not None:  # rows refer to frames and mounts: to images, sorted so
        rows = _by_image(project, rows)
        image = rows.image
    cameras = [project.spec.images[iid].camera for iid in project.image_ids]
    units = [camera_units(project, cid) for cid in cameras]
    pixel_size = np.array([
        (1.0, 1.0) if unit == PIXEL else _pixel_size(project, cid)
        for cid, unit in zip(cameras, units)
    ]).reshape(-1, 2)
    parts, part_index = row_part_index(result.problem.groups, rows, project_ids(project).cameras)
    return ImageResiduals(
        image=image,
        point=rows.point,
        group=rows.group,
        parts=parts,
        part_index=part_index,
        image_ids=np.asarray(project.image_ids, dtype=object)[image],
        point_ids=np.asarray(project.point_ids, dtype=object)[rows.point],
        camera_ids=np.asarray(cameras, dtype=object)[image],
        units=np.asarray(units, dtype=object)[image],
        xy=rows.xy,
        v=rows.v,
        v_px=rows.v / pixel_size[image],
        redundancy=rows.r,
        w=rows.w,
        removed=rows.removed,
        outlier=rows.outlier,
    )


def _by_image(project: Project, rows):
    """`rows` of a project with rigs with `image` the row of `project.image_ids` each
    (frame and mount name one image), sorted by it."""
    rigs = project.rigs
    code = rigs.image_frame * len(rigs.mount_ids) + rigs.image_mount
    lookup = dict(zip(code.tolist(), range(code.size)))
    image = np.array([lookup[c] for c in (rows.image * len(rigs.mount_ids) + rows.mount)
                      .tolist()], dtype=int)
    order = np.argsort(image, kind="stable")
    fields = {f.name: getattr(rows, f.name)[order] for f in dataclasses.fields(rows)}
    return dataclasses.replace(rows, **{**fields, "image": image[order]})


def in_pixel_frame(project: Project, residuals: ImageResiduals) -> ImageResiduals:
    """`residuals` with every row in pixels (col, row; row down), as the image points of a
    pixel project are given: rows of mm cameras through their pixel grid (x, y to col, row;
    v to (vx / ps_x, -vy / ps_y)), rows of pixel cameras as they are."""
    mm = residuals.units == MM
    xy, v = residuals.xy.copy(), residuals.v_px.copy()
    v[mm, 1] = -v[mm, 1]  # y up -> row down
    for cid in np.unique(residuals.camera_ids[mm]).tolist():
        rows = mm & (residuals.camera_ids == cid)
        xy[rows] = np.asarray(project.pixel_grids[cid].image_to_pixel(residuals.xy[rows]))
    units = np.full(len(residuals.units), PIXEL, dtype=object)
    return dataclasses.replace(residuals, xy=xy, v=v, v_px=v, units=units)


@shared
def other_observations(project: Project, result: Adjustment) -> list[ScalarObservation]:
    """Every scalar observation that is not an image coordinate, group by group.

    GNSS/INS angle residuals are converted to decimal degrees (r and w have no unit).
    """
    observations = []
    for stats in group_statistics(project, result):
        if stats.kind == "image_points" or not is_measurement(stats.group):
            continue
        rows, coordinates = np.nonzero(stats.observed)
        v = stats.v[rows, coordinates]
        if stats.kind == "gnss_ins":
            angles = np.isin(np.asarray(IMAGE_PARAMETER_NAMES)[coordinates], ANGLE_NAMES)
            v = np.where(angles, np.degrees(v), v)
        ids = name_rows(project_ids(project), stats.group, rows)
        for k, coordinate in enumerate(coordinates.tolist()):
            observations.append(ScalarObservation(
                kind=stats.kind,
                group=stats.group.name,
                ids=with_coordinate(stats.group, ids[k], coordinate),
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
            "group": part_name(groups[rej.group], project_ids(project).cameras, rej.row),
            **observation_ids(project, groups[rej.group], rej.row, rej.coordinate),
            "w": float(rej.w),
        }
        for rej in result.rejections
    ]


def part_rows(group, camera_ids, n: int):
    """`named_parts` of `group` (n rows), a part of all rows as slice(None): views of the
    group's tables, not copies."""
    for name, rows in named_parts(group, camera_ids):
        yield name, slice(None) if len(rows) == n else rows


@shared
def reliability_summary(project: Project, result: Adjustment) -> ReliabilitySummary | None:
    """Min/mean/sum of the redundancy numbers and the largest |w|, overall and per group.

    Over the measurements the final solution used (data-snooping rejections and constraint
    groups excluded); None when the result holds no reliability.
    """
    reliability = result.reliability
    if reliability is None:
        return None
    parts, groups, worst = [], {}, (-1.0, "")
    ids = project_ids(project)
    for stats in group_statistics(project, result):
        if not is_measurement(stats.group):
            continue
        used = stats.observed & ~stats.removed
        abs_w = np.abs(stats.w)
        with np.errstate(invalid="ignore"):
            for name, rows in part_rows(stats.group, ids.cameras, len(used)):
                here = used[rows]
                r, w = stats.r[rows][here], abs_w[rows][here]
                known = ~np.isnan(r)  # np.nansum, nanmin, nanmean as numpy has them
                total, some = np.sum(np.where(known, r, 0.0)), np.isfinite(r).any()
                finite_w = w[np.isfinite(w)]
                groups[name] = {
                    "n": int(np.count_nonzero(here)),
                    "redundancy_sum": float(total),
                    "min_redundancy": float(np.fmin.reduce(r)) if some else math.nan,
                    "mean_redundancy": float(total / np.count_nonzero(known)) if some else math.nan,
                    "max_abs_w": float(finite_w.max()) if finite_w.size else math.nan,
                    "n_outliers": int(np.count_nonzero(stats.outlier[rows] & here)),
                    "n_removed": int(np.count_nonzero(stats.removed[rows])),
                }
                parts.append(r)
        finite_w = abs_w[used]
        finite_w = finite_w[np.isfinite(finite_w)]
        if finite_w.size and finite_w.max() > worst[0]:
            where = np.argmax(np.where(used & ~np.isnan(abs_w), abs_w, np.where(used, 0.0, -1.0)))
            row, coordinate = np.unravel_index(where, abs_w.shape)
            named = ids_of_observation(ids, stats.group, int(row), int(coordinate))
            part = part_name(stats.group, ids.cameras, int(row))
            worst = (float(finite_w.max()), f"{part} {describe(named)}")
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


@shared
def camera_covariances(project: Project, result: Adjustment) -> dict[str, np.ndarray]:
    """Per camera: Cxx (p, p) of all its parameters (`camera_covariance`), shared by the
    correlations of NAME.out and results.json and the covariances of results.json."""
    return {
        cid: camera_covariance(result, model, row)
        for cid, (model, row) in project.camera_rows.items()
    }


@shared
def camera_correlations(project: Project, result: Adjustment) -> dict[str, tuple[list, np.ndarray]]:
    """Per camera: the names of its estimated IOPs and their correlation matrix ρ."""
    covariances = camera_covariances(project, result)
    return {
        cid: correlation_of_free(result, model, row, covariances[cid])
        for cid, (model, row) in project.camera_rows.items()
    }


@shared
def point_ellipsoids(project: Project, result: Adjustment):
    """1σ error ellipsoids of the object points: semi-axes (n, 3) descending, object units;
    directions (n, 3, 3) with the unit axis k in column k; `has` (n,) True for points with
    a free (estimated) coordinate, the only ones computed (NaN for the others: the fixed
    targets of a calibration have none)."""
    has = np.asarray(project.problem.free.points).any(axis=1)
    n = has.size
    axes, directions = np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan)
    if has.any():
        axes[has], directions[has] = error_ellipsoids(point_covariances(result)[has])
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
