"""Schur-complement Levenberg-Marquardt: a descent for jaxba's optimistix trust-region loop.

`SchurDampedNewtonDescent` does, in `query` (once per accepted iterate), the per-observation
Jacobian blocks and the normal equations, and in `step(radius, ...)` (once per trial step)
the damped solve with λ = 1/radius by the Schur complement. `SchurLevenbergMarquardt` runs
it in `_trust_region.LevenbergMarquardt`, driven by `optx.least_squares` with
`two_block_residuals` as `fn`.
"""

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, PyTree, Scalar

from .._trust_region import (
    CERES_INITIAL_RADIUS,
    AbstractNormalDescent,
    LevenbergMarquardt,
    TrustRegionUpdate,
    normal_equations_result,
)
from ._normal import NormalEquations, normal_equations, predicted_reduction, solve_damped
from ._problem import TwoBlockProblem, TwoBlockY, two_block_residuals

# The normal equations of the last accepted point and whether they are finite (checked once
# there, not at every trial step).
_CheckedNormal = tuple[NormalEquations, optx.RESULTS]


class SchurDampedNewtonDescent(AbstractNormalDescent[TwoBlockY, _CheckedNormal]):
    """The damped Newton (Levenberg-Marquardt) step -(JᵀJ + λD)⁻¹ Jᵀr, λ = 1/radius,
    for a `TwoBlockProblem`, solved by the Schur complement on the point block.

    D is Marquardt's diag(JᵀJ) clamped as Ceres does (`marquardt_diagonal`), which makes
    the step invariant to the units of the unknowns (no separate Jacobi scaling needed).

    The descent holds `problem`: the residual function given to `optx.least_squares` must
    be `two_block_residuals` with the same problem as args.
    """

    problem: TwoBlockProblem
    min_diagonal: float = 1e-6
    max_diagonal: float = 1e32

    def init(self, y: TwoBlockY, residual: Array) -> _CheckedNormal:
        shapes = jax.eval_shape(self._normal_equations, y, residual)
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes), optx.RESULTS.successful

    def query(self, y: TwoBlockY, residual: Array, state: _CheckedNormal) -> _CheckedNormal:
        del state
        normal = self._normal_equations(y, residual)
        return normal, normal_equations_result(normal)

    def step(self, radius: Scalar, state: _CheckedNormal) -> tuple[TwoBlockY, optx.RESULTS]:
        normal, result = state
        camera_step, point_step = solve_damped(self.problem, normal, 1.0 / radius)
        return (-camera_step, -point_step), result

    def predicted_reduction(self, y_diff: TwoBlockY, state: _CheckedNormal) -> Scalar:
        return predicted_reduction(self.problem, state[0], y_diff)

    def _normal_equations(self, y: TwoBlockY, residual: Array) -> NormalEquations:
        return normal_equations(self.problem, y, residual, self.min_diagonal, self.max_diagonal)


class SchurLevenbergMarquardt(LevenbergMarquardt):
    """Levenberg-Marquardt for two-block (bundle-adjustment) problems, Schur-complement step:
    memory O(n_obs + (n_cameras n_c)²) instead of a dense Jacobian. Use with
    `optx.least_squares(two_block_residuals, solver, y0, args=problem)` (or
    `solve_two_block`), y0 = (cameras (n_cameras, n_c), points (n_points, n_p)).

    Arguments: `problem`; `rtol`, `atol`: optimistix's Cauchy termination (both the
    step and the residual change small, elementwise, in `norm`); `function_tolerance`:
    also stop once an accepted step changes the cost by less than this fraction (Ceres'
    criterion; 0 = off); `min_diagonal`, `max_diagonal`: damping clamps (Ceres'
    defaults); `initial_radius`: first trust-region radius 1/λ (Ceres' default 1e4;
    from 1, Dubrovnik-16 takes 19 steps instead of 9); `update`: the trust-region rule
    (default Ceres').
    """

    def __init__(
        self,
        problem: TwoBlockProblem,
        rtol: float,
        atol: float,
        *,
        function_tolerance: float = 0.0,
        norm: Callable[[PyTree], Scalar] = optx.max_norm,
        min_diagonal: float = 1e-6,
        max_diagonal: float = 1e32,
        initial_radius: float = CERES_INITIAL_RADIUS,
        update: TrustRegionUpdate = TrustRegionUpdate(),
    ):
        descent = SchurDampedNewtonDescent(problem, min_diagonal, max_diagonal)
        super().__init__(rtol, atol, descent, norm=norm, function_tolerance=function_tolerance,
                         initial_radius=initial_radius, update=update)


def solve_two_block(
    problem: TwoBlockProblem,
    y0: TwoBlockY,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    function_tolerance: float = 0.0,
    max_steps: int = 100,
    throw: bool = False,
) -> optx.Solution:
    """Minimise ½ Σ |residuals|² of `problem` from `y0` with `SchurLevenbergMarquardt`.

    Returns the `optx.Solution` (value = (cameras, points), `stats["num_steps"]`, `result`).
    """
    solver = SchurLevenbergMarquardt(
        problem,
        rtol=rtol,
        atol=atol,
        function_tolerance=function_tolerance,
    )
    return optx.least_squares(
        two_block_residuals, solver, y0, args=problem, max_steps=max_steps, throw=throw
    )
