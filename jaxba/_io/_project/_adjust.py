"""Adjust a project with the settings of its `[adjustment]` table.

The pipeline: adjust by least squares, then with the robust loss if one is set;
estimate variance components (`variance_components = true`); Baarda data snooping
(`data_snooping = true`), with a second variance-component pass when observations were
removed; reliability at the final solution, unless its normal matrix is singular (a
degenerate solution that did not converge: `reliability` is then None).
"""

import dataclasses
from collections.abc import Callable

import numpy as np

from ..._adjust._adjust import adjust
from ..._adjust._snooping import data_snooping, restart_from
from ..._adjust._variance_components import estimate_variance_components
from ..._solvers._progress import Iteration
from ..._statistics._adjustment import Adjustment
from ..._statistics._reliability import reliability
from ..._timing import Timings
from ._build import Project


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


def adjust_project(
    project: Project,
    *,
    on_iteration: Callable[[Iteration], None] | None = None,
    solver: str | None = None,
    timings: Timings | None = None,
) -> Adjustment:
    """Run the project's adjustment and statistics; see the module docstring. `solver`:
    "auto", "dense" or "schur" (object points eliminated), as for `jaxba.adjust`; None: the
    project's `solver` setting. Phases are timed into `timings` (as `jaxba.adjust`): the
    re-adjustments of variance components and data snooping, and reliability, count as
    "statistics"."""
    settings = project.spec.settings
    solver = solver or settings.solver
    options = dict(
        sigma0=settings.sigma0, max_steps=settings.max_iterations,
        rtol=settings.rtol, atol=settings.atol, solver=solver,
    )
    timings = Timings() if timings is None else timings
    snooping = dict(alpha=settings.snooping_alpha, familywise=settings.snooping_familywise)
    problem = project.problem
    # A robust loss from far-off approximations treats every residual as an outlier; start
    # it from the least-squares solution instead.
    least_squares = dataclasses.replace(problem, robust=None)
    result = adjust(least_squares, labels=project.labels, on_iteration=on_iteration,
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
        # named by the project's cameras all the same.
        current, components, rounds = estimate_variance_components(
            dataclasses.replace(current, ids=ids), reference=project.problem, **options
        )
        variance_iterations += rounds
        iterations = _continue_numbering(iterations, current.iterations)
        return current

    with timings.phase("statistics"):
        if settings.variance_components and result.converged:
            result = with_components(result)
        if settings.data_snooping and result.converged:
            result, found, _ = data_snooping(result, **snooping, **options)
            rejections = tuple(found)
            if found:
                iterations = _continue_numbering(iterations, result.iterations)
                if settings.variance_components:
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
