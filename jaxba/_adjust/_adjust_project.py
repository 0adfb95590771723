"""Adjust a project with the settings of its `[adjustment]` table: `adjust_project`, the
project's side of the pipeline (`jaxba._adjust._pipeline`)."""

from collections.abc import Callable

from .._project._build import Project
from .._solvers._progress import Iteration
from .._statistics._adjustment import Adjustment
from .._timing import Timings
from ._pipeline import adjust_pipeline


def adjust_project(
    project: Project,
    *,
    on_iteration: Callable[[Iteration], None] | None = None,
    solver: str | None = None,
    timings: Timings | None = None,
) -> Adjustment:
    """Run the project's adjustment and statistics (`adjust_pipeline`) with its settings.
    `solver`: "auto", "dense" or "schur" (object points eliminated), as for `jaxba.adjust`;
    None: the project's `solver` setting. Phases are timed into `timings` (as
    `jaxba.adjust`)."""
    settings = project.spec.settings
    return adjust_pipeline(
        project.problem, labels=project.labels, sigma0=settings.sigma0,
        max_steps=settings.max_iterations, rtol=settings.rtol, atol=settings.atol,
        stop=settings.stop, solver=solver or settings.solver,
        variance_components=settings.variance_components,
        data_snooping=settings.data_snooping, alpha=settings.snooping_alpha,
        familywise=settings.snooping_familywise, on_iteration=on_iteration, timings=timings)
