"""BAL ("Bundle Adjustment in the Large") problems: reader, camera model, benchmark runner."""

from ._cli import run_bal as run_bal
from ._model import (
    bal_initial as bal_initial,
    bal_project as bal_project,
    bal_residual as bal_residual,
    bal_two_block as bal_two_block,
    rotate_point as rotate_point,
)
from ._reader import (
    CAMERA_PARAMETER_NAMES as CAMERA_PARAMETER_NAMES,
    BalFormatError as BalFormatError,
    BalProblem as BalProblem,
    read_bal as read_bal,
)
