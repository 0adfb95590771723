"""jaxba: self-calibrating bundle adjustment in JAX, differentiable and batchable."""

from ._camera import (
    CAMERA_MODELS as CAMERA_MODELS,
)
from ._camera import (
    AbstractCamera as AbstractCamera,
)
from ._camera import (
    AbstractDistortion as AbstractDistortion,
)
from ._camera import (
    AbstractRefraction as AbstractRefraction,
)
from ._camera import (
    Affine as Affine,
)
from ._camera import (
    AtmosphericRefraction as AtmosphericRefraction,
)
from ._camera import (
    DecenteringSmac as DecenteringSmac,
)
from ._camera import (
    NoRefraction as NoRefraction,
)
from ._camera import (
    PixelGrid as PixelGrid,
)
from ._camera import (
    RadialSmac as RadialSmac,
)
from ._camera import (
    SmacCamera as SmacCamera,
)
from ._datum import DatumError as DatumError
from ._datum import check_datum as check_datum
from ._observations import (
    AbstractObservationGroup as AbstractObservationGroup,
)
from ._observations import (
    Distances as Distances,
)
from ._observations import (
    ImagePoints as ImagePoints,
)
from ._observations import (
    ParameterObservations as ParameterObservations,
)
from ._observations import (
    collinearity_residual as collinearity_residual,
)
from ._parameters import (
    IMAGE_PARAMETER_NAMES as IMAGE_PARAMETER_NAMES,
)
from ._parameters import (
    POINT_PARAMETER_NAMES as POINT_PARAMETER_NAMES,
)
from ._parameters import (
    Parameters as Parameters,
)
from ._parameters import (
    flatten as flatten,
)
from ._parameters import (
    parameter_labels as parameter_labels,
)
from ._parameters import (
    unflatten as unflatten,
)
from ._problem import BundleProblem as BundleProblem
from ._project import (
    AdjustmentSettings as AdjustmentSettings,
    Project as Project,
    ProjectError as ProjectError,
    ProjectSpec as ProjectSpec,
    adjust_project as adjust_project,
    build_project as build_project,
    read_project as read_project,
)
from ._progress import Iteration as Iteration
from ._rotation import (
    matrix_to_opk as matrix_to_opk,
)
from ._rotation import (
    matrix_to_quaternion as matrix_to_quaternion,
)
from ._rotation import (
    matrix_to_rodrigues as matrix_to_rodrigues,
)
from ._rotation import (
    opk_to_matrix as opk_to_matrix,
)
from ._rotation import (
    quaternion_to_matrix as quaternion_to_matrix,
)
from ._rotation import (
    quaternion_to_rodrigues as quaternion_to_rodrigues,
)
from ._rotation import (
    rodrigues_to_matrix as rodrigues_to_matrix,
)
from ._rotation import (
    rodrigues_to_quaternion as rodrigues_to_quaternion,
)
from ._solve import Adjustment as Adjustment
from ._solve import NotConvergedError as NotConvergedError
from ._solve import adjust as adjust
from ._synthetic import (
    SyntheticTruth as SyntheticTruth,
    write_synthetic_project as write_synthetic_project,
)
from ._statistics import Precision as Precision
from ._synthetic import (
    SyntheticTruth as SyntheticTruth,
    write_synthetic_project as write_synthetic_project,
)
from ._statistics import precision as precision

__version__ = "0.1.0"
