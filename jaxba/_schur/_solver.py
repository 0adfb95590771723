"""Schur-complement Levenberg-Marquardt as an optimistix descent + trust-region solver.

`SchurDampedNewtonDescent` plays the part of `optx.DampedNewtonDescent`: in `query` (once
per accepted iterate) it builds the per-observation Jacobian blocks and the normal
equations; in `step(step_size, ...)` (once per trial step) it solves the damped system
with λ = 1/step_size by the Schur complement. `SchurLevenbergMarquardt` pairs it with
`optx.ClassicalTrustRegion`, as `optx.LevenbergMarquardt` pairs the dense descent, and
is driven by `optx.least_squares` with `two_block_residuals` as `fn`.
"""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, PyTree, Scalar

from .._trust_region import CERES_INITIAL_RADIUS, CERES_TRUST_REGION, silent
from ._normal import NormalEquations, normal_equations, solve_damped
from ._problem import TwoBlockProblem, TwoBlockY, two_block_residuals


class _SchurDescentState(eqx.Module):
    normal: NormalEquations
    cost: Float[Array, ""]  # ½ Σ r² at the last accepted iterate
    converged: Bool[Array, ""]  # the last accepted step changed the cost by < tolerance


class SchurDampedNewtonDescent(
    optx.AbstractDescent[TwoBlockY, optx.FunctionInfo.ResidualJac, _SchurDescentState]
):
    """The damped Newton (Levenberg-Marquardt) step -(JᵀJ + λD)⁻¹ Jᵀr, λ = 1/step_size,
    for a `TwoBlockProblem`, solved by the Schur complement on the point block.

    D is Marquardt's diag(JᵀJ) clamped as Ceres does (`marquardt_diagonal`), which makes
    the step invariant to the units of the unknowns (no separate Jacobi scaling needed).

    The descent holds `problem` because the per-observation Jacobian blocks are not in
    `FunctionInfo.ResidualJac` (a matrix-free operator); the residual function given to
    `optx.least_squares` must be `two_block_residuals` with the same problem as args.

    `initial_radius` scales the trust region: λ = 1 / (initial_radius · step_size), and
    optx's trust region starts at step_size 1 (1.0: exactly optx's λ = 1/step_size).

    Function tolerance (Ceres' `function_tolerance`): once an accepted step changed the
    cost by less than `function_tolerance` times the previous cost, the descent proposes
    the zero step; optimistix evaluates it, accepts it, and its Cauchy test (zero change
    in y and in the residuals) ends the solve as converged. 0 disables this.
    """

    problem: TwoBlockProblem
    min_diagonal: float = 1e-6
    max_diagonal: float = 1e32
    function_tolerance: float = 0.0
    initial_radius: float = 1.0

    def init(
        self, y: TwoBlockY, f_info_struct: optx.FunctionInfo.ResidualJac
    ) -> _SchurDescentState:
        shapes = jax.eval_shape(self._normal_equations, y, f_info_struct.residual)
        normal = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        cost = jnp.array(jnp.inf, f_info_struct.residual.dtype)
        return _SchurDescentState(normal, cost, jnp.array(False))

    def query(
        self,
        y: TwoBlockY,
        f_info: optx.FunctionInfo.ResidualJac,
        state: _SchurDescentState,
    ) -> _SchurDescentState:
        cost = f_info.as_min()
        change = jnp.abs(state.cost - cost)
        converged = jnp.isfinite(state.cost) & (change <= self.function_tolerance * state.cost)
        return _SchurDescentState(self._normal_equations(y, f_info.residual), cost, converged)

    def step(self, step_size: Scalar, state: _SchurDescentState) -> tuple[TwoBlockY, optx.RESULTS]:
        # As optx.DampedNewtonDescent: λ = 1/radius, "infinite" for a vanishing step size;
        # the trust region starts at step_size 1, i.e. radius = initial_radius.
        usable = step_size > jnp.finfo(step_size.dtype).eps
        radius = self.initial_radius * jnp.where(usable, step_size, 1.0)
        damping = jnp.where(usable, 1.0 / radius, jnp.finfo(step_size.dtype).max)
        camera_step, point_step = solve_damped(self.problem, state.normal, damping)
        y_diff = jax.tree.map(
            lambda x: jnp.where(state.converged, 0.0, -x), (camera_step, point_step)
        )
        return y_diff, optx.RESULTS.successful

    def _normal_equations(self, y: TwoBlockY, residual: Array) -> NormalEquations:
        return normal_equations(self.problem, y, residual, self.min_diagonal, self.max_diagonal)


class SchurLevenbergMarquardt(optx.AbstractGaussNewton[TwoBlockY, Array, Any]):
    """Levenberg-Marquardt for two-block (bundle-adjustment) problems, Schur-complement step.

    `optx.LevenbergMarquardt` with `SchurDampedNewtonDescent` in place of the dense QR
    descent: memory O(n_obs + (n_cameras n_c)²) instead of a dense Jacobian. Use with
    `optx.least_squares(two_block_residuals, solver, y0, args=problem)` (or
    `solve_two_block`), y0 = (cameras (n_cameras, n_c), points (n_points, n_p)).

    Arguments: `problem`; `rtol`, `atol`: optimistix's Cauchy termination (both the
    step and the residual change small, elementwise, in `norm`); `function_tolerance`:
    also stop once an accepted step changes the cost by less than this fraction (Ceres'
    criterion; 0 = off); `min_diagonal`, `max_diagonal`: damping clamps (Ceres'
    defaults); `initial_radius`: first trust-region radius 1/λ (Ceres' default 1e4;
    from 1, Dubrovnik-16 takes 19 steps instead of 9); `search`: the trust-region update
    (default `CERES_TRUST_REGION`);
    `verbose`: False, or a callable `**info -> None` as for optimistix solvers (see
    `jaxba._progress.report_step`).
    """

    rtol: float
    atol: float
    norm: Callable[[PyTree], Scalar]
    descent: SchurDampedNewtonDescent
    search: optx.ClassicalTrustRegion
    verbose: Callable[..., None]

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
        search: optx.ClassicalTrustRegion = CERES_TRUST_REGION,
        verbose: bool | Callable[..., None] = False,
    ):
        if verbose is True:
            raise ValueError("verbose must be False or a callable **info -> None")
        if function_tolerance > 0 and atol <= 0:
            raise ValueError(
                "function_tolerance needs atol > 0 (the zero step must test as converged)"
            )
        self.rtol = rtol
        self.atol = atol
        self.norm = norm
        self.descent = SchurDampedNewtonDescent(
            problem, min_diagonal, max_diagonal, function_tolerance, initial_radius
        )
        self.search = search
        self.verbose = verbose if verbose else silent


def solve_two_block(
    problem: TwoBlockProblem,
    y0: TwoBlockY,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    function_tolerance: float = 0.0,
    max_steps: int = 100,
    verbose: Callable[..., None] | None = None,
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
        verbose=verbose or False,
    )
    return optx.least_squares(
        two_block_residuals, solver, y0, args=problem, max_steps=max_steps, throw=throw
    )
