"""The figures of a project's report: what `jaxba adjust --plots` writes and the HTML
report embeds, each under a file name and a title."""

import dataclasses
from collections.abc import Callable

import numpy as np

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from ._correlation import plot_correlation
from ._coverage import plot_coverage
from ._distortion import distorted_cameras, plot_distortion
from ._ellipses import plot_point_ellipses
from ._normal import plot_normalised_residuals
from ._residuals import plot_image_residuals


@dataclasses.dataclass(frozen=True)
class ReportFigure:
    """`name`: the file name without ".png"; `make()` draws the matplotlib Figure."""

    name: str
    title: str
    make: Callable[[], object]


def _file_part(camera_id: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in camera_id)


def figure_set(project: Project, result: Adjustment) -> list[ReportFigure]:
    """The report's figures, in reading order: residual vectors (residuals), normalised
    residuals (where the result holds reliability), image coverage (coverage), the distortion
    curves of each camera with an estimated radial or decentering term (distortion_<camera>),
    the IOP correlations of each camera with an estimated parameter (correlation_<camera>)
    and the point error ellipses (point_ellipses, where a point is estimated). Nothing is
    drawn until `make` is called."""
    figures = [ReportFigure("residuals", "Image residuals",
                            lambda: plot_image_residuals(project, result))]
    if result.reliability is not None:
        figures.append(ReportFigure("normalised_residuals", "Normalised residuals",
                                    lambda: plot_normalised_residuals(project, result)))
    figures.append(ReportFigure("coverage", "Image coverage",
                                lambda: plot_coverage(project, result)))
    for cid in distorted_cameras(project):
        figures.append(ReportFigure(f"distortion_{_file_part(cid)}", f"Distortion of camera {cid}",
                                    lambda cid=cid: plot_distortion(project, result, cid)))
    for cid, (model, row) in project.camera_rows.items():
        if bool(np.asarray(project.problem.free.cameras[model][row]).any()):
            figures.append(ReportFigure(
                f"correlation_{_file_part(cid)}", f"IOP correlations of camera {cid}",
                lambda cid=cid: plot_correlation(result, project, cid)))
    if np.asarray(project.problem.free.points).any():
        figures.append(ReportFigure("point_ellipses", "Point error ellipses",
                                    lambda: plot_point_ellipses(project, result)))
    return figures
