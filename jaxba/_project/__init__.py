"""The project model: a project as its files describe it (`ProjectSpec`, plain Python) and
built into a `BundleProblem` with the IDs that name its rows (`Project`, `build_project`).

Reading and writing the files is io's (`jaxba._io._project`); computing missing
approximations and adjusting a project, the adjust layer's. The specs need no jax; building
is imported when first used.
"""

from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._build": ("Project", "build_project"),
    "._errors": ("ProjectError",),
    "._spec": ("AdjustmentSettings", "ProjectSpec"),
})
