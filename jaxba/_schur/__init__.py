"""Schur-complement Levenberg-Marquardt for two-block (bundle-adjustment) least squares."""

from ._bundle import (
    BundleCofactors as BundleCofactors,
    bundle_structure as bundle_structure,
    schur_cofactors as schur_cofactors,
    solve_schur as solve_schur,
)
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
from ._solver import (
    SchurDampedNewtonDescent as SchurDampedNewtonDescent,
    SchurLevenbergMarquardt as SchurLevenbergMarquardt,
    solve_two_block as solve_two_block,
)
