"""Maps over a sensor (projection uncertainty, the difference of two calibrations) and σ along
one pixel's ray against distance."""

import numpy as np

from ._base import new_figure


def plot_sensor_map(pixels: np.ndarray, values: np.ndarray, sensor: tuple[int, int], *,
                    title: str, label: str, observed: np.ndarray | None = None):
    """Heat map with contours of `values` (n,) on a regular grid of `pixels` (n, 2) (col,
    row; columns varying fastest, as `sensor_grid` makes them) over a sensor (ncols, nrows),
    row down, with the points `observed` (m, 2) pixels overlaid. Returns the Figure."""
    cols, rows = np.unique(pixels[:, 0]), np.unique(pixels[:, 1])
    grid = np.asarray(values, dtype=float).reshape(rows.size, cols.size)
    width, height = sensor
    figure = new_figure(figsize=(7.0, 7.0 * height / width + 0.8), layout="constrained")
    ax = figure.subplots()
    finite = grid[np.isfinite(grid)]
    top = float(np.percentile(finite, 95)) if finite.size else 1.0
    image = ax.imshow(grid, extent=(cols[0], cols[-1], rows[-1], rows[0]), cmap="viridis",
                      vmin=0.0, vmax=top if top > 0 else 1.0, interpolation="bilinear")
    if finite.size and np.ptp(finite) > 0:
        levels = np.unique(np.round(np.linspace(finite.min(), top, 7)[1:], 12))
        contours = ax.contour(cols, rows, grid, levels=levels, colors="white", linewidths=0.7)
        ax.clabel(contours, fontsize=7, fmt="%.3g")
    if observed is not None and len(observed):
        ax.plot(observed[:, 0], observed[:, 1], ",", color="red", alpha=0.6)
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.set_title(title)
    figure.colorbar(image, ax=ax, shrink=0.8, label=label)
    return figure


def plot_sigma_along_ray(distances: np.ndarray, worst: np.ndarray, rms: np.ndarray, *,
                         title: str, unit: str = "px", observed: np.ndarray | None = None):
    """σ in the worst direction and RMS σ (`unit`) of one pixel against the distance along
    its ray (object units, log scale); `observed`: distances of the calibration's points
    from the camera, shown as a rug. Returns the Figure."""
    figure = new_figure(figsize=(7.0, 4.0), layout="constrained")
    ax = figure.subplots()
    ax.plot(distances, worst, label="worst direction")
    ax.plot(distances, rms, label="RMS", linestyle="--")
    if observed is not None and len(observed):
        ax.plot(observed, np.zeros_like(observed), "|", color="red", alpha=0.4,
                label="calibration points")
    ax.set_xscale("log")
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("distance along the ray (object units)")
    ax.set_ylabel(f"σ ({unit})")
    ax.set_title(title)
    ax.legend()
    return figure
