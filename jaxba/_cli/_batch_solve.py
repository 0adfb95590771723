"""The part of `jaxba batch` that runs wherever it is sent: a chunk of projects in, one
`Outcome` per project out (`solve_chunk`); `run_batch` hands the chunks to an executor
(`jaxba._dask`: in this process or on Dask workers) and writes the reports itself.

A chunk is projects of one kind padded once and solved in one vmapped program that also
checks their datum and computes their statistics (`adjust_padded`), or one project adjusted
alone (`adjust_project`: robust loss, variance components or data snooping). The chunks of
one group are padded to the group's shape and to one length (a short chunk is filled up
with copies of its last project, whose results are dropped): one compiled program serves
them all.
"""

import dataclasses
import math

from .._adjust._adjust import NotConvergedError
from .._adjust._adjust_project import adjust_project
from .._adjust._batch import adjust_padded
from .._adjust._padding import BatchShape, pad_problems
from .._project._build import Project, put_on_device
from .._statistics._adjustment import Adjustment
from .._statistics._datum import DatumError


@dataclasses.dataclass(frozen=True)
class Chunk:
    """Projects solved together: `single` (one project, adjusted alone) or a padded batch
    of `size` problems (the projects, filled up with copies of the last) of `shape`."""

    projects: tuple[Project, ...]
    single: bool = False
    shape: BatchShape | None = None
    size: int = 0


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What became of one project: its adjustment, or why it failed (`reason`); `mode`
    "batch" or "single" once it was solved, "" when it failed before (its datum)."""

    mode: str
    result: Adjustment | None = None
    reason: str = ""


def solve_chunk(chunk: Chunk) -> list[Outcome]:
    """One `Outcome` per project of `chunk`, in order. A datum defect, a solve that cannot
    go on or non-finite residuals fail their project only; other exceptions propagate."""
    if chunk.single:
        (project,) = chunk.projects
        try:
            return [Outcome("single", adjust_project(put_on_device(project)))]
        except (DatumError, NotConvergedError) as error:
            return [Outcome("single", reason=str(error))]
    projects = list(chunk.projects)
    filled = projects + [projects[-1]] * max(chunk.size - len(projects), 0)
    settings = [p.spec.settings for p in filled]
    results = adjust_padded(
        pad_problems([p.problem for p in filled], chunk.shape),
        sigma0=[s.sigma0 for s in settings],
        max_steps=settings[0].max_iterations,
        rtol=settings[0].rtol,
        atol=settings[0].atol,
        alpha=[s.snooping_alpha for s in settings],
        familywise=[s.snooping_familywise for s in settings],
        check=True,
        labels=[p.labels for p in filled],
    )[:len(projects)]
    return [Outcome("", reason=f"{p.spec.path}: {result}") if isinstance(result, DatumError)
            else _batch_outcome(result) for p, result in zip(projects, results)]


def _batch_outcome(result: Adjustment) -> Outcome:
    if not math.isfinite(result.precision.sigma0_squared):
        return Outcome("batch", reason="non-finite residuals (NaN or inf)")
    return Outcome("batch", result)
