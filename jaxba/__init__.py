"""jaxba: self-calibrating bundle adjustment in JAX, differentiable and batchable."""

from ._bal import (
    BalFormatError as BalFormatError,
    BalProblem as BalProblem,
    read_bal as read_bal,
    run_bal as run_bal,
)
from ._batch import (
    PaddedBatch as PaddedBatch,
    adjust_batch as adjust_batch,
    broadcast_plan as broadcast_plan,
    check_datum_batch as check_datum_batch,
    pad_problems as pad_problems,
    solve_batch as solve_batch,
)
from ._batch_run import run_batch as run_batch
from ._camera import (
    CAMERA_MODELS as CAMERA_MODELS,
    AbstractCamera as AbstractCamera,
    AbstractDistortion as AbstractDistortion,
    AbstractRefraction as AbstractRefraction,
    Affine as Affine,
    AtmosphericRefraction as AtmosphericRefraction,
    BalCamera as BalCamera,
    DecenteringSmac as DecenteringSmac,
    FisheyeCamera as FisheyeCamera,
    NoRefraction as NoRefraction,
    OpenCVCamera as OpenCVCamera,
    PhotoModelerCamera as PhotoModelerCamera,
    PixelGrid as PixelGrid,
    RadialSmac as RadialSmac,
    SmacCamera as SmacCamera,
)
from ._datum import DatumError as DatumError, check_datum as check_datum
from ._differentiable import (
    adjusted as adjusted,
    covariance as covariance,
    iop_trace_gradient as iop_trace_gradient,
    sensitivity as sensitivity,
)
from ._free_network import (
    InnerConstraints as InnerConstraints,
    inner_constraints as inner_constraints,
)
from ._io import (
    read_colmap_model as read_colmap_model,
    write_colmap as write_colmap,
    write_colmap_project as write_colmap_project,
    write_dbat_project as write_dbat_project,
    write_opencv_yaml as write_opencv_yaml,
    write_project_camera_yaml as write_project_camera_yaml,
    write_zhang_project as write_zhang_project,
)
from ._levenberg_marquardt import NormalLevenbergMarquardt as NormalLevenbergMarquardt
from ._linearisation import (
    LinearisationPlan as LinearisationPlan,
    linearisation_plan as linearisation_plan,
    pad_plans as pad_plans,
)
from ._montecarlo import (
    Replicates as Replicates,
    bootstrap as bootstrap,
    monte_carlo as monte_carlo,
)
from ._observations import (
    AbstractObservationGroup as AbstractObservationGroup,
    Distances as Distances,
    ImagePoints as ImagePoints,
    ParameterObservations as ParameterObservations,
    collinearity_residual as collinearity_residual,
)
from ._parameters import (
    IMAGE_PARAMETER_NAMES as IMAGE_PARAMETER_NAMES,
    POINT_PARAMETER_NAMES as POINT_PARAMETER_NAMES,
    Parameters as Parameters,
    flatten as flatten,
    parameter_labels as parameter_labels,
    unflatten as unflatten,
)
from ._plots import (
    plot_correlation as plot_correlation,
    plot_image_residuals as plot_image_residuals,
)
from ._precision import (
    camera_correlation as camera_correlation,
    correlation as correlation,
    error_ellipsoids as error_ellipsoids,
    full_covariance as full_covariance,
    point_covariances as point_covariances,
    propagate as propagate,
)
from ._problem import BundleProblem as BundleProblem, free_indices as free_indices
from ._progress import Iteration as Iteration
from ._project import (
    AdjustmentSettings as AdjustmentSettings,
    Project as Project,
    ProjectError as ProjectError,
    ProjectSpec as ProjectSpec,
    adjust_project as adjust_project,
    build_project as build_project,
    read_project as read_project,
)
from ._reliability import (
    Rejection as Rejection,
    Reliability as Reliability,
    data_snooping as data_snooping,
    reliability as reliability,
    remove_observation as remove_observation,
    restart_from as restart_from,
)
from ._report import (
    OutputError as OutputError,
    read_observations as read_observations,
    write_reports as write_reports,
)
from ._robust import RobustLoss as RobustLoss
from ._rotation import (
    matrix_to_opk as matrix_to_opk,
    matrix_to_quaternion as matrix_to_quaternion,
    matrix_to_rodrigues as matrix_to_rodrigues,
    opk_to_matrix as opk_to_matrix,
    quaternion_to_matrix as quaternion_to_matrix,
    quaternion_to_rodrigues as quaternion_to_rodrigues,
    rodrigues_to_matrix as rodrigues_to_matrix,
    rodrigues_to_quaternion as rodrigues_to_quaternion,
)
from ._schur import (
    BundleCofactors as BundleCofactors,
    SchurDampedNewtonDescent as SchurDampedNewtonDescent,
    SchurLevenbergMarquardt as SchurLevenbergMarquardt,
    TwoBlockProblem as TwoBlockProblem,
    check_datum_schur as check_datum_schur,
    schur_cofactors as schur_cofactors,
    schur_precision as schur_precision,
    schur_redundancy_numbers as schur_redundancy_numbers,
    solve_schur as solve_schur,
    solve_two_block as solve_two_block,
    two_block_residuals as two_block_residuals,
)
from ._solve import (
    Adjustment as Adjustment,
    NotConvergedError as NotConvergedError,
    Solution as Solution,
    adjust as adjust,
    solve as solve,
)
from ._statistics import Precision as Precision, precision as precision
from ._synthetic import (
    SyntheticTruth as SyntheticTruth,
    write_synthetic_project as write_synthetic_project,
)
from ._variance_components import (
    VarianceComponent as VarianceComponent,
    estimate_variance_components as estimate_variance_components,
)

__version__ = "0.1.0"
