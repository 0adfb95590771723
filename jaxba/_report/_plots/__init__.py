"""Plots of an adjusted project, as matplotlib Figures (no pyplot state, no display).

Residual vectors per image, the IOP correlation matrix, distortion curves with 1σ bands,
normalised residuals against N(0, 1), image coverage and point error ellipses; `figure_set`
names the set `jaxba adjust --plots` writes and the HTML report embeds.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._correlation": ("plot_correlation",),
    "._coverage": ("plot_coverage",),
    "._distortion": ("plot_distortion",),
    "._ellipses": ("plot_point_ellipses",),
    "._normal": ("plot_normalised_residuals",),
    "._residuals": ("plot_image_residuals",),
    "._set": ("figure_set",),
    "._uncertainty": ("plot_sensor_map", "plot_sigma_along_ray"),
})
