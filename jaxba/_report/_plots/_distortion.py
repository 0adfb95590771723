"""Distortion curves of the cameras: radial Δr and decentering against the radius, ±1σ."""

import numpy as np

from ..._models._cameras import CAMERA_MODELS
from ..._models._cameras._names import DISTORTION_TERMS
from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from ..._statistics._distortion import KINDS, distortion_profiles
from .._collect import MM, camera_units, image_residuals
from ._base import new_figure, sensor_frame

_TITLES = {
    "radial": "radial distortion Δr (along the radius, + outward)",
    "decentering": "decentering distortion (largest over all directions)",
}


def estimated_kinds(project: Project, camera_id: str) -> list[str]:
    """The kinds of `KINDS` of which the camera has an estimated term."""
    model, row = project.camera_rows[camera_id]
    free = np.asarray(project.problem.free.cameras[model][row])
    names = CAMERA_MODELS[model].parameter_names
    return [kind for kind in KINDS if kind in DISTORTION_TERMS[model]
            and free[np.isin(names, DISTORTION_TERMS[model][kind])].any()]


def distorted_cameras(project: Project) -> list[str]:
    """The cameras with an estimated radial or decentering term, in project order."""
    return [cid for cid in project.camera_rows if estimated_kinds(project, cid)]


def plot_distortion(project: Project, result: Adjustment, camera_id: str | None = None):
    """Distortion curves of one camera (or of every camera with an estimated radial or
    decentering term, one row each, for None): the radial distortion Δr against the radius r
    from the principal point, and the decentering distortion, those with an estimated term,
    each with its ±1σ band from the covariance of its parameters, out to the sensor's
    farthest corner.

    The curves come from the camera model itself (`jaxba._statistics._distortion`): the
    displacement of the image point by those terms alone. mm models are drawn in µm against
    mm (with pixels on the right-hand axis where the camera has a pixel size), pixel models
    in pixels. Returns the matplotlib Figure (one Axes per curve, plus the pixel axes).
    """
    if camera_id is not None and camera_id not in project.camera_rows:
        raise ValueError(
            f"unknown camera {camera_id!r}; the adjusted cameras are {list(project.camera_rows)}")
    cameras = [camera_id] if camera_id is not None else distorted_cameras(project)
    if not cameras:
        raise ValueError("no camera has an estimated radial or decentering term")
    residuals = image_residuals(project, result)
    kinds = {cid: estimated_kinds(project, cid) for cid in cameras}
    if not any(kinds.values()):
        raise ValueError(f"camera {camera_id!r} has no estimated radial or decentering term")
    n_columns = max(len(chosen) for chosen in kinds.values())
    figure = new_figure(figsize=(5.2 * n_columns, 3.8 * len(cameras)), layout="constrained")
    axes = figure.subplots(len(cameras), n_columns, squeeze=False)
    for ax_row, cid in zip(axes, cameras):
        model, row = project.camera_rows[cid]
        frame, _ = sensor_frame(project, cid, residuals.xy[residuals.camera_ids == cid])
        corners = [(x, y) for x in frame[:2] for y in frame[2:]]
        profiles = distortion_profiles(result, model, row, corners,
                                       constants=project.spec.cameras[cid].constants)
        for ax, kind in zip(ax_row, kinds[cid]):
            _curve(ax, project, cid, profiles[kind])
        for ax in ax_row[len(kinds[cid]):]:
            figure.delaxes(ax)
    figure.suptitle(f"{project.spec.name}: lens distortion at the solution, ±1σ bands",
                    fontsize=10)
    return figure


def _curve(ax, project, camera_id, profile) -> None:
    mm = camera_units(project, camera_id) == MM
    factor, unit = (1000.0, "µm") if mm else (1.0, "px")  # drawn in µm for mm models
    value, std = factor * profile.value, factor * profile.std
    ax.fill_between(profile.radius, value - std, value + std, color="tab:blue", alpha=0.25,
                    linewidth=0, label="±1σ")
    ax.plot(profile.radius, value, color="tab:blue", linewidth=1.5, label=profile.kind)
    ax.axhline(0.0, color="0.6", linewidth=0.6)
    ax.set_xlim(0.0, profile.radius[-1])
    ax.set_xlabel(f"radius r from the principal point ({'mm' if mm else 'px'})", fontsize=8)
    ax.set_ylabel(f"{profile.kind} ({unit})", fontsize=8)
    model, row = project.camera_rows[camera_id]
    free = np.asarray(project.problem.free.cameras[model][row])
    estimated = [name for name, f in zip(CAMERA_MODELS[model].parameter_names, free)
                 if f and name in profile.names]
    ax.set_title(f"{camera_id}: {_TITLES[profile.kind]}\n{', '.join(estimated)} estimated;"
                 f" 1σ at r = {profile.radius[-1]:.3g}: {std[-1]:.2g} {unit}", fontsize=9)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="best")
    grid = project.pixel_grids.get(camera_id)
    if mm and grid is not None:
        pixel_um = 1000.0 * float(np.mean(grid.pixel_size))
        pixels = ax.secondary_yaxis("right", functions=(lambda v: v / pixel_um,
                                                        lambda p: p * pixel_um))
        pixels.set_ylabel("px", fontsize=8)
        pixels.tick_params(labelsize=7)
