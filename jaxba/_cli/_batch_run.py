"""`jaxba batch`: adjust many project files in padded batches, write reports and a summary.

Plain Python around the jitted core. Projects are read and their outputs checked first
(`_batch_read.read_batch`, no jax; the command line reads only the project files there, and
each project's tables where it is adjusted); with `resume`, those whose reports are all
there are skipped. The others are built, solved in padded chunks and reported
(`_batch_adjust.adjust_entries`): here, or with `jobs` on worker processes of this machine,
each a share of the projects from end to end (`_batch_processes`); then the summary is
written (`_batch_rows`). A process whose projects are all adjusted by workers loads no jax.
"""

import pathlib
import time
from collections.abc import Callable

from .._dask import check_scheduler
from .._io._project import read_project
from .._project._errors import ProjectError
from .._report._outputs import report_kinds
from ._batch_processes import Workers, run_on_processes, worker_processes
from ._batch_read import BatchEntry, finished_results, read_batch
from ._batch_rows import summary_row, write_summary

# Projects per worker process at least: a worker costs ~2.5 CPU s of its own (imports,
# loading the chunk program), a Zhang-size project ~40 ms; fewer are faster in one process.
SHARE = 100


def worker_count(n_projects: int, jobs: int) -> int:
    """Worker processes for `n_projects` with `jobs` allowed: at most one per `SHARE`
    projects; below 2, none (all in the calling process)."""
    return min(jobs, n_projects // SHARE)


def run_batch(
    paths,
    out_dir,
    *,
    progress: Callable[[str], None] | None = None,
    entries: list[BatchEntry] | None = None,
    advance: Callable[[], None] | None = None,
    scheduler=None,
    chunk_size: int | None = None,
    resume: bool = False,
    jobs: int = 1,
    workers: Workers | None = None,
    reports: str = "all",
) -> list[dict]:
    """Adjust the projects `paths` and write DIR/<project name>/ reports, DIR/summary.csv and
    DIR/summary.json. Returns the summary rows (one dict per project, in input order).

    Nothing is computed when a report would overwrite an input file or DIR cannot be
    written (`OutputError`, from `read_batch`; `entries`: its result, if already read).

    Each row: path, name, status ("ok", "not converged", "failed"), reason, mode ("batch",
    "single" or "resumed"), converged, sigma0, redundancy, the two-sided χ² test of σ̂0
    against σ0 (`variance_test`: variance_test.alpha, .statistic = r σ̂0²/σ0², .low, .high
    (its bounds), .passed; empty without redundancy), and per camera parameter
    `<camera>.<model>.<name>` and `<camera>.<model>.<name>.std` (e.g. C1.opencv.fx: one
    name means one parameter across projects of different models; the model's units: mm
    for mm-models, pixels for "opencv").

    `scheduler`: where the chunks are solved: None in this process; "local" or "local:N"
    (a Dask cluster of N worker processes started for the run), a Dask scheduler's address
    or a `distributed.Client` (`jaxba._dask.executor`; `SchedulerError` when it cannot be
    used: Dask missing or a malformed name before anything is built, no answer from the
    address before anything is solved). `chunk_size`: projects per vmapped solve (one task;
    default `_batch_adjust.CHUNK`): chunks are the same wherever they run, and so are the
    results (to rounding, they depend on the chunk length). `resume`: a project whose
    reports all exist is not adjusted again; its row is read from its results.json (mode
    "resumed").
    `jobs`: worker processes of this machine that each adjust a share of the projects
    from end to end, reports included (`_batch_processes`; at most one per `SHARE` projects,
    so that a worker's start-up is paid for; not with a `scheduler`); 1: all in this process.
    The workers import the calling script again (Python's `multiprocessing`): a script
    calls `run_batch` with `jobs` above 1 under `if __name__ == "__main__":`.
    `workers`: worker processes already started (`worker_processes(worker_count(len(paths),
    jobs))`, so that their start-up overlaps the reading): the projects are adjusted on them
    (on fewer where fewer than `SHARE` each are pending), whatever `jobs`.
    `reports`: the reports of each project (`REPORT_SETS`): "all" (NAME.out, NAME.res,
    NAME.sigma, results.json, observations.csv) or "compact" (no file with a row per
    observation: NAME.out, NAME.sigma, results.json); `entries` read already carry theirs.

    `progress` receives one line per stage and per project; `advance()` is called once per
    project when it is finished (failed, skipped, or adjusted and its reports written).
    """
    say = progress or (lambda line: None)
    finished = advance or (lambda: None)
    out_dir = pathlib.Path(out_dir)
    started = time.perf_counter()
    kinds = report_kinds(reports)
    entries = read_batch(paths, out_dir, reports=kinds) if entries is None else entries
    if chunk_size is not None and chunk_size < 1:
        raise ValueError(f"chunk_size {chunk_size}: must be at least 1")
    if jobs < 1:
        raise ValueError(f"jobs {jobs}: must be at least 1")
    if scheduler is not None:
        if workers is not None:
            raise ValueError("workers and a scheduler: give one")
        check_scheduler(scheduler)
    for entry in entries:
        if resume and entry.status == "pending":
            _resume(entry)
        if entry.status == "failed":
            say(f"failed  {entry.path}: {entry.reason}")
            finished()
        elif entry.mode == "resumed":
            say(f"skipped {entry.path}: its reports are in {entry.out_dir}")
            finished()
    pending = [e for e in entries if e.status == "pending"]
    say(f"read {len(entries)} projects ({len(pending)} to adjust) in"
        f" {time.perf_counter() - started:.1f} s")
    if workers is not None:
        if pending:
            shares = max(1, min(workers.size, len(pending) // SHARE))
            run_on_processes(pending, workers, shares, chunk_size, say, finished)
    elif scheduler is None and worker_count(len(pending), jobs) > 1:
        with worker_processes(worker_count(len(pending), jobs)) as pool:
            run_on_processes(pending, pool, pool.size, chunk_size, say, finished)
    else:
        from ._batch_adjust import adjust_entries

        adjust_entries(pending, say, finished, chunk_size, scheduler)
    rows = [entry.row if entry.row is not None else summary_row(entry) for entry in entries]
    write_summary(rows, out_dir)
    say(f"wrote {out_dir / 'summary.csv'} and summary.json"
        f" ({time.perf_counter() - started:.1f} s in all)")
    return rows


def _resume(entry: BatchEntry) -> None:
    """Mark `entry` resumed, with the row of its results.json, if all its reports exist."""
    results = finished_results(entry)
    if results is None:
        return
    if entry.spec is None:  # its summary row needs its camera models
        try:
            entry.spec = read_project(entry.path)
        except ProjectError:
            return  # adjusting it fails it, with the reason
    entry.mode, entry.previous = "resumed", results
    entry.status = "ok" if results["converged"] else "not converged"
    entry.reason = "" if results["converged"] else results.get("message", "")
