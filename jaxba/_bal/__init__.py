"""BAL ("Bundle Adjustment in the Large") problems: reader, camera model, benchmark runner.

The reader needs no jax; the rest is imported when first used.
"""

from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._cli": ("run_bal",),
    "._model": ("bal_initial", "bal_project", "bal_residual", "bal_two_block", "rotate_point"),
    "._reader": ("CAMERA_PARAMETER_NAMES", "BalFormatError", "BalProblem", "read_bal"),
})
