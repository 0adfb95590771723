"""Writing files safely, used by the readers' writers, the reports and the command line: the
output checks (`check_folder`, `check_targets`, `OutputError`), the output folder's lock
(`output_lock`) and `replace_files` (all or nothing). Plain Python, no jax."""

from ._atomic import replace_files
from ._lock import output_lock
from ._paths import OutputError, check_folder, check_targets, resolved

__all__ = ["OutputError", "check_folder", "check_targets", "output_lock", "replace_files",
           "resolved"]
