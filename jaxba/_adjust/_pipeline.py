"""The adjustment pipeline of a project (`adjust_pipeline`; its `[adjustment]` table gives
the options, `jaxba.adjust_project`).

The pipeline: adjust by least squares, then with the robust loss if one is set;
estimate variance components (`variance_components = true`); Baarda data snooping
(`data_snooping = true`), with a second variance-component pass when observations were
removed; reliability at the final solution, unless its normal matrix is singular (a
degenerate solution that did not converge: `reliability` is then None).
"""

import dataclasses
from collections.abc import Callable

import numpy as np

from .._problem._bundle import BundleProblem
from .._solvers._progress import Iteration
from .._statistics._adjustment import Adjustment
from .._statistics._reliability import reliability
from .._timing import Timings
from ._adjust import adjust
from ._snooping import data_snooping as snoop, restart_from
from ._variance_components import estimate_variance_components


def _continue_numbering(before: list[Iteration], after: list[Iteration]) -> list[Iteration]:
    start = before[-1].iteration + 1 if before else 0
    renumbered = [dataclasses.replace(it, iteration=start + k) for k, it in enumerate(after)]
    return before + renumbered


def _final_reliability(result: Adjustment, snooping: dict):
    """`reliability` at the final solution; None for a result that did not converge and
    whose normal matrix is singular (`adjust` found its statistics unavailable)."""
    try:
        return reliability(result, **snooping)
    except np.linalg.LinAlgError:
        if result.converged:
            raise
        return None


def adjust_pipeline(
    problem: BundleProblem,
    *,
    labels: list[str] | None = None,
    sigma0: float = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    stop: str = "statistical",
    solver: str = "auto",
    variance_components: bool = False,
    data_snooping: bool = False,
    alpha: float = 0.05,
    familywise: bool = True,
    on_iteration: Callable[[Iteration], None] | None = None,
    timings: Timings | None = None,
) -> Adjustment:
    """Adjust `problem` and compute its statistics; see the module docstring. `labels`,
    `sigma0`, `max_steps`, `rtol`, `atol`, `stop`, `solver` ("auto", "dense" or "schur") and
    `on_iteration` as for `jaxba.adjust`; `variance_components` and `data_snooping` switch
    those steps on; `alpha` and `familywise`: the significance of the w-tests (snooping and
    reliability). Phases are timed into `timings` (as `jaxba.adjust`): the re-adjustments of
    variance components and data snooping, and reliability, count as "statistics"."""
    options = dict(sigma0=sigma0, max_steps=max_steps, rtol=rtol, atol=atol, stop=stop,
                   solver=solver)
    timings = Timings() if timings is None else timings
    snooping = dict(alpha=alpha, familywise=familywise)
    # A robust loss from far-off approximations treats every residual as an outlier; start
    # it from the least-squares solution instead.
    least_squares = dataclasses.replace(problem, robust=None)
    result = adjust(least_squares, labels=labels, on_iteration=on_iteration,
                    timings=timings, **options)
    iterations, ids = list(result.iterations), result.ids  # re-adjustments have no labels
    if problem.robust is not None and result.converged:
        result = adjust(restart_from(problem, result.parameters), check=False,
                        timings=timings, **options)
        iterations = _continue_numbering(iterations, result.iterations)
    components, variance_iterations, rejections = None, 0, ()

    def with_components(current):
        nonlocal components, variance_iterations, iterations
        # Re-adjustments (robust loss, data snooping) carry no IDs: the components are
        # named by the first adjustment's IDs all the same.
        current, components, rounds = estimate_variance_components(
            dataclasses.replace(current, ids=ids), reference=problem, **options
        )
        variance_iterations += rounds
        iterations = _continue_numbering(iterations, current.iterations)
        return current

    with timings.phase("statistics"):
        if variance_components and result.converged:
            result = with_components(result)
        if data_snooping and result.converged:
            result, found, _ = snoop(result, **snooping, **options)
            rejections = tuple(found)
            if found:
                iterations = _continue_numbering(iterations, result.iterations)
                if variance_components:
                    result = with_components(result)
        final_reliability = _final_reliability(result, snooping)
    return dataclasses.replace(
        result,
        ids=ids,
        timings=timings,
        iterations=iterations,
        reliability=final_reliability,
        variance_components=components,
        variance_iterations=variance_iterations,
        rejections=rejections,
    )
