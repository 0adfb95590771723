"""The normalised residuals against the standard normal distribution: histogram and Q-Q plot."""

import math

import numpy as np

from ..._project._build import Project
from ..._statistics._adjustment import Adjustment
from .._collect import group_statistics, is_measurement
from ._base import new_figure


def normalised_residuals(project: Project, result: Adjustment) -> np.ndarray:
    """w (n,) of every measurement the solution used (data-snooping rejections and
    constraints left out), group by group; empty without reliability."""
    parts = [
        stats.w[stats.observed & ~stats.removed & np.isfinite(stats.w)]
        for stats in group_statistics(project, result) if is_measurement(stats.group)
    ]
    return np.concatenate(parts) if parts else np.zeros(0)


def plot_normalised_residuals(project: Project, result: Adjustment):
    """Histogram of the normalised residuals w = v / σ_v with the standard normal density,
    and their normal probability (Q-Q) plot: sorted w against the normal quantiles
    Φ⁻¹((i - 0.5) / n), with the line w = quantile. Dashed red: ± the critical value of the
    data snooping. Under the model w ~ N(0, 1). Returns the matplotlib Figure (two Axes).
    """
    w = normalised_residuals(project, result)
    if result.reliability is None or w.size == 0:
        raise ValueError("no normalised residuals: the result holds no reliability")
    critical = float(result.reliability.critical_value)
    limit = max(4.0, math.ceil(float(np.max(np.abs(w)))), math.ceil(critical))
    figure = new_figure(figsize=(10, 4.2), layout="constrained")
    histogram, quantiles = figure.subplots(1, 2)
    bins = np.linspace(-limit, limit, int(np.clip(2 * limit / 0.25, 16, 80)) + 1)
    histogram.hist(w, bins=bins, density=True, color="tab:blue", alpha=0.6, label="w")
    grid = np.linspace(-limit, limit, 401)
    histogram.plot(grid, np.exp(-0.5 * grid**2) / math.sqrt(2 * math.pi), color="black",
                   linewidth=1.2, label="N(0, 1)")
    for side in (-critical, critical):
        histogram.axvline(side, color="tab:red", linestyle="--", linewidth=0.8)
        quantiles.axhline(side, color="tab:red", linestyle="--", linewidth=0.8)
    histogram.set_xlim(-limit, limit)
    histogram.set_xlabel("normalised residual w", fontsize=8)
    histogram.set_ylabel("density", fontsize=8)
    histogram.legend(fontsize=7)
    histogram.set_title(
        f"n = {w.size}, mean {np.mean(w):.3f}, std {np.std(w):.3f}, |w| > {critical:.2f}:"
        f" {np.count_nonzero(np.abs(w) > critical)}", fontsize=9)
    import scipy.special  # here: not loaded with the public names (0.15 s)

    theoretical = scipy.special.ndtri((np.arange(1, w.size + 1) - 0.5) / w.size)
    quantiles.plot(theoretical, np.sort(w), ".", markersize=3, color="tab:blue")
    span = max(float(np.max(np.abs(theoretical))), 1.0)
    quantiles.plot([-span, span], [-span, span], color="black", linewidth=1.0)
    quantiles.set_xlabel("standard normal quantile", fontsize=8)
    quantiles.set_ylabel("sorted w", fontsize=8)
    quantiles.set_title("normal probability plot (Q-Q)", fontsize=9)
    for ax in (histogram, quantiles):
        ax.tick_params(labelsize=7)
    figure.suptitle(f"{project.spec.name}: normalised residuals", fontsize=10)
    return figure
