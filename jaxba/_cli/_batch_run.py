"""`jaxba batch`: adjust many project files in padded batches, write reports and a summary.

Plain Python around the jitted core. Projects are read and their outputs checked first
(`_batch_read.read_batch`, no jax; the command line reads only the project files there, and
each project's tables where it is adjusted); with `resume`, those whose reports are all
there are skipped. The others are built one by one; a file or datum error marks that project
failed and the others go on. Projects of one kind (same observation groups, camera models,
iteration settings) are padded to one shape and solved in vmapped chunks of `CHUNK`
(`_batch_solve`): one compiled program for all of them (datum check, solve, statistics).
A project that asks for a robust loss, variance components or data snooping is adjusted
alone with `adjust_project` (those are sequential re-adjustments); its summary row says so.

The chunks run on an executor (`jaxba._dask`): in this process, one after the other, or on
the workers of a Dask cluster, all at once; everything else (grouping, failures, reports,
summary) is the same code for both. With `jobs` the whole pipeline after reading (build,
solve, reports) runs on worker processes of this machine, each on a share of the projects
(`_batch_processes`). Reports are written here as each chunk's results come
back, by writer threads while the next chunks are solved. A chunk whose task raised (a
worker that kept dying under it, a bug) is tried again one project at a time, so that only
the project at fault fails, with the exception as its reason.
"""

import collections
import concurrent.futures
import csv
import io
import json
import math
import pathlib
import time
from collections.abc import Callable

import numpy as np

from .._adjust._padding import batch_kind, batch_shape
from .._dask import check_scheduler, executor
from .._files._atomic import replace_files
from .._io._project import read_project
from .._models._cameras import CAMERA_MODELS
from .._project import ProjectError, build_project
from .._statistics._summary import variance_test
from ._batch_processes import run_on_processes
from ._batch_read import BatchEntry, finished_results, read_batch, summary_paths
from ._batch_solve import Chunk, Outcome, solve_chunk

CHUNK = 10  # projects per vmapped solve (one Dask task), by default
WRITERS = 2  # threads writing reports while the chunks are solved
# Projects per worker process at least: a worker costs ~5 CPU s of its own (imports, the
# chunk program traced), a Zhang-size project ~30 ms; fewer are faster in one process.
SHARE = 100


def _needs_single(project) -> bool:
    """Whether the project is adjusted alone (`jaxba.adjust_project`), not in a vmapped chunk:
    a robust loss, variance components, data snooping, a board warp (the chunk's padded
    blocks have none), or a stopping rule other than the statistical one."""
    settings = project.spec.settings
    return (project.problem.robust is not None or settings.variance_components
            or settings.data_snooping or project.problem.initial.warp is not None
            or settings.stop != "statistical")


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
    default `CHUNK`): chunks are the same wherever they run, and so are the results (to
    rounding, they depend on the chunk length). `resume`: a project whose reports all
    exist is not adjusted again; its row is read from its results.json (mode "resumed").
    `jobs`: worker processes of this machine that each adjust a share of the projects
    from end to end, reports included (`_batch_processes`; at most one per `SHARE` projects,
    so that a worker's start-up is paid for; not with a `scheduler`); 1: all in this process.

    `progress` receives one line per stage and per project; `advance()` is called once per
    project when it is finished (failed, skipped, or adjusted and its reports written).
    """
    say = progress or (lambda line: None)
    finished = advance or (lambda: None)
    out_dir = pathlib.Path(out_dir)
    started = time.perf_counter()
    entries = read_batch(paths, out_dir) if entries is None else entries
    if chunk_size is not None and chunk_size < 1:
        raise ValueError(f"chunk_size {chunk_size}: must be at least 1")
    if jobs < 1:
        raise ValueError(f"jobs {jobs}: must be at least 1")
    if scheduler is not None:
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
    processes = min(jobs, len(pending) // SHARE)
    if scheduler is None and processes > 1:
        run_on_processes(pending, processes, chunk_size, say, finished, adjust_entries)
    else:
        adjust_entries(pending, say, finished, chunk_size, scheduler)
    rows = [entry.row if entry.row is not None else _summary_row(entry)
            for entry in entries]
    _write_summary(rows, out_dir)
    say(f"wrote {out_dir / 'summary.csv'} and summary.json"
        f" ({time.perf_counter() - started:.1f} s in all)")
    return rows


def adjust_entries(
    entries: list[BatchEntry],
    say: Callable[[str], None],
    finished: Callable[[], None],
    chunk_size: int | None = None,
    scheduler=None,
) -> None:
    """Build, solve and report the pending `entries` here (their solves on `scheduler`'s
    executor): each entry's status, reason, mode and summary `row` filled in; a project
    that cannot be built fails alone."""
    for entry in entries:
        try:
            if entry.spec is None:  # read its project file only (`read_batch(tables=False)`)
                entry.spec = read_project(entry.path)
            entry.project = build_project(entry.spec)
        except (ProjectError, ValueError, OSError) as error:
            entry.status, entry.reason = "failed", str(error)
            say(f"failed  {entry.path}: {entry.reason}")
            finished()
    ready = [e for e in entries if e.status == "pending"]
    if ready:
        with executor(scheduler) as run:
            if scheduler is not None:
                say(f"solving on {run.description}")
            _solve(run, _chunks(ready, chunk_size or CHUNK), say, finished, len(ready))
    for entry in entries:
        entry.row = _summary_row(entry)


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


def _solve(run, chunks, say, finished, total: int) -> None:
    """Solve `chunks` on `run`, record the outcomes and write the reports as they come; a
    chunk of several projects whose task raised is tried again one project at a time.

    The reports of a chunk are written by a writer thread while the next chunk is solved
    (XLA, file writes and fsync release the GIL; `WRITERS` threads, so that one formats
    while another waits for the disk); what each project became is said here, in order, as
    its reports are done."""
    from .._report import write_batch_reports

    done = 0
    writer = concurrent.futures.ThreadPoolExecutor(WRITERS, thread_name_prefix="jaxba-reports")
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
                written.append((members, writer.submit(_record_all, members, outcomes,
                                                       write_batch_reports)))
                report(block=False)
            report(block=True)
            chunks = again
    finally:
        writer.shutdown(wait=True, cancel_futures=True)


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
        write_reports(entry.project, result, entry.out_dir)
    except (ValueError, OSError) as error:
        entry.status, entry.reason = "failed", f"reports not written: {error}"


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


def _summary_row(entry: BatchEntry) -> dict:
    row = {"path": str(entry.path), "name": entry.name, "status": entry.status,
           "reason": entry.reason, "mode": entry.mode}
    if entry.previous is not None:
        return row | _previous_row(entry.previous, entry.spec)
    result = entry.result
    row["converged"] = bool(result.converged) if result is not None else False
    row["sigma0"] = result.sigma0 if result is not None else None
    row["redundancy"] = result.precision.redundancy if result is not None else None
    if result is None:
        return row
    row |= _test_columns(variance_test(result))
    for camera_id, (model, index) in entry.project.camera_rows.items():
        values = np.asarray(result.parameters.cameras[model])[index]
        stds = np.asarray(result.precision.std.cameras[model])[index]
        for name, value, std in zip(CAMERA_MODELS[model].parameter_names, values, stds):
            row[f"{camera_id}.{model}.{name}"] = float(value)
            row[f"{camera_id}.{model}.{name}.std"] = float(std)
    return row


TEST_COLUMNS = ("alpha", "statistic", "low", "high", "passed")


def _test_columns(test) -> dict:
    """The χ² test of σ̂0 (a `VarianceTest`, or results.json's "variance_test"; None: no
    redundancy) as the columns variance_test.alpha, .statistic, .low, .high, .passed."""
    if test is None:
        return dict.fromkeys((f"variance_test.{key}" for key in TEST_COLUMNS), None)
    get = test.get if isinstance(test, dict) else lambda key: getattr(test, key)
    return {f"variance_test.{key}": get(key) for key in TEST_COLUMNS}


def _previous_row(results: dict, spec) -> dict:
    """The summary columns of a project from its results.json (null: a non-finite number);
    the camera models from its project files."""
    row = {"converged": bool(results["converged"]), "sigma0": results["sigma0"],
           "redundancy": results["redundancy"]}
    row |= _test_columns(results.get("variance_test"))
    for camera_id, parameters in results["cameras"].items():
        model = spec.cameras[camera_id].model_key
        for name, entry in parameters.items():
            if entry["status"] != "constant":
                row[f"{camera_id}.{model}.{name}"] = entry["value"]
                row[f"{camera_id}.{model}.{name}.std"] = entry["std"]
    return row


def _json_number(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_summary(rows: list[dict], out_dir: pathlib.Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=columns, restval="")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    cleaned = [{k: _json_number(v) for k, v in row.items()} for row in rows]
    paths = summary_paths(out_dir)
    replace_files({paths["csv"]: table.getvalue(),
                   paths["json"]: json.dumps(cleaned, indent=1)})
