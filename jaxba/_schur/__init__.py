"""The Schur backend: Levenberg-Marquardt and statistics of a `BundleProblem` with the object
points eliminated (reduced camera matrix assembled pair-wise)."""

from ._bundle import (
    BundleCofactors as BundleCofactors,
    bundle_structure as bundle_structure,
    schur_cofactors as schur_cofactors,
    schur_precision as schur_precision,
    schur_solve as schur_solve,
    solve_schur as solve_schur,
)
from ._choice import SCHUR_MIN_UNKNOWNS as SCHUR_MIN_UNKNOWNS, use_schur as use_schur
from ._datum import check_datum_schur as check_datum_schur
from ._normal import marquardt_diagonal as marquardt_diagonal
from ._reliability import schur_redundancy_numbers as schur_redundancy_numbers
