"""Summaries of the residuals for the reports: n and RMS of the image residuals overall, per
camera and per image, and each observation group's part of vᵀPv."""

import math

import numpy as np

from .._problem._observations import host_query
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._collect import MM, ImageResiduals, image_residuals, part_rows, project_ids, shared


def _summary_entries(residuals: ImageResiduals, pixels: np.ndarray, codes: np.ndarray,
                     k: int) -> list[dict]:
    """The n and RMS entries (`residual_summaries`) of k sets of rows at once (`pixels` (n,):
    True for rows in pixels): row i counts in the sets `codes[i]` (n, m), each its n,
    n_removed and RMS of vx, vy in mm and in pixels over its rows not removed by data
    snooping, the squares summed by one `np.bincount` (row by row, as a sum over the set's
    rows alone)."""
    used = ~residuals.removed
    squares = np.empty((len(used), 4))  # vx², vy² in mm, in pixels; 0 for removed rows
    squares[:, :2], squares[:, 2:] = residuals.v ** 2, residuals.v_px ** 2
    squares[~used] = 0.0
    index = codes[:, :, None] * 4 + np.arange(4)
    weights = np.broadcast_to(squares[:, None, :], index.shape)
    sums = np.bincount(index.ravel(), weights=weights.ravel(), minlength=k * 4).reshape(k, 4)
    n = np.bincount(codes[used].ravel(), minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sums / n[:, None])
    rms[np.bincount(codes[used & pixels].ravel(), minlength=k) > 0, :2] = math.nan
    n_removed = np.bincount(codes[~used].ravel(), minlength=k)
    return [
        {
            "n": int(n[c]),
            "n_removed": int(n_removed[c]),
            "rms_x_mm": float(rms[c, 0]),
            "rms_y_mm": float(rms[c, 1]),
            "rms_x_px": float(rms[c, 2]),
            "rms_y_px": float(rms[c, 3]),
        }
        for c in range(k)
    ]


def residual_summaries(residuals: ImageResiduals) -> dict:
    """Overall, per-camera and per-image summaries of the image residuals: n and RMS of vx,
    vy in mm and in pixels over the rows not removed by data snooping (`n_removed` of them
    were); cameras and images with rows only, in the order of the rows (sorted by image).
    The mm RMS is NaN when a row is in pixels (pixel-unit model), the pixel RMS when a row
    has no pixel size; both are NaN for no rows."""
    starts = np.ones(len(residuals.image), dtype=bool)  # rows sorted by image: its first rows
    starts[1:] = residuals.image[1:] != residuals.image[:-1]
    first, image_codes = np.flatnonzero(starts), np.cumsum(starts) - 1
    image_cameras = residuals.camera_ids[first].tolist()
    cameras = list(dict.fromkeys(image_cameras))
    camera_codes = np.array([cameras.index(c) for c in image_cameras], dtype=int).reshape(-1)
    images = residuals.image_ids[first].tolist()
    pixels = (residuals.units[first] != MM)[image_codes]  # units per image, not per row
    several = len(cameras) > 1  # one camera: its rows are all rows, its entry the overall one
    levels = [np.zeros(len(residuals.image), dtype=int), 1 + image_codes]
    levels += [1 + len(images) + camera_codes[image_codes].reshape(-1)] if several else []
    entries = _summary_entries(residuals, pixels, np.column_stack(levels),
                               1 + len(images) + several * len(cameras))
    return {
        "all": entries[0],
        "cameras": (dict(zip(cameras, entries[1 + len(images):])) if several
                    else {cid: dict(entries[0]) for cid in cameras}),
        "images": dict(zip(images, entries[1:1 + len(images)])),
    }


@shared
def image_residual_summaries(project: Project, result: Adjustment) -> dict:
    """`residual_summaries` of the result's image residuals (gathered once per write)."""
    return residual_summaries(image_residuals(project, result))


@shared
def group_summaries(project: Project, result: Adjustment) -> dict[str, dict]:
    """Per observation group (per part: `AbstractObservationGroup.parts`, the image points of
    each camera): its number of observations and its part vᵀPv of the total.

    P = σ0² Σ⁻¹ with the a priori σ0 of the project, so vᵀPv = σ0² Σ (v/σ)² over the group's
    real observations; the parts add up to σ̂0² · r.
    """
    prior = project.spec.settings.sigma0
    summaries = {}
    camera_ids = project_ids(project).cameras
    for group, residual in zip(result.problem.groups, result.residuals):
        sigma = np.asarray(host_query(group, "sigma"), dtype=float)
        mask = np.isfinite(sigma)  # `group.mask()`, without a jax call
        sigma = np.where(mask, sigma, 1.0)
        normalised = np.where(mask, np.asarray(residual, dtype=float) / sigma, 0.0)
        for name, rows in part_rows(group, camera_ids, len(mask)):
            summaries[name] = {
                "n": int(np.count_nonzero(mask[rows])),
                "vtpv": float(prior**2 * np.sum(normalised[rows] ** 2)),
            }
    return summaries
