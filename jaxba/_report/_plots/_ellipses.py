"""Error ellipses of the object points in plan (X-Y) and elevation (X-Z), magnified."""

import numpy as np

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from ..._statistics._derived import point_covariances
from ._base import new_figure, nice

VIEWS = {"plan": (0, 1), "elevation": (0, 2)}  # coordinates drawn: X-Y and X-Z
_SIZE_FRACTION = 0.05  # auto scale: the largest semi-axis is drawn this fraction of the extent


def ellipses_2d(covariances: np.ndarray, axes: tuple[int, int]):
    """1σ error ellipses of the 2 x 2 marginals (`axes`) of `covariances` (n, 3, 3): semi-axes
    (n, 2), major first, and the angle of the major axis from the first coordinate towards
    the second (n,), degrees."""
    marginal = covariances[:, axes][:, :, axes]
    eigenvalues, eigenvectors = np.linalg.eigh(marginal)  # ascending
    semi = np.sqrt(np.clip(eigenvalues[:, ::-1], 0, None))
    major = eigenvectors[:, :, 1]
    return semi, np.degrees(np.arctan2(major[:, 1], major[:, 0]))


def plot_point_ellipses(project: Project, result: Adjustment, *, scale: float | None = None):
    """1σ error ellipses of the estimated object points in plan (X-Y) and elevation (X-Z),
    drawn `scale` times their size (None: a round factor that draws the largest semi-axis at
    about 5 % of the extent of the points); a bar below shows a round σ at that scale.
    Points with all coordinates fixed: black triangles; camera stations: grey squares.
    Returns the matplotlib Figure (two Axes)."""
    from matplotlib.collections import EllipseCollection

    covariances = point_covariances(result)
    xyz = np.asarray(result.parameters.points, dtype=float)
    free = np.asarray(project.problem.free.points).any(axis=1)
    stations = np.asarray(result.parameters.images, dtype=float)[:, :3]
    views = {name: ellipses_2d(covariances[free], axes) for name, axes in VIEWS.items()}
    largest = max((float(np.nanmax(semi)) for semi, _ in views.values() if semi.size),
                  default=0.0)
    if scale is None:
        extent = float(np.max(np.ptp(xyz, axis=0))) if len(xyz) else 1.0
        scale = nice(_SIZE_FRACTION * extent / largest) if largest > 0 else 1.0
    figure = new_figure(figsize=(11, 5.2), layout="constrained")
    for ax, (name, (i, j)) in zip(figure.subplots(1, 2), VIEWS.items()):
        semi, angle = views[name]
        ax.add_collection(EllipseCollection(
            2 * scale * semi[:, 0], 2 * scale * semi[:, 1], angle, units="xy",
            offsets=xyz[free][:, [i, j]], offset_transform=ax.transData,
            facecolors="none", edgecolors="tab:blue", linewidths=0.8))
        ax.plot(xyz[free, i], xyz[free, j], ".", color="tab:blue", markersize=2)
        ax.plot(xyz[~free, i], xyz[~free, j], "^", color="black", markersize=5,
                label="fixed points")
        ax.plot(stations[:, i], stations[:, j], "s", color="0.6", markersize=4,
                label="camera stations")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("X (object units)", fontsize=8)
        ax.set_ylabel(f"{'YZ'[j - 1]} (object units)", fontsize=8)
        ax.set_title(f"{name} ({'X-Y' if j == 1 else 'X-Z'})", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7, loc="upper right")
        ax.autoscale_view()
        if largest > 0:
            _scale_bar(ax, nice(largest), scale)
    figure.suptitle(f"{project.spec.name}: 1σ error ellipses of the object points, drawn"
                    f" x {scale:g} (object units)", fontsize=10)
    return figure


def _scale_bar(ax, sigma: float, scale: float) -> None:
    """A bar of length σ · scale (data units) in the lower left corner, labelled "σ = ..."."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    ax.add_artist(AnchoredSizeBar(ax.transData, sigma * scale, f"σ = {sigma:g}", "lower left",
                                  frameon=False, size_vertical=0, fontproperties={"size": 7}))
