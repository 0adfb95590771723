"""Summaries of the residuals for the reports: n and RMS of the image residuals overall, per
camera and per image, and each observation group's part of vᵀPv."""

import math

import numpy as np

from .._problem._observations import host_query, named_parts
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._collect import MM, ImageResiduals, image_residuals, project_ids, shared


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
        for name, rows in named_parts(group, camera_ids):
            summaries[name] = {
                "n": int(np.count_nonzero(mask[rows])),
                "vtpv": float(prior**2 * np.sum(normalised[rows] ** 2)),
            }
    return summaries
