"""Residual vectors of the image points on each image's sensor outline, with a scale arrow."""

import math

import numpy as np

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from .._collect import PIXEL, camera_units, image_residuals
from ._base import draw_outline, image_length, label_image_axes, new_figure, nice, sensor_frame

_CELL = (3.2, 2.6)  # inches per image in the grid of all images
_VECTOR_FRACTION = 0.06  # auto scale: the RMS residual is drawn this fraction of the format width
_KEY_ROOM = 0.16  # room below the outline for the scale arrow, a fraction of the format height
_MARGIN = 0.03  # room around the outline, a fraction of the larger format side


def plot_image_residuals(
    project: Project,
    result: Adjustment,
    image_id: str | None = None,
    *,
    scale: float | None = None,
):
    """Residual vectors v = observed - computed on the sensor outline, per image.

    One panel for `image_id`, or a grid with one panel per image (None). Vectors start at the
    measured point and are drawn `scale` times their length in image units (None: a round
    factor that draws the RMS residual of the shown images at about 6 % of the format width);
    blue for observations the solution used, red with a circle for outliers (rejected by data
    snooping, or |w| above the critical value). Vectors are clipped to the sensor outline;
    below it a scale arrow shows a round residual length near the RMS ("1 µm", "0.5 px").
    mm models: x right, y up, sensor centred; pixel models (col, row), row down. Returns the
    matplotlib Figure (one Axes per image).
    """
    residuals = image_residuals(project, result)
    if image_id is not None and image_id not in project.image_ids:
        raise ValueError(f"unknown image {image_id!r}; the project has {project.image_ids}")
    images = list(dict.fromkeys(residuals.image_ids)) if image_id is None else [image_id]
    image_of = np.asarray(residuals.image_ids, dtype=object)
    shown = np.isin(image_of, images)
    used = ~residuals.outlier & shown
    size = float(np.sqrt(np.mean(np.sum(residuals.v[used] ** 2, axis=1)))) if used.any() else 0.0
    if scale is None:
        frames = [
            sensor_frame(project, cid, residuals.xy[image_of == iid])[0]
            for iid, cid in ((i, project.spec.images[i].camera) for i in images)
        ]
        width = max((f[1] - f[0] for f in frames), default=1.0)
        scale = nice(_VECTOR_FRACTION * width / size) if size > 0 else 1.0
    key = nice(size) if size > 0 else None
    n_columns = 1 if len(images) == 1 else min(len(images), 4 if len(images) > 9 else 3)
    n_rows = math.ceil(len(images) / n_columns)
    figure = new_figure(
        figsize=(_CELL[0] * n_columns, _CELL[1] * n_rows + 0.6) if len(images) > 1 else (7, 5.6),
        layout="constrained",
    )
    axes = figure.subplots(n_rows, n_columns, squeeze=False).ravel()
    for ax in axes[len(images):]:
        figure.delaxes(ax)
    for ax, iid in zip(axes, images):
        camera_id = project.spec.images[iid].camera
        selected = image_of == iid
        _residual_panel(
            ax, project, camera_id, residuals.xy[selected], residuals.v[selected],
            residuals.outlier[selected], scale, key, width=0.004 if len(images) > 1 else 0.0025,
        )
        n_out = int(np.count_nonzero(residuals.outlier[selected]))
        title = f"{iid} ({camera_id}, {np.count_nonzero(selected)} points"
        if n_out:
            title += f", {n_out} outlier{'s' if n_out > 1 else ''}"
        ax.set_title(title + ")", fontsize=9)
    units = {residuals.units[k] for k in np.flatnonzero(shown)} or {"mm"}
    unit = "pixels" if units == {PIXEL} else "mm" if units == {"mm"} else "image units"
    figure.suptitle(
        f"{project.spec.name}: image residuals v = observed - computed, vectors x {scale:g}"
        f" ({unit}); red: outliers",
        fontsize=10,
    )
    return figure


def _residual_panel(ax, project, camera_id, xy, v, outlier, scale, key, width):
    from matplotlib.patches import Rectangle

    frame, row_down = sensor_frame(project, camera_id, xy)
    x0, x1, y0, y1 = frame
    draw_outline(ax, frame)
    sensor = Rectangle((x0, y0), x1 - x0, y1 - y0, transform=ax.transData)
    arrows = []
    for chosen, color in ((~outlier, "tab:blue"), (outlier, "tab:red")):
        if chosen.any():
            arrows.append(ax.quiver(
                xy[chosen, 0], xy[chosen, 1], v[chosen, 0], v[chosen, 1], color=color,
                angles="xy", scale_units="xy", scale=1.0 / scale, width=width,
            ))
            arrows[-1].set_clip_path(sensor)
    if outlier.any():
        ax.scatter(
            xy[outlier, 0], xy[outlier, 1], s=40, facecolors="none", edgecolors="tab:red",
            linewidths=1.0,
        ).set_clip_path(sensor)
    ax.set_aspect("equal")
    margin = _MARGIN * max(x1 - x0, y1 - y0)
    room = _KEY_ROOM * (y1 - y0) if key is not None and arrows else margin
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim((y1 + room, y0 - margin) if row_down else (y0 - room, y1 + margin))
    if key is not None and arrows:
        below = y1 + 0.5 * room if row_down else y0 - 0.5 * room
        label = image_length(key, camera_units(project, camera_id))
        ax.quiverkey(arrows[0], x0 + 0.05 * (x1 - x0), below, key, label, coordinates="data",
                     labelpos="E", color="black", fontproperties={"size": 7})
    label_image_axes(ax, project, camera_id, row_down)
    ax.tick_params(labelsize=7)

