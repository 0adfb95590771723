"""BAL ("Bundle Adjustment in the Large") problems: reader and BundleProblem.

The reader needs no jax; the rest is imported when first used.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._model": ("bal_bundle",),
    "._project": ("BalProject", "write_bal_project"),
    "._reader": ("CAMERA_PARAMETER_NAMES", "BalFormatError", "BalProblem", "read_bal"),
})
