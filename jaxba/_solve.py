"""Solve a bundle with optimistix Levenberg-Marquardt and report honestly."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from ._causes import DIVERGED_SIGMA0, divergence_cause
from ._datum import check_datum, nonfinite_start_error
from ._float64 import require_float64
from ._free_network import (
    free_network_precision,
    inner_constraint_group,
    minimal_constraints,
    to_inner_datum,
)
from ._levenberg_marquardt import UNBATCHED_BLOCK, NormalLevenbergMarquardt
from ._linearisation import LinearisationPlan, linearisation_plan, normal_equations
from ._parameters import Parameters, parameter_labels
from ._problem import BundleProblem, free_indices, observed_minus_computed, params_from_scaled
from ._progress import Iteration, StepRecorder
from ._schur._bundle import bundle_structure, solve_schur
from ._schur._choice import use_schur
from ._schur._datum import check_datum_schur
from ._schur._reliability import schur_precision_and_redundancy
from ._solution import Solution
from ._statistics import Precision, precision, precision_from_covariance
from ._steps import StepInfo, least_squares_stepwise
from ._timing import Timings
from ._trust_region import STEP_TOLERANCE


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
    - `backend`: the normal-equation backend that solved, "dense" or "schur";
    - `timings`: wall seconds per phase ("datum check", "solve", "statistics", ...) with
      the compilations inside each (`jaxba._timing.Timings`);
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
    backend: str = "dense"
    timings: Timings = dataclasses.field(default_factory=Timings)
    reliability: "Reliability | None" = None  # noqa: F821  (defined in _reliability)
    variance_components: dict | None = None
    variance_iterations: int = 0
    rejections: tuple = ()

    @property
    def sigma0(self) -> float:
        """A posteriori σ̂0."""
        return float(np.sqrt(self.precision.sigma0_squared))


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
    unknown by less than `step_tolerance` of its σ (gᵀN⁻¹g ≤ τ², `jaxba._trust_region`,
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
_whitened = eqx.filter_jit(BundleProblem.whitened)
_normal_solution = eqx.filter_jit(_make_normal_solution)


@eqx.filter_jit
def _solve(problem, plan, *, max_steps, rtol, atol, step_tolerance) -> Solution:
    solver, args, z0 = _make_normal_solver(
        problem, plan, rtol=rtol, atol=atol, step_tolerance=step_tolerance)
    solution = optx.least_squares(
        _residual_fn, solver, z0, args=args, has_aux=True, max_steps=max_steps, throw=False)
    return _make_normal_solution(args, solution)


def _stop_reason(result: optx.RESULTS, max_steps: int) -> str:
    """Why an unconverged solve stopped, in words."""
    if result == optx.RESULTS.nonlinear_max_steps_reached:
        return f"the maximum number of steps ({max_steps}) was reached"
    return optx.RESULTS[result]


def _stalled(iterations: list[Iteration]) -> bool:
    """Whether the cost fell by less than half over the last two accepted iterations (a
    solve stuck far from the solution, not one merely cut short by `max_steps`)."""
    costs = [it.cost for it in iterations]
    return len(costs) < 3 or not costs[-1] < 0.5 * costs[-3]


def _precision_unavailable(problem, params, sigma0, final_cost, redundancy) -> Precision:
    """σ̂0² from the final cost; covariance and σ NaN (the normal matrix was singular)."""
    n_free = free_indices(problem).size
    sigma0_squared = sigma0**2 * 2 * final_cost / redundancy if redundancy > 0 else np.nan
    return precision_from_covariance(problem, params, np.full((n_free, n_free), np.nan),
                                     sigma0_squared, redundancy, problem.n_observations())


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
    timings: Timings | None = None,
) -> Adjustment:
    """Adjust `problem` by Levenberg-Marquardt (`solve`: optx.least_squares).

    The datum is checked first (`DatumError` names the unobservable directions, using
    `labels`, one per scalar unknown in `flatten` order; `check=False` skips it, e.g. when
    re-adjusting a checked bundle with new weights). `on_iteration` is called for
    every accepted iterate. With `throw=True` a non-converged solve raises
    `NotConvergedError`; otherwise `converged` and `message` say what happened. Where the
    normal matrix at the solution is singular (a degenerate solution, e.g. from far-off
    approximations) the statistics are unavailable (σ and covariance NaN) and the result
    is marked not converged. Needs float64 (`ValueError` otherwise).

    `solver`: "dense" (normal equations of all unknowns, dense statistics), "schur" (object
    points eliminated: `solve_schur`, `check_datum_schur`, `schur_precision`, whose
    `Precision` holds the covariance in blocks and the redundancy numbers) or "auto"
    (`use_schur`: "schur" for large bundles). A free network on the Schur backend is solved
    with a minimal datum and carried over to its inner constraints (`jaxba._free_network`).
    The phases are timed into `timings` (a new `Timings` when None), which the result
    holds.
    """
    require_float64("jaxba.adjust")
    timings = Timings() if timings is None else timings
    schur = use_schur(problem, solver)
    free_network = schur and inner_constraint_group(problem) is not None
    solved = minimal_constraints(problem, problem.initial) if free_network else problem
    # The Schur split's structure, computed once for the datum check, solve and covariance.
    split = {"structure": bundle_structure(solved)} if schur else {}
    if check:
        with timings.phase("datum check"):
            if schur:
                check_datum_schur(solved, labels=labels, **split)
            else:
                check_datum(problem, labels=labels)
    redundancy = problem.n_observations() - problem.n_unknowns()
    recorder = StepRecorder(redundancy, sigma0, on_iteration)
    with timings.phase("solve"):
        solution = (solve_schur if schur else solve)(
            solved, max_steps=max_steps, rtol=rtol, atol=atol, on_step=recorder, **split)
        solution = jax.block_until_ready(solution)
    params, result, steps = solution.parameters, solution.result, solution.steps
    if free_network:
        params = to_inner_datum(problem, params)
    final_cost = float(solution.cost)
    if not np.isfinite(final_cost):
        # A trial point with a non-finite cost is rejected and the first, the approximations,
        # always accepted: only approximations where the model is not finite get here.
        error = nonfinite_start_error(problem, labels or parameter_labels(problem.initial))
        if error is not None:
            raise error
        raise NotConvergedError("the adjustment produced non-finite residuals (NaN or inf)")
    converged = result == optx.RESULTS.successful
    message = "converged" if converged else _stop_reason(result, max_steps)
    if throw and not converged:
        raise NotConvergedError(f"no convergence after {int(steps)} steps: {message}")
    with timings.phase("statistics"):
        whitened = _whitened(problem, params)
        residuals = observed_minus_computed(problem, whitened)
        try:
            if free_network:
                parameter_precision = free_network_precision(
                    problem, params, sigma0=sigma0, **split)
            else:
                # The Schur backend's redundancy numbers come with the covariance (one
                # program for both), for `jaxba.reliability` to use.
                parameter_precision = (schur_precision_and_redundancy if schur else precision)(
                    problem, params, sigma0=sigma0, **split)
        except np.linalg.LinAlgError as error:
            parameter_precision = _precision_unavailable(
                problem, params, sigma0, final_cost, redundancy)
            converged, message = False, (
                f"the normal matrix at the solution is singular ({error}): no σ, no"
                " correlations; check the approximations and which parameters are free")
    sigma_ratio = np.sqrt(parameter_precision.sigma0_squared) / sigma0
    if not converged and not sigma_ratio <= DIVERGED_SIGMA0 and _stalled(recorder.iterations):
        # Stuck far from a consistent solution: name the approximations it left behind.
        cause = divergence_cause(problem, params, parameter_precision.std, whitened,
                                 labels or parameter_labels(problem.initial))
        after = "" if "maximum number of steps" in message else f", after {int(steps)} steps"
        message = f"{cause} ({message}{after}; σ̂0/σ0 = {sigma_ratio:.3g})"
    return Adjustment(
        problem=problem,
        parameters=params,
        precision=parameter_precision,
        residuals=residuals,
        iterations=recorder.iterations,
        converged=bool(converged),
        message=str(message),
        steps=int(steps),
        backend="schur" if schur else "dense",
        timings=timings,
    )
