"""Heat map of the correlation matrix of a camera's estimated IOPs."""

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from .._collect import camera_correlations
from ._base import new_figure


def plot_correlation(result: Adjustment, project: Project, camera_id: str):
    """Heat map of the correlation matrix of the estimated IOPs of one camera.

    ρ_ij = C_ij / (σ_i σ_j) from Cxx = σ̂0² N⁻¹ (`jaxba.camera_correlation`), colours from -1
    (blue) to +1 (red), the value written in every cell. Returns the matplotlib Figure (the
    matrix Axes and its colour bar).
    """
    if camera_id not in project.camera_rows:
        raise ValueError(
            f"unknown camera {camera_id!r}; the adjusted cameras are {list(project.camera_rows)}"
        )
    names, matrix = camera_correlations(project, result)[camera_id]
    if not names:
        raise ValueError(f"camera {camera_id!r} has no estimated parameters")
    n = len(names)
    size = max(4.0, 0.55 * n + 2.0)
    figure = new_figure(figsize=(size + 1.0, size), layout="constrained")
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
