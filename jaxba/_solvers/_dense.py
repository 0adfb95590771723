"""The Dense backend's solve: Levenberg-Marquardt on the normal equations of all free unknowns."""

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float

from .._problem._bundle import BundleProblem, params_from_scaled
from .._problem._linearisation import LinearisationPlan, linearisation_plan, normal_equations
from ._levenberg_marquardt import UNBATCHED_BLOCK, NormalLevenbergMarquardt
from ._solution import Solution
from ._steps import StepInfo, least_squares_stepwise
from ._trust_region import STEP_TOLERANCE


def _residual_fn(z, args):
    problem, index, scale = args
    return problem.residuals(params_from_scaled(problem, z, index, scale)), None


def column_scale(problem: BundleProblem, plan: LinearisationPlan) -> Float[Array, " n_free"]:
    """Jacobi scaling: 1/‖column‖ of the residuals' Jacobian at the approximations.

    The solver works on z with x_free = x_free,0 + scale ⊙ z, so every column has unit
    norm at the start and the Levenberg-Marquardt damping λI treats all unknowns alike.
    Masked residual entries are exactly 0 and add nothing to the norms.
    """
    norms = jnp.sqrt(jnp.diag(normal_equations(problem, problem.initial, plan)[0]))
    return 1.0 / jnp.where(norms > 0, norms, 1.0)


def solve(
    problem: BundleProblem,
    plan: LinearisationPlan | None = None,
    *,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    step_tolerance: float = STEP_TOLERANCE,
    on_step: Callable[[StepInfo], None] | None = None,
) -> Solution:
    """Levenberg-Marquardt on the Jacobi-scaled free unknowns (`NormalLevenbergMarquardt`).

    Converged at an accepted iterate from which the Gauss-Newton step would move every
    unknown by less than `step_tolerance` of its σ (gᵀN⁻¹g ≤ τ², `jaxba._solvers._trust_region`,
    with its Gauss-Newton steps; 0: both off), or where optimistix's Cauchy test passes
    (step and residual change within `rtol`, `atol`, elementwise, in the scaled unknowns),
    or when every step from it is rejected down to the trust region's minimum radius.
    No datum check, no statistics. Without `on_step` the whole solve is one compiled
    `optx.least_squares` (pure: it can be `jax.vmap`ped over problems of one structure, as
    Monte Carlo and batches do, and differentiated); with `on_step` the same solver runs one
    compiled step at a time and `on_step(StepInfo)` hears every step (`least_squares_stepwise`:
    not under jit or vmap). `plan` = `linearisation_plan(problem)`, computed here when not
    given (it must be given under `jax.vmap` or `jax.jit`, where the problem's index arrays
    are traced).
    """
    if plan is None:
        plan = linearisation_plan(problem)
    settings = dict(max_steps=max_steps, rtol=rtol, atol=atol, step_tolerance=step_tolerance)
    if on_step is None:
        return _solve(problem, plan, **settings)
    solver, args, z0 = _normal_solver(problem, plan, rtol=rtol, atol=atol,
                                      step_tolerance=step_tolerance, block_size=UNBATCHED_BLOCK)
    solution = least_squares_stepwise(
        _residual_fn, solver, z0, args, has_aux=True, max_steps=max_steps, on_step=on_step)
    return _normal_solution(args, solution)


def _make_normal_solver(problem, plan, *, rtol, atol, step_tolerance, block_size=None):
    """The dense-backend solver, the residual function's args and the start z = 0."""
    scale = column_scale(problem, plan)
    solver = NormalLevenbergMarquardt(
        problem, plan, scale, rtol, atol, step_tolerance=step_tolerance, block_size=block_size)
    return solver, (problem, plan.free_index, scale), jnp.zeros_like(scale)


def _make_normal_solution(args, solution: optx.Solution) -> Solution:
    problem, index, scale = args
    params = params_from_scaled(problem, solution.value, index, scale)
    return Solution(
        parameters=params,
        converged=solution.result == optx.RESULTS.successful,
        steps=solution.stats["num_steps"],
        accepted_steps=solution.state.num_accepted_steps,
        cost=solution.state.cost,  # ½Σẽ² at the final (accepted) iterate
        result=solution.result,
    )


_normal_solver = eqx.filter_jit(_make_normal_solver)
_normal_solution = eqx.filter_jit(_make_normal_solution)


@eqx.filter_jit
def _solve(problem, plan, *, max_steps, rtol, atol, step_tolerance) -> Solution:
    solver, args, z0 = _make_normal_solver(
        problem, plan, rtol=rtol, atol=atol, step_tolerance=step_tolerance)
    solution = optx.least_squares(
        _residual_fn, solver, z0, args=args, has_aux=True, max_steps=max_steps, throw=False)
    return _make_normal_solution(args, solution)
