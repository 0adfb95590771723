"""Solve a bundle with optimistix Levenberg-Marquardt and report honestly."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._datum import check_datum
from ._levenberg_marquardt import DECREMENT_TOLERANCE, NormalLevenbergMarquardt
from ._linearisation import LinearisationPlan, linearisation_plan, normal_equations
from ._parameters import Parameters
from ._problem import BundleProblem, observed_minus_computed, params_from_scaled
from ._progress import Iteration, StepRecorder, listening, report_step
from ._schur._bundle import schur_precision, solve_schur
from ._schur._choice import use_schur
from ._schur._datum import check_datum_schur
from ._statistics import Precision, precision
from ._trust_region import silent


class NotConvergedError(RuntimeError):
    """The adjustment stopped without meeting its convergence criteria."""


@dataclasses.dataclass(frozen=True)
class Adjustment:
    """The outcome of `adjust`.

    - `parameters`: adjusted unknowns (fixed ones at their given values);
    - `precision`: σ̂0², redundancy, covariance and σ of every unknown;
    - `residuals`: per observation group, v = observed - computed in the observation's
      units (masked entries 0), same shapes as the group's residuals;
    - `iterations`: every accepted iterate with its cost ½Σe² and σ̂0² (re-adjustments
      for variance components or data snooping continue the numbering);
    - `converged`, `message`, `steps` (solver steps, rejected ones included);
    - filled in by `adjust_project` as the project asks: `reliability` (a `Reliability`),
      `variance_components` ({group: VarianceComponent}) with `variance_iterations`, and
      `rejections` (data snooping, in order of removal).
    """

    problem: BundleProblem
    parameters: Parameters
    precision: Precision
    residuals: tuple[np.ndarray, ...]
    iterations: list[Iteration]
    converged: bool
    message: str
    steps: int
    reliability: "Reliability | None" = None  # noqa: F821  (defined in _reliability)
    variance_components: dict | None = None
    variance_iterations: int = 0
    rejections: tuple = ()

    @property
    def sigma0(self) -> float:
        """A posteriori σ̂0."""
        return float(np.sqrt(self.precision.sigma0_squared))


class Solution(eqx.Module):
    """What `solve` returns: adjusted `parameters`, `converged` flag, solver `steps`, the
    final `cost` ½Σẽ² and optimistix's `result` code. A pytree, so it batches under vmap."""

    parameters: Parameters
    converged: Bool[Array, ""]
    steps: Int[Array, ""]
    cost: Float[Array, ""]
    result: optx.RESULTS


def _residual_fn(z, args):
    problem, index, scale = args
    return problem.residuals(params_from_scaled(problem, z, index, scale)), None


def _flat_residuals(problem: BundleProblem, params: Parameters) -> Float[Array, " n"]:
    return jnp.concatenate([jnp.ravel(r) for r in problem.residuals(params)])


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
    decrement_tolerance: float = DECREMENT_TOLERANCE,
    progress: bool = True,
) -> Solution:
    """Levenberg-Marquardt on the Jacobi-scaled free unknowns, through optx.least_squares.

    Converged at an accepted iterate from which the Gauss-Newton step would lower the cost
    by less than `decrement_tolerance` times the cost (see `NormalDampedNewtonDescent`), or
    where optimistix's Cauchy test passes (step and residual change within `rtol`, `atol`,
    elementwise, in the scaled unknowns), or when every step from it is rejected down to the
    trust region's minimum radius (`jaxba._trust_region`).
    Pure and jitted (normal equations from per-row Jacobian blocks, Cholesky per trial
    step: `NormalLevenbergMarquardt`): no datum check, no statistics, so it can be `jax.vmap`ped
    over problems of one structure (Monte Carlo, batches). `plan` =
    `linearisation_plan(problem)`, computed here when not given (it must be given under
    `jax.vmap` or `jax.jit`, where the problem's index arrays are traced).
    `progress=False` leaves out the per-step host callback: jax then caches the compiled
    solve persistently, and under vmap the callback is not unrolled per batch element.
    """
    if plan is None:
        plan = linearisation_plan(problem)
    return _solve(problem, plan, max_steps=max_steps, rtol=rtol, atol=atol,
                  decrement_tolerance=decrement_tolerance, progress=progress)


@eqx.filter_jit
def _solve(problem, plan, *, max_steps, rtol, atol, decrement_tolerance, progress) -> Solution:
    index = plan.free_index
    scale = column_scale(problem, plan)
    solver = NormalLevenbergMarquardt(
        problem, plan, scale, rtol, atol, decrement_tolerance=decrement_tolerance,
        verbose=report_step if progress else silent)
    solution = optx.least_squares(
        _residual_fn, solver, jnp.zeros_like(scale), args=(problem, index, scale),
        has_aux=True, max_steps=max_steps, throw=False,
    )
    params = params_from_scaled(problem, solution.value, index, scale)
    return Solution(
        parameters=params,
        converged=solution.result == optx.RESULTS.successful,
        steps=solution.stats["num_steps"],
        cost=0.5 * jnp.sum(_flat_residuals(problem, params) ** 2),
        result=solution.result,
    )


def adjust(
    problem: BundleProblem,
    *,
    sigma0: float = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    labels: list[str] | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
    throw: bool = False,
    check: bool = True,
    solver: str = "auto",
) -> Adjustment:
    """Adjust `problem` by Levenberg-Marquardt (`solve`: optx.least_squares).

    The datum is checked first (`DatumError` names the unobservable directions, using
    `labels`, one per scalar unknown in `flatten` order; `check=False` skips it, e.g. when
    re-adjusting a checked bundle with new weights). `on_iteration` is called for
    every accepted iterate. With `throw=True` a non-converged solve raises
    `NotConvergedError`; otherwise `converged` and `message` say what happened.

    `solver`: "dense" (normal equations of all unknowns, dense statistics), "schur" (object
    points eliminated: `solve_schur`, `check_datum_schur`, `schur_precision`, whose
    `Precision` holds the covariance in blocks) or "auto" (`use_schur`: "schur" above
    `SCHUR_MIN_UNKNOWNS` unknowns).
    """
    schur = use_schur(problem, solver)
    if check:
        if schur:
            check_datum_schur(problem, labels=labels)
        else:
            check_datum(problem, labels=labels)
    redundancy = problem.n_observations() - problem.n_unknowns()
    recorder = StepRecorder(redundancy, sigma0, on_iteration)
    with listening(recorder):
        if schur:
            solution = solve_schur(problem, max_steps=max_steps, rtol=rtol, atol=atol)
        else:
            solution = solve(problem, max_steps=max_steps, rtol=rtol, atol=atol)
        solution = jax.block_until_ready(solution)
    params, result, steps = solution.parameters, solution.result, solution.steps
    final_cost = float(solution.cost)
    whitened = problem.whitened(params)
    if not np.isfinite(final_cost):
        raise NotConvergedError("the adjustment produced non-finite residuals (NaN or inf)")
    converged = result == optx.RESULTS.successful
    message = "converged" if converged else optx.RESULTS[result]
    if throw and not converged:
        raise NotConvergedError(f"no convergence after {int(steps)} steps: {message}")
    residuals = observed_minus_computed(problem, whitened)
    return Adjustment(
        problem=problem,
        parameters=params,
        precision=(schur_precision if schur else precision)(problem, params, sigma0=sigma0),
        residuals=residuals,
        iterations=recorder.iterations,
        converged=bool(converged),
        message=str(message),
        steps=int(steps),
    )
