"""Adjust a bundle: datum check, solve on the backend its size calls for, statistics."""

from collections.abc import Callable

import jax
import numpy as np

from .._float64 import require_float64
from .._problem._bundle import BundleProblem, free_indices, observed_minus_computed
from .._problem._checks import check_problem
from .._problem._parameters import parameter_labels
from .._solvers._progress import Iteration, StepRecorder
from .._solvers._solution import stop_reason
from .._solvers._solve import stopping_rule
from .._statistics._adjustable import adjustable
from .._statistics._adjustment import Adjustment
from .._statistics._causes import DIVERGED_SIGMA0, divergence_cause
from .._statistics._covariance import Precision, precision_from_covariance
from .._statistics._datum import nonfinite_start_error, whitened_residuals
from .._statistics._ids import ids_from_labels
from .._statistics._no_sigma import unknowns_without_sigma
from .._timing import Timings


class NotConvergedError(RuntimeError):
    """The adjustment stopped without meeting its convergence criteria."""


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
    stop: str = "statistical",
    labels: list[str] | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
    throw: bool = False,
    check: bool = True,
    solver: str = "auto",
    timings: Timings | None = None,
) -> Adjustment:
    """Adjust `problem` by Levenberg-Marquardt on the normal-equation backend `solver` names
    (`jaxba._statistics._adjustable`).

    The datum is checked first (`DatumError` names the unobservable directions, using
    `labels`, one per scalar unknown in `flatten` order as `parameter_labels` writes them;
    the result's `cameras`, `images`, `points` are keyed by their IDs, by row numbers
    without labels; `ValueError` for labels of another form); `check=False` skips it, e.g. when
    re-adjusting a checked bundle with new weights). `on_iteration` is called for
    every accepted iterate. With `throw=True` a non-converged solve raises
    `NotConvergedError`; otherwise `converged` and `message` say what happened. Where the
    normal matrix at the solution is singular (a degenerate solution, e.g. from far-off
    approximations) the statistics are unavailable (σ and covariance NaN) and the result
    is marked not converged. Needs float64 (`ValueError` otherwise). A bundle with no
    observations or free unknowns, or a free image, camera or point no observation reaches,
    is refused first (`jaxba._problem._checks.ProblemError`, a `ValueError`, naming it).

    `stop`: where the solve stops, "statistical" (the next Gauss-Newton step would move every
    unknown by less than 1e-5 of its σ) or "cost" (Ceres' rule: an accepted step lowered the
    cost by at most 1e-6 of it, and the next step would move every unknown by less than 1e-3
    of its σ; `jaxba._solvers._solve.stopping_rule`); `rtol`, `atol`: the
    Cauchy test beside either.

    `solver`: "dense" (normal equations of all unknowns, dense statistics), "schur" (object
    points eliminated; the `Precision` holds the covariance in blocks and the redundancy
    numbers) or "auto" (`use_schur`: "schur" for large bundles). The phases are timed into
    `timings` (a new `Timings` when None), which the result holds.
    """
    require_float64("jaxba.adjust")
    stopping_rule(stop)  # a bad name refused before any work
    ids = ids_from_labels(problem.initial, labels) if labels is not None else None
    check_problem(problem, labels)
    timings = Timings() if timings is None else timings
    bundle = adjustable(problem, solver)
    with timings.phase("datum check" if check else "solve"):
        # The solve's and the statistics' programs compile on another core meanwhile (where
        # the backend's take seconds): wall time saved, not work.
        bundle.compile_ahead(rtol=rtol, atol=atol, stop=stop)
        if check:
            bundle.check_datum(labels)
            bundle.compile_statistics_ahead()
    redundancy = problem.n_observations() - problem.n_unknowns()
    recorder = StepRecorder(redundancy, sigma0, on_iteration)
    with timings.phase("solve"):
        solution = bundle.solve(max_steps=max_steps, rtol=rtol, atol=atol, stop=stop,
                                on_step=recorder)
        solution = jax.block_until_ready(solution)
    params, result, steps = solution.parameters, solution.result, solution.steps
    final_cost = float(solution.cost)
    if not np.isfinite(final_cost):
        # A trial point with a non-finite cost is rejected and the first, the approximations,
        # always accepted: only approximations where the model is not finite get here.
        error = nonfinite_start_error(problem, labels or parameter_labels(problem.initial))
        if error is not None:
            raise error
        raise NotConvergedError("the adjustment produced non-finite residuals (NaN or inf)")
    converged = bool(solution.converged)  # read in its program: an `==` here compiles one
    message = "converged" if converged else stop_reason(result, max_steps)
    if throw and not converged:
        raise NotConvergedError(f"no convergence after {int(steps)} steps: {message}")
    with timings.phase("statistics"):
        try:
            parameter_precision, whitened = bundle.precision_and_whitened(
                params, sigma0=sigma0)
        except np.linalg.LinAlgError as error:
            whitened = whitened_residuals(problem, params)
            parameter_precision = _precision_unavailable(
                problem, params, sigma0, final_cost, redundancy)
            converged, message = False, (
                f"the normal matrix at the solution is singular ({error}): no σ, no"
                " correlations; check the approximations and which parameters are free")
        residuals = observed_minus_computed(problem, whitened)
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
        backend=bundle.name,
        timings=timings,
        sigma0_prior=float(sigma0),
        ids=ids,
        no_sigma=unknowns_without_sigma(problem, parameter_precision) if converged else {},
    )
