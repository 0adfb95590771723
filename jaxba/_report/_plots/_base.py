"""What the plots share: a matplotlib Figure without pyplot, round numbers for scales, the
sensor outline of a camera and lengths in image units written for people."""

import math

import numpy as np

from ..._project._build import Project
from .._collect import PIXEL, camera_units


def new_figure(**options):
    """A `matplotlib.figure.Figure(**options)`: no pyplot state, no display (any backend);
    save it with `fig.savefig(...)`, Jupyter shows it inline."""
    from matplotlib.figure import Figure

    return Figure(**options)


def nice(value: float) -> float:
    """The number 1, 2 or 5 x 10^k nearest below `value` (> 0)."""
    exponent = math.floor(math.log10(value))
    mantissa = value / 10**exponent
    return next(m for m in (5.0, 2.0, 1.0) if m <= mantissa * (1 + 1e-12)) * 10**exponent


def sensor_frame(project: Project, camera_id: str, xy: np.ndarray):
    """(x0, x1, y0, y1) of the sensor outline in the camera's image units, and y inverted?

    mm models: centred on the sensor, y up, from the pixel grid (else the extent of the
    points `xy` (n, 2)); pixel models: (col, row) from -0.5 to ncols - 0.5, row down.
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


def image_length(length: float, units: str) -> str:
    """A length in image units as text: pixels as "0.5 px", mm below 1 mm in µm ("2 µm")."""
    if units == PIXEL:
        return f"{length:g} px"
    return f"{length * 1000:g} µm" if abs(length) < 1 else f"{length:g} mm"


def label_image_axes(ax, project: Project, camera_id: str, row_down: bool) -> None:
    """The axes of an image panel with their units: x, y (mm) for mm models, col, row (px)
    for pixel models (`row_down`, as `sensor_frame` says)."""
    units = "px" if camera_units(project, camera_id) == PIXEL else "mm"
    ax.set_xlabel(f"{'col' if row_down else 'x'} ({units})", fontsize=8)
    ax.set_ylabel(f"{'row' if row_down else 'y'} ({units})", fontsize=8)


def draw_outline(ax, frame, *, cross: bool = True) -> None:
    """The sensor outline `frame` = (x0, x1, y0, y1) and, with `cross`, its centre lines."""
    x0, x1, y0, y1 = frame
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="0.4", linewidth=0.8)
    if cross:
        ax.plot([x0, x1], [0.5 * (y0 + y1)] * 2, color="0.85", linewidth=0.5)
        ax.plot([0.5 * (x0 + x1)] * 2, [y0, y1], color="0.85", linewidth=0.5)
