"""jaxba: self-calibrating bundle adjustment in JAX, differentiable and batchable.

Public names are imported from their modules when first used (`jaxba._lazy`), so that
`import jaxba` does not load jax. The parts behind them (plans, the flat vector of unknowns,
the Schur backend's pieces) are in `jaxba.advanced`.
"""

from . import advanced as advanced
from ._lazy import lazy_exports

_public, __dir__, __all__ = lazy_exports(__name__, {
    "._statistics._adjustment": ("Adjustment",),
    "._statistics._by_id": ("ById", "Estimate", "Estimates", "PointEstimate"),
    "._statistics._ids": ("Ids",),
    "._timing": ("Timings",),
    "._approximations": (
        "RELATIVE_ORIENTATION_PARAMETERS", "SIMILARITY_PARAMETERS", "Dlt", "DltOrientation",
        "EssentialMatrix", "Intersection", "RelativeOrientation", "Resection", "Similarity",
        "absolute_orientation", "air_base_from_parallax", "decompose_dlt", "dlt",
        "elevation_from_parallax", "elevation_from_parallax_difference", "essential_matrix",
        "flying_height_from_parallax", "forward_intersection", "ground_from_parallax",
        "relative_orientation", "space_resection", "stereo_parallax",
    ),
    "._io._bal": ("BalFormatError", "BalProblem", "read_bal", "write_bal_project"),
    "._cli._bal": ("run_bal",),
    "._adjust._batch": ("adjust_batch", "check_datum_batch"),
    "._cli._batch_run": ("run_batch",),
    "._models._cameras": (
        "CAMERA_MODELS", "AbstractCamera", "AbstractDistortion", "AbstractRefraction", "Affine",
        "AtmosphericRefraction", "BalCamera", "DecenteringSmac", "FisheyeCamera",
        "MetrologyCamera", "NoRefraction", "OpenCVCamera", "OpenCVFullCamera",
        "PhotoModelerCamera", "PixelGrid", "RadialSmac", "SmacCamera", "metrology_to_smac",
        "smac_to_metrology",
        "AbstractRayRefraction", "CameraModelError", "FlatPort", "RefractedCamera",
    ),
    "._statistics._datum": ("DatumError", "check_datum"),
    "._solvers._solve": ("solve",),
    "._statistics._differentiable": (
        "adjusted", "camera_positions", "covariance", "iop_trace_gradient", "sensitivity",
    ),
    "._statistics._free_network": ("inner_constraints",),
    "._problem._inner_constraints": ("InnerConstraints",),
    "._io": (
        "ColmapModel", "ColmapProject", "DbatProject", "ZhangProject", "read_colmap_model",
        "write_colmap", "write_colmap_project", "write_dbat_project",
        "write_opencv_yaml", "write_project_camera_yaml", "write_zhang_project",
    ),
    "._io._camera_export": ("OpenCVExport", "export_camera_opencv", "fit_opencv"),
    "._adjust._initialise": (
        "BlockInitialisation", "IdealCoordinates", "ideal_coordinates", "image_residuals",
        "initialise_block",
    ),
    "._adjust._montecarlo": ("Replicates", "bootstrap", "monte_carlo"),
    "._problem._observations": (
        "AbstractObservationGroup", "Distances", "ImagePoints", "ParameterObservations",
    ),
    "._problem._parameters": (
        "IMAGE_PARAMETER_NAMES", "POINT_PARAMETER_NAMES", "Parameters", "parameter_labels",
    ),
    "._report._plots": (
        "figure_set", "plot_correlation", "plot_coverage", "plot_distortion",
        "plot_image_residuals", "plot_normalised_residuals", "plot_point_ellipses",
    ),
    "._statistics._derived": (
        "camera_correlation", "correlation", "error_ellipsoids", "full_covariance",
        "point_covariances", "propagate",
    ),
    "._models._poses": ("POSE_MODELS", "AbstractPose", "OpkPose", "RodriguesPose"),
    "._problem._bundle": ("BundleProblem",),
    "._solvers._progress": ("Iteration",),
    "._project": ("AdjustmentSettings", "Project", "ProjectError", "ProjectSpec", "build_project"),
    "._io._project": ("read_project", "write_project"),
    "._adjust._adjust_project": ("adjust_project",),
    "._adjust._complete": ("Completion", "complete_project"),
    "._adjust._deferred": ("Deferral", "adjust_deferred"),
    "._statistics._reliability": ("Reliability", "reliability"),
    "._files._paths": ("OutputError",),
    "._report": ("html_report", "read_observations", "write_reports"),
    "._models._robust": ("RobustLoss",),
    "._models._rotation": (
        "matrix_to_opk", "matrix_to_quaternion", "matrix_to_rodrigues", "opk_to_matrix",
        "quaternion_to_matrix", "quaternion_to_rodrigues", "rodrigues_to_matrix",
        "rodrigues_to_quaternion",
    ),
    "._adjust._adjust": ("NotConvergedError", "adjust"),
    "._solvers._solution": ("Solution",),
    "._adjust._snooping": ("Rejection", "data_snooping", "remove_observation", "restart_from"),
    "._statistics._covariance": ("Precision", "precision"),
    "._io._synthetic": ("SyntheticTruth", "write_synthetic_project"),
    "._io._close_range": ("write_close_range_project",),
    "._adjust._variance_components": ("VarianceComponent", "estimate_variance_components"),
    "._statistics._projection": ("ProjectionUncertainty", "projection_uncertainty"),
    "._statistics._compare": ("Calibration", "Comparison", "calibration_of"),
    "._io._calibration": ("compare", "read_calibration"),
})


def __getattr__(name: str) -> object:
    if name == "__version__":  # one source: pyproject.toml, read from the installed metadata
        from importlib.metadata import version  # when asked: ~35 ms of imports

        globals()[name] = version(__name__)
        return globals()[name]
    if name in advanced.__all__:
        raise AttributeError(f"jaxba.{name} is internal: it is jaxba.advanced.{name}")
    return _public(name)
