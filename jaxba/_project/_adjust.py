"""Adjust a project with the settings of its `[adjustment]` table."""

from collections.abc import Callable

from .._progress import Iteration
from .._solve import Adjustment, adjust
from ._build import Project


def adjust_project(
    project: Project, *, on_iteration: Callable[[Iteration], None] | None = None
) -> Adjustment:
    """Run `adjust` on the project's problem with its settings and parameter labels."""
    settings = project.spec.settings
    return adjust(
        project.problem,
        sigma0=settings.sigma0,
        max_steps=settings.max_iterations,
        rtol=settings.rtol,
        atol=settings.atol,
        labels=project.labels,
        on_iteration=on_iteration,
    )
