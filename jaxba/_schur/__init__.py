"""Schur-complement Levenberg-Marquardt for two-block (bundle-adjustment) least squares."""

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
from ._normal import (
    NormalEquations as NormalEquations,
    marquardt_diagonal as marquardt_diagonal,
    normal_equations as normal_equations,
    solve_damped as solve_damped,
)
from ._problem import (
    TwoBlockProblem as TwoBlockProblem,
    TwoBlockY as TwoBlockY,
    two_block_residuals as two_block_residuals,
)
from ._reliability import schur_redundancy_numbers as schur_redundancy_numbers
from ._solver import (
    SchurDampedNewtonDescent as SchurDampedNewtonDescent,
    SchurLevenbergMarquardt as SchurLevenbergMarquardt,
    solve_two_block as solve_two_block,
)
