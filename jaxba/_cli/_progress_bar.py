"""A progress bar over the projects of `jaxba batch` or the images of `jaxba detect` (rich),
for the command line.

On a terminal the command's lines are printed above a bar that advances as each item is
finished; elsewhere (a pipe, a log file) only the lines, exactly as without a bar, unless the
bar is asked for. rich is imported only when a bar is shown.
"""

import contextlib
import dataclasses
import sys
from collections.abc import Callable, Iterator


@dataclasses.dataclass(frozen=True)
class ProjectProgress:
    """Where `run_batch` reports: `say(line)` per stage and project, `advance()` once per
    finished project."""

    say: Callable[[str], None]
    advance: Callable[[], None]


@contextlib.contextmanager
def project_progress(
    total: int, say: Callable[[str], None], *, bar: bool | None = None, noun: str = "projects"
) -> Iterator[ProjectProgress]:
    """Report a batch of `total` projects (or other items, `noun`): lines through `say` alone
    (`bar` False, or None when stdout is not a terminal), or printed above a rich bar on
    stdout (`bar` True, or None on a terminal) that counts finished ones and estimates the
    time left."""
    if bar is None:
        bar = sys.stdout.isatty()
    if not bar:
        yield ProjectProgress(say, lambda: None)
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn(noun), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("left"), TimeRemainingColumn())
    with Progress(*columns, console=Console(file=sys.stdout, force_terminal=True)) as progress:
        task = progress.add_task(noun, total=total)

        def print_line(line: str) -> None:
            progress.console.print(line, markup=False, highlight=False, soft_wrap=True)

        yield ProjectProgress(print_line, lambda: progress.advance(task))
