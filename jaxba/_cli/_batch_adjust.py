"""`jaxba batch`'s pipeline after reading, in one process: build the projects, solve them in
padded chunks on an executor, write their reports (`adjust_entries`). `run_batch` runs it
here or on each worker process (`_batch_processes`).

Projects of one kind (same observation groups, camera models, iteration settings) are padded
to one shape and solved in vmapped chunks of `CHUNK` (`_batch_solve`): one compiled program
for all of them (datum check, solve, statistics). A project that asks for a robust loss,
variance components or data snooping is adjusted alone with `adjust_project` (those are
sequential re-adjustments); its summary row says so. The chunks run on an executor
(`jaxba._dask`): in this process, one after the other, or on the workers of a Dask cluster,
all at once. Reports are written here as each chunk's results come back, by writer threads
(one in a worker process) while the next chunks are solved. A chunk whose task raised (a
worker that kept dying under it, a bug) is tried again one project at a time, so that only
the project at fault fails, with the exception as its reason; a project that stops
unconverged in its chunk is adjusted again alone, whose iterations tell why (`jaxba
adjust`'s message).
"""

import collections
import concurrent.futures
from collections.abc import Callable

from .._adjust._padding import batch_kind, batch_shape
from .._dask import executor
from .._project import build_project
from ._batch_read import PROJECT_ERRORS, BatchEntry, read_whole
from ._batch_rows import summary_row
from ._batch_solve import Chunk, Outcome, solve_chunk

CHUNK = 10  # projects per vmapped solve (one Dask task), by default
# Threads writing reports while the chunks are solved: in a process alone on the machine,
# one formats while the other writes (and XLA solves); in a worker process, which shares the
# cores with the others, one (`adjust_entries(writers=...)`).
WRITERS_ALONE = 2


def _needs_single(project) -> bool:
    """Whether the project is adjusted alone (`jaxba.adjust_project`), not in a vmapped chunk:
    a robust loss, variance components, data snooping, a board warp (the chunk's padded
    blocks have none), a free network (its inner constraints tie every unknown in the
    project's own order: not padded), or a stopping rule other than the statistical one."""
    settings = project.spec.settings
    return (project.problem.robust is not None or settings.variance_components
            or settings.data_snooping or project.problem.initial.warp is not None
            or settings.datum == "free" or settings.stop != "statistical")


def adjust_entries(
    entries: list[BatchEntry],
    say: Callable[[str], None],
    finished: Callable[[], None],
    chunk_size: int | None = None,
    scheduler=None,
    writers: int = WRITERS_ALONE,
) -> None:
    """Build, solve and report the pending `entries` here (their solves on `scheduler`'s
    executor), the reports by `writers` threads: each entry's status, reason, mode and
    summary `row` filled in; a project that cannot be built fails alone."""
    for entry in entries:
        try:
            if entry.spec is None:  # its project file only was read (`read_batch(tables=False)`)
                entry.spec = read_whole(entry)
            entry.project = build_project(entry.spec, on_device=False)  # padded in NumPy
        except PROJECT_ERRORS as error:
            entry.status, entry.reason = "failed", str(error)
            say(f"failed  {entry.path}: {entry.reason}")
            finished()
    ready = [e for e in entries if e.status == "pending"]
    if ready:
        with executor(scheduler) as run:
            if scheduler is not None:
                say(f"solving on {run.description}")
            _solve(run, _chunks(ready, chunk_size or CHUNK), say, finished, len(ready),
                   writers)
    for entry in entries:
        entry.row = summary_row(entry)


def _chunks(ready: list[BatchEntry], size: int) -> list[tuple[list[BatchEntry], Chunk]]:
    """Projects of one kind grouped, each group cut into chunks of `size` padded to the
    group's shape; a project adjusted alone is its own chunk."""
    groups: dict[tuple, list[BatchEntry]] = {}
    for entry in ready:
        if _needs_single(entry.project):
            groups.setdefault(("single", id(entry)), []).append(entry)
            continue
        settings = entry.project.spec.settings
        key = (batch_kind(entry.project.problem), settings.max_iterations, settings.rtol,
               settings.atol)
        groups.setdefault(key, []).append(entry)
    chunks = []
    for key, members in groups.items():
        if key[0] == "single":
            chunks.append((members, Chunk((members[0].project,), single=True)))
            continue
        step = min(size, len(members))
        # Chunks of one group padded alike: one compiled program for all of them.
        shape = batch_shape([e.project.problem for e in members]) if step < len(members) else None
        for start in range(0, len(members), step):
            part = members[start:start + step]
            chunks.append((part, Chunk(tuple(e.project for e in part), shape=shape, size=step)))
    return chunks


def _solve(run, chunks, say, finished, total: int, writers: int) -> None:
    """Solve `chunks` on `run`, record the outcomes and write the reports as they come; a
    chunk of several projects whose task raised is tried again one project at a time, a
    project that did not converge in its chunk alone (`_unconverged_in_batch`).

    The reports of a chunk are written by one of `writers` threads while the next chunk
    is solved (XLA and file writes release the GIL); what each project became is said here,
    in order, as its reports are done. In a worker process that shares the cores with
    others, a second writer only contends for the GIL: 1000 Zhang-size projects on 2 cores
    and 2 workers took 3-17 % more CPU with two writers than with one (median 6 %, 7
    alternated runs), with twice the context switches."""
    from .._report import write_batch_reports

    done = 0
    writer = concurrent.futures.ThreadPoolExecutor(writers, thread_name_prefix="jaxba-reports")
    written: collections.deque = collections.deque()

    def report(block: bool) -> None:
        nonlocal done
        while written and (block or written[0][1].done()):
            members, future = written.popleft()
            future.result()
            for entry in members:
                done += 1
                sigma0 = f"sigma0 {entry.result.sigma0:.4f}" if entry.result is not None else ""
                say(f"[{done:{len(str(total))}d}/{total}] {entry.name}: {entry.status}"
                    f" {sigma0} {entry.reason}".rstrip())
                finished()

    try:
        while chunks:
            batched = sum(len(members) for members, chunk in chunks if not chunk.single)
            if batched:
                n_batches = sum(not chunk.single for _, chunk in chunks)
                say(f"solving {batched} project(s) in {n_batches} padded batch(es)")
            again = []
            for k, outcomes in run.map(solve_chunk, [chunk for _, chunk in chunks]):
                members, chunk = chunks[k]
                if isinstance(outcomes, BaseException):
                    if len(members) > 1:
                        say(f"a batch of {len(members)} failed ({type(outcomes).__name__});"
                            " trying its projects one by one")
                        again += [([e], Chunk((e.project,), chunk.single, chunk.shape, 1))
                                  for e in members]
                        continue
                    reason = f"{type(outcomes).__name__}: {outcomes}".strip()
                    outcomes = [Outcome("single" if chunk.single else "", reason=reason)]
                kept = []
                for entry, outcome in zip(members, outcomes):
                    if _unconverged_in_batch(outcome):
                        say(f"{entry.name}: not converged in its batch; adjusting it alone")
                        again.append(([entry], Chunk((entry.project,), single=True)))
                    else:
                        kept.append((entry, outcome))
                if kept:
                    members, outcomes = map(list, zip(*kept))
                    written.append((members, writer.submit(_record_all, members, outcomes,
                                                           write_batch_reports)))
                report(block=False)
            report(block=True)
            chunks = again
    finally:
        writer.shutdown(wait=True, cancel_futures=True)


def _unconverged_in_batch(outcome: Outcome) -> bool:
    """A batched solve that stopped unconverged: adjusted again alone, whose iterations
    tell a solve stuck far from the solution (and which approximations it left) from one
    merely cut short, as `jaxba adjust` says it."""
    return outcome.mode == "batch" and outcome.result is not None and not outcome.result.converged


def _record_all(members: list[BatchEntry], outcomes: list[Outcome], write_reports) -> None:
    for entry, outcome in zip(members, outcomes):
        _record(entry, outcome, write_reports)


def _record(entry: BatchEntry, outcome: Outcome, write_reports) -> None:
    """The outcome into `entry`; the reports written for an adjusted project."""
    entry.mode = outcome.mode
    if outcome.result is None:
        entry.status, entry.reason = "failed", outcome.reason
        return
    result = outcome.result
    entry.result = result
    entry.status = "ok" if result.converged else "not converged"
    entry.reason = "" if result.converged else result.message
    try:
        write_reports(entry.project, result, entry.out_dir, entry.reports)
    except (ValueError, OSError) as error:
        entry.status, entry.reason = "failed", f"reports not written: {error}"
