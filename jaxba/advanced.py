"""The parts behind jaxba's public calls, for work on the engine: linearisation plans and
padding for `jit`/`vmap`, the flat vector of unknowns, the Schur backend's pieces, the optimistix
solver and the residual of one image point. Imported from their modules when first used, as
`jaxba` (`jaxba._lazy`; absolute module names: this is a module, not a package)."""

from ._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "jaxba._adjust._batch": ("solve_batch",),
    "jaxba._adjust._padding": ("PaddedBatch", "broadcast_plan", "pad_problems"),
    "jaxba._models._board_warp": ("board_extent", "warp_shape"),
    "jaxba._problem._bundle": ("free_indices",),
    "jaxba._problem._linearisation": ("LinearisationPlan", "linearisation_plan", "pad_plans"),
    "jaxba._problem._observations": ("collinearity_residual",),
    "jaxba._problem._parameters": ("flatten", "unflatten"),
    "jaxba._solvers._dense": ("Dense",),
    "jaxba._solvers._levenberg_marquardt": ("NormalLevenbergMarquardt",),
    "jaxba._solvers._schur._descent": ("Schur",),
    "jaxba._solvers._solve": ("choose_backend",),
    "jaxba._statistics._covariance": (
        "BundleCofactors", "SchurCovariance", "schur_cofactors", "schur_precision",
    ),
    "jaxba._statistics._datum": ("check_datum_schur",),
    "jaxba._statistics._reliability": ("schur_redundancy_numbers",),
})
