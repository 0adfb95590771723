"""Plots of an adjusted project: image residual vectors and IOP correlation matrices.

Plain matplotlib around the report tables (`jaxba._report`); matplotlib is imported inside the
functions (the `plots` extra), so jaxba imports without it. Figures are built with the
object-oriented API (`matplotlib.figure.Figure`, no pyplot state): save them with
`fig.savefig(...)`; Jupyter shows them inline.
"""

import math

import numpy as np

from .._io._project._build import Project
from .._statistics._adjustment import Adjustment
from ._collect import PIXEL, camera_correlations, camera_units, image_residuals

_CELL = (3.2, 2.4)  # inches per image in the grid of all images
_VECTOR_FRACTION = 0.06  # auto scale: the RMS residual is drawn this fraction of the format width


def _matplotlib():
    try:
        import matplotlib  # noqa: F401
        from matplotlib.figure import Figure
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError(
            "jaxba plots need matplotlib: pip install 'jaxba[plots]'"
        ) from error
    return Figure


def _nice(value: float) -> float:
    """The number 1, 2 or 5 x 10^k nearest below `value` (> 0)."""
    exponent = math.floor(math.log10(value))
    mantissa = value / 10**exponent
    return next(m for m in (5.0, 2.0, 1.0) if m <= mantissa) * 10**exponent


def _format(project: Project, camera_id: str, xy: np.ndarray):
    """(x0, x1, y0, y1) of the sensor outline in the camera's image units, and y inverted?

    mm models: centred on the sensor, y up, from the pixel grid (else the points' extent);
    pixel models: (col, row) from -0.5 to ncols - 0.5, row down.
    """
    spec = project.spec.cameras[camera_id]
    if camera_units(project, camera_id) == PIXEL:
        if spec.sensor is not None:
            return (-0.5, spec.sensor[0] - 0.5, -0.5, spec.sensor[1] - 0.5), True
        lo, hi = (xy.min(axis=0), xy.max(axis=0)) if len(xy) else (np.zeros(2), np.ones(2))
        return (lo[0], hi[0], lo[1], hi[1]), True
    grid = project.pixel_grids.get(camera_id)
    if grid is not None:
        half = np.asarray(grid.sensor, dtype=float) * np.asarray(grid.pixel_size) / 2
        return (-half[0], half[0], -half[1], half[1]), False
    extent = np.max(np.abs(xy), axis=0) if len(xy) else np.ones(2)
    return (-extent[0], extent[0], -extent[1], extent[1]), False


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
    snooping, or |w| above the critical value). mm models: x right, y up, sensor centred;
    pixel models (col, row), row down. Returns the matplotlib Figure (one Axes per image).
    """
    figure_class = _matplotlib()
    residuals = image_residuals(project, result)
    images = list(dict.fromkeys(residuals.image_ids)) if image_id is None else [image_id]
    if image_id is not None and image_id not in project.image_ids:
        raise ValueError(f"unknown image {image_id!r}; the project has {project.image_ids}")
    image_of = np.asarray(residuals.image_ids, dtype=object)
    if scale is None:
        used = ~residuals.outlier & np.isin(image_of, images)
        size = float(np.sqrt(np.mean(np.sum(residuals.v[used] ** 2, axis=1)))) if used.any() else 0
        frames = [
            _format(project, cid, residuals.xy[image_of == iid])[0]
            for iid, cid in ((i, project.spec.images[i].camera) for i in images)
        ]
        width = max((f[1] - f[0] for f in frames), default=1.0)
        scale = _nice(_VECTOR_FRACTION * width / size) if size > 0 else 1.0
    n_columns = 1 if len(images) == 1 else min(len(images), 4 if len(images) > 9 else 3)
    n_rows = math.ceil(len(images) / n_columns)
    figure = figure_class(
        figsize=(_CELL[0] * n_columns, _CELL[1] * n_rows + 0.6) if len(images) > 1 else (7, 5.2),
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
            residuals.outlier[selected], scale, width=0.004 if len(images) > 1 else 0.0025,
        )
        n_out = int(np.count_nonzero(residuals.outlier[selected]))
        title = f"{iid} ({camera_id}, {np.count_nonzero(selected)} points"
        if n_out:
            title += f", {n_out} outlier{'s' if n_out > 1 else ''}"
        ax.set_title(title + ")", fontsize=9)
    units = {residuals.units[k] for k in np.flatnonzero(np.isin(image_of, images))} or {"mm"}
    unit = "pixels" if units == {PIXEL} else "mm" if units == {"mm"} else "image units"
    figure.suptitle(
        f"{project.spec.name}: image residuals v = observed - computed, vectors x {scale:g}"
        f" ({unit}); red: outliers",
        fontsize=10,
    )
    return figure


def _residual_panel(ax, project, camera_id, xy, v, outlier, scale, width):
    (x0, x1, y0, y1), row_down = _format(project, camera_id, xy)
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="0.4", linewidth=0.8)
    ax.plot([x0, x1], [0.5 * (y0 + y1)] * 2, color="0.85", linewidth=0.5)
    ax.plot([0.5 * (x0 + x1)] * 2, [y0, y1], color="0.85", linewidth=0.5)
    for chosen, color in ((~outlier, "tab:blue"), (outlier, "tab:red")):
        if chosen.any():
            ax.quiver(
                xy[chosen, 0], xy[chosen, 1], v[chosen, 0], v[chosen, 1], color=color,
                angles="xy", scale_units="xy", scale=1.0 / scale, width=width,
            )
    if outlier.any():
        ax.scatter(
            xy[outlier, 0], xy[outlier, 1], s=40, facecolors="none", edgecolors="tab:red",
            linewidths=1.0,
        )
    ax.set_aspect("equal")
    margin = 0.04 * max(x1 - x0, y1 - y0)
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim((y1 + margin, y0 - margin) if row_down else (y0 - margin, y1 + margin))
    ax.tick_params(labelsize=7)


def plot_correlation(result: Adjustment, project: Project, camera_id: str):
    """Heat map of the correlation matrix of the estimated IOPs of one camera.

    ρ_ij = C_ij / (σ_i σ_j) from Cxx = σ̂0² N⁻¹ (`jaxba.camera_correlation`), colours from -1
    (blue) to +1 (red), the value written in every cell. Returns the matplotlib Figure (the
    matrix Axes and its colour bar).
    """
    figure_class = _matplotlib()
    if camera_id not in project.camera_rows:
        raise ValueError(
            f"unknown camera {camera_id!r}; the adjusted cameras are {list(project.camera_rows)}"
        )
    names, matrix = camera_correlations(project, result)[camera_id]
    if not names:
        raise ValueError(f"camera {camera_id!r} has no estimated parameters")
    n = len(names)
    size = max(4.0, 0.55 * n + 2.0)
    figure = figure_class(figsize=(size + 1.0, size), layout="constrained")
    ax = figure.subplots()
    image = ax.imshow(matrix, cmap="RdBu_r", vmin=-1.0, vmax=1.0)
    ax.set_xticks(range(n), names, rotation=90 if n > 8 else 0)
    ax.set_yticks(range(n), names)
    fontsize = 9 if n <= 8 else 7 if n <= 12 else 5
    for i in range(n):
        for j in range(n):
            value = matrix[i, j]
            ax.text(
                j, i, f"{value:.2f}", ha="center", va="center", fontsize=fontsize,
                color="white" if abs(value) > 0.6 else "black",
            )
    figure.colorbar(image, ax=ax, shrink=0.8, label="correlation")
    model = project.camera_rows[camera_id][0]
    ax.set_title(f"{project.spec.name}: IOP correlations of camera {camera_id} ({model})")
    return figure
