"""Where on the sensor a camera's observations lie: all its images overlaid."""

import math

import numpy as np

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from .._collect import image_residuals
from ._base import draw_outline, label_image_axes, new_figure, sensor_frame

COVERAGE_CELLS = 10  # the format is cut into 10 x 10 cells for the covered fraction


def format_coverage(xy: np.ndarray, frame) -> float:
    """The fraction of the `COVERAGE_CELLS`² equal cells of the sensor outline `frame`
    (x0, x1, y0, y1) that hold at least one of the points `xy` (n, 2)."""
    x0, x1, y0, y1 = frame
    cells = np.floor((xy - [x0, y0]) / [(x1 - x0) / COVERAGE_CELLS, (y1 - y0) / COVERAGE_CELLS])
    inside = np.all((cells >= 0) & (cells < COVERAGE_CELLS), axis=1)
    return len({tuple(c) for c in cells[inside].astype(int).tolist()}) / COVERAGE_CELLS**2


def plot_coverage(project: Project, result: Adjustment):
    """The measured image points of every image of each camera on its sensor outline, one
    panel per camera, coloured by image; the title gives the images, the points and the
    fraction of a 10 x 10 grid of the format that holds a point. Returns the matplotlib
    Figure (one Axes per camera)."""
    residuals = image_residuals(project, result)
    cameras = list(dict.fromkeys(residuals.camera_ids))
    if not cameras:
        raise ValueError("the project has no image points")
    n_columns = min(len(cameras), 2)
    n_rows = math.ceil(len(cameras) / n_columns)
    figure = new_figure(figsize=(6 * n_columns, 4.6 * n_rows), layout="constrained")
    axes = figure.subplots(n_rows, n_columns, squeeze=False).ravel()
    for ax in axes[len(cameras):]:
        figure.delaxes(ax)
    for ax, cid in zip(axes, cameras):
        chosen = residuals.camera_ids == cid
        xy = residuals.xy[chosen]
        frame, row_down = sensor_frame(project, cid, xy)
        draw_outline(ax, frame)
        _, image_codes = np.unique(residuals.image[chosen], return_inverse=True)
        ax.scatter(xy[:, 0], xy[:, 1], c=image_codes % 20, cmap="tab20", vmin=0, vmax=19,
                   s=6, linewidths=0)
        x0, x1, y0, y1 = frame
        margin = 0.03 * max(x1 - x0, y1 - y0)
        ax.set_xlim(x0 - margin, x1 + margin)
        ax.set_ylim((y1 + margin, y0 - margin) if row_down else (y0 - margin, y1 + margin))
        ax.set_aspect("equal")
        label_image_axes(ax, project, cid, row_down)
        ax.tick_params(labelsize=7)
        ax.set_title(
            f"camera {cid}: {image_codes.max() + 1} images, {len(xy)} points,"
            f" {format_coverage(xy, frame):.0%} of the format covered", fontsize=9)
    figure.suptitle(f"{project.spec.name}: image coverage (colour: image)", fontsize=10)
    return figure
