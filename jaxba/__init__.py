"""jaxba: self-calibrating bundle adjustment in JAX, differentiable and batchable.

Public names are imported from their modules when first used (`jaxba._lazy`), so that
`import jaxba` does not load jax.
"""

from importlib.metadata import version as _distribution_version

from ._lazy import lazy_exports

__version__ = _distribution_version(__name__)  # one source: pyproject.toml

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._adjustment": ("Adjustment",),
    "._approximations": (
        "RELATIVE_ORIENTATION_PARAMETERS", "SIMILARITY_PARAMETERS", "Dlt", "DltOrientation",
        "EssentialMatrix", "Intersection", "RelativeOrientation", "Resection", "Similarity",
        "absolute_orientation", "air_base_from_parallax", "decompose_dlt", "dlt",
        "elevation_from_parallax", "elevation_from_parallax_difference", "essential_matrix",
        "flying_height_from_parallax", "forward_intersection", "ground_from_parallax",
        "relative_orientation", "space_resection", "stereo_parallax",
    ),
    "._bal": ("BalFormatError", "BalProblem", "read_bal"),
    "._bal._cli": ("run_bal",),
    "._batch": (
        "PaddedBatch", "adjust_batch", "broadcast_plan", "check_datum_batch", "pad_problems",
        "solve_batch",
    ),
    "._batch_run": ("run_batch",),
    "._camera": (
        "CAMERA_MODELS", "AbstractCamera", "AbstractDistortion", "AbstractRefraction", "Affine",
        "AtmosphericRefraction", "BalCamera", "DecenteringSmac", "FisheyeCamera",
        "MetrologyCamera", "NoRefraction", "OpenCVCamera", "PhotoModelerCamera", "PixelGrid",
        "RadialSmac", "SmacCamera", "metrology_to_smac", "smac_to_metrology",
    ),
    "._datum": ("DatumError", "check_datum"),
    "._dense": ("solve",),
    "._differentiable": (
        "adjusted", "camera_positions", "covariance", "iop_trace_gradient", "sensitivity",
    ),
    "._free_network": ("InnerConstraints", "inner_constraints"),
    "._io": (
        "read_colmap_model", "write_colmap", "write_colmap_project", "write_dbat_project",
        "write_opencv_yaml", "write_project_camera_yaml", "write_zhang_project",
    ),
    "._initialise": (
        "BlockInitialisation", "IdealCoordinates", "ideal_coordinates", "image_residuals",
        "initialise_block",
    ),
    "._levenberg_marquardt": ("NormalLevenbergMarquardt",),
    "._linearisation": ("LinearisationPlan", "linearisation_plan", "pad_plans"),
    "._montecarlo": ("Replicates", "bootstrap", "monte_carlo"),
    "._observations": (
        "AbstractObservationGroup", "Distances", "ImagePoints", "ParameterObservations",
        "collinearity_residual",
    ),
    "._parameters": (
        "IMAGE_PARAMETER_NAMES", "POINT_PARAMETER_NAMES", "Parameters", "flatten",
        "parameter_labels", "unflatten",
    ),
    "._plots": ("plot_correlation", "plot_image_residuals"),
    "._precision": (
        "camera_correlation", "correlation", "error_ellipsoids", "full_covariance",
        "point_covariances", "propagate",
    ),
    "._pose": ("POSE_MODELS", "AbstractPose", "OpkPose", "RodriguesPose"),
    "._problem": ("BundleProblem", "free_indices"),
    "._progress": ("Iteration",),
    "._project": ("AdjustmentSettings", "ProjectError", "ProjectSpec", "read_project"),
    "._project._adjust": ("adjust_project",),
    "._project._build": ("Project", "build_project"),
    "._reliability": ("Reliability", "reliability"),
    "._report": ("OutputError", "read_observations", "write_reports"),
    "._robust": ("RobustLoss",),
    "._rotation": (
        "matrix_to_opk", "matrix_to_quaternion", "matrix_to_rodrigues", "opk_to_matrix",
        "quaternion_to_matrix", "quaternion_to_rodrigues", "rodrigues_to_matrix",
        "rodrigues_to_quaternion",
    ),
    "._schur._bundle": ("BundleCofactors", "schur_cofactors", "schur_precision", "solve_schur"),
    "._schur._datum": ("check_datum_schur",),
    "._schur._reliability": ("schur_redundancy_numbers",),
    "._solve": ("NotConvergedError", "adjust"),
    "._solution": ("Solution",),
    "._snooping": ("Rejection", "data_snooping", "remove_observation", "restart_from"),
    "._statistics": ("Precision", "precision"),
    "._synthetic": ("SyntheticTruth", "write_synthetic_project"),
    "._variance_components": ("VarianceComponent", "estimate_variance_components"),
})
