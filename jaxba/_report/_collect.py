"""Gather an adjustment into plain NumPy tables keyed by the project's IDs.

Everything the report writers need, in report units: IOPs in the camera's units (mm based),
EOP positions and object points in object units, angles in decimal degrees, image residuals
v = observed - computed in mm and, where the camera has a pixel size, in pixels. Nothing
here calls jax beyond turning arrays into NumPy.
"""

import dataclasses
import math

import numpy as np

from .._camera import CAMERA_MODELS
from .._observations import ImagePoints
from .._parameters import ANGLE_NAMES, IMAGE_PARAMETER_NAMES, POINT_PARAMETER_NAMES
from .._project import Project
from .._solve import Adjustment

FREE, FIXED, WEIGHTED = "free", "fixed", "weighted"
# One character per coordinate, as the σ columns of the input tables: - free, 0 fixed, w weighted.
STATUS_CODE = {FREE: "-", FIXED: "0", WEIGHTED: "w"}


@dataclasses.dataclass(frozen=True)
class ParameterTable:
    """Rows of one kind of unknown: `ids` (n,), `values` and `stds` (n, k), `status` (n, k)."""

    names: tuple[str, ...]
    ids: list[str]
    values: np.ndarray
    stds: np.ndarray
    status: list[list[str]]


@dataclasses.dataclass(frozen=True)
class ImageResiduals:
    """Image residuals of all image-point groups, sorted by image (file order within one).

    `xy` and `v` are (n, 2) in mm; `v_px` is v divided by the pixel size (same axes, y up),
    NaN for cameras without a pixel size.
    """

    image_ids: list[str]
    point_ids: list[str]
    camera_ids: list[str]
    xy: np.ndarray
    v: np.ndarray
    v_px: np.ndarray


def _status(estimated: bool, weighted: bool) -> str:
    if not estimated:
        return FIXED
    return WEIGHTED if weighted else FREE


def _is_weighted(sigma) -> bool:
    """File σ: None free, 0 fixed, > 0 weighted (an observation of the parameter)."""
    return sigma is not None and sigma > 0


def camera_tables(project: Project, result: Adjustment) -> dict[str, ParameterTable]:
    """One single-row table per camera: every parameter of its model, value and σ."""
    tables = {}
    for cid, (model, row) in project.camera_rows.items():
        names = CAMERA_MODELS[model].parameter_names
        camera = project.spec.cameras[cid]
        estimated = np.asarray(project.problem.free.cameras[model])[row]
        tables[cid] = ParameterTable(
            names=tuple(names),
            ids=[cid],
            values=np.asarray(result.parameters.cameras[model])[row][None, :],
            stds=np.asarray(result.precision.std.cameras[model])[row][None, :],
            status=[[_status(bool(e), n in camera.sigma) for n, e in zip(names, estimated)]],
        )
    return tables


def image_table(project: Project, result: Adjustment) -> ParameterTable:
    """EOPs of all images; omega, phi, kappa and their σ in decimal degrees."""
    angles = [IMAGE_PARAMETER_NAMES.index(name) for name in ANGLE_NAMES]
    values = np.array(result.parameters.images, dtype=float)
    stds = np.array(result.precision.std.images, dtype=float)
    values[:, angles] = np.degrees(values[:, angles])
    stds[:, angles] = np.degrees(stds[:, angles])
    estimated = np.asarray(project.problem.free.images)
    status = [
        [_status(bool(e), _is_weighted(s)) for e, s in zip(estimated[k], spec.eop_sigma)]
        for k, spec in enumerate(project.spec.images[iid] for iid in project.image_ids)
    ]
    return ParameterTable(IMAGE_PARAMETER_NAMES, list(project.image_ids), values, stds, status)


def point_table(project: Project, result: Adjustment) -> ParameterTable:
    """Object points used by the adjustment (those observed in images or by distances)."""
    estimated = np.asarray(project.problem.free.points)
    status = [
        [_status(bool(e), _is_weighted(s)) for e, s in zip(estimated[k], spec.sigma)]
        for k, spec in enumerate(project.spec.points[pid] for pid in project.point_ids)
    ]
    return ParameterTable(
        POINT_PARAMETER_NAMES,
        list(project.point_ids),
        np.asarray(result.parameters.points, dtype=float),
        np.asarray(result.precision.std.points, dtype=float),
        status,
    )


def image_residuals(project: Project, result: Adjustment) -> ImageResiduals:
    """All image residuals, one row per measured image point."""
    image_rows, point_rows, xy, v = [], [], [], []
    for group, residual in zip(result.problem.groups, result.residuals):
        if isinstance(group, ImagePoints):
            image_rows.append(np.asarray(group.image))
            point_rows.append(np.asarray(group.point))
            xy.append(np.asarray(group.measured, dtype=float))
            v.append(np.asarray(residual, dtype=float))
    if not image_rows:
        empty = np.zeros((0, 2))
        return ImageResiduals([], [], [], empty, empty, empty)
    image_rows, point_rows = np.concatenate(image_rows), np.concatenate(point_rows)
    order = np.argsort(image_rows, kind="stable")
    image_ids = [project.image_ids[k] for k in image_rows[order]]
    camera_ids = [project.spec.images[iid].camera for iid in image_ids]
    pixel_size = np.array([_pixel_size(project, cid) for cid in camera_ids]).reshape(-1, 2)
    v = np.concatenate(v)[order]
    return ImageResiduals(
        image_ids=image_ids,
        point_ids=[project.point_ids[k] for k in point_rows[order]],
        camera_ids=camera_ids,
        xy=np.concatenate(xy)[order],
        v=v,
        v_px=v / pixel_size,
    )


def _pixel_size(project: Project, camera_id: str) -> tuple[float, float]:
    grid = project.pixel_grids.get(camera_id)
    return (math.nan, math.nan) if grid is None else tuple(grid.pixel_size)


def rms(values: np.ndarray) -> np.ndarray:
    """Root mean square over the rows, per column; NaN for no rows."""
    values = np.asarray(values, dtype=float)
    if values.shape[0] == 0:
        return np.full(values.shape[1:], math.nan)
    return np.sqrt(np.mean(values**2, axis=0))


def residual_summary(residuals: ImageResiduals, selected: np.ndarray) -> dict:
    """n and RMS of vx, vy (mm, and pixels where every selected row has a pixel size)."""
    rms_mm = rms(residuals.v[selected])
    rms_px = rms(residuals.v_px[selected])
    return {
        "n": int(np.count_nonzero(selected)),
        "rms_x_mm": float(rms_mm[0]),
        "rms_y_mm": float(rms_mm[1]),
        "rms_x_px": float(rms_px[0]),
        "rms_y_px": float(rms_px[1]),
    }


def residual_summaries(residuals: ImageResiduals) -> dict:
    """Overall, per-camera and per-image residual summaries (see `residual_summary`)."""
    cameras = np.asarray(residuals.camera_ids, dtype=object)
    images = np.asarray(residuals.image_ids, dtype=object)
    return {
        "all": residual_summary(residuals, np.ones(len(images), dtype=bool)),
        "cameras": {c: residual_summary(residuals, cameras == c) for c in dict.fromkeys(cameras)},
        "images": {i: residual_summary(residuals, images == i) for i in dict.fromkeys(images)},
    }


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
