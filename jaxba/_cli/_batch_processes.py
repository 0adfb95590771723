"""`jaxba batch` on several worker processes of this machine: each adjusts a share of the
projects from end to end (build, solve, statistics, reports), so that every core works on
the whole per-project pipeline, reports included, and not only on the compiled solve.

Every output is checked once, here (`read_batch`); the pending projects, read here whole or
only their project files (the command line's: a worker reads the tables of its share), are
dealt out to `jobs` processes in contiguous shares (projects of one kind usually sit
together, so each share pads and compiles few shapes; the programs are shared through the
persistent compilation cache). A worker sends its progress lines and one message per
finished project back through a queue, and returns what became of each of its projects
(status, reason, mode and summary row), from which the caller writes the summary.
A forked copy of a process that runs jax's threads is not safe, and the caller itself never
loads jax. On Linux the workers are forked from a "forkserver" process that imports the
pipeline once (`PRELOAD`, ~1.5 CPU s; importing starts none of jax's threads) and forks a
worker per share, which then sets up jax; elsewhere each worker is spawned and imports the
pipeline itself. They are started on a thread of the caller before the projects are read
(`worker_processes`), so that the forkserver's imports overlap the reading of the project
files. The forkserver, which holds the caller's stdout and stderr, ends at once when the
caller does (`_end_at_once`): a reader of the batch's output (a pipe, `| tee`) is not kept
waiting while it tears down what it imported.
"""

import atexit
import concurrent.futures
import contextlib
import dataclasses
import itertools
import math
import multiprocessing
import os
import queue as queue_module
import sys
import threading
import time
from collections.abc import Callable, Iterator

from ._batch_read import PROJECT_ERRORS, BatchEntry, read_whole

# Seconds to wait, once every share has returned, for messages still on their way.
LAST_MESSAGES = 10.0

_queue = None  # a worker's channel to the parent (set by `_start_worker`)

# What every worker runs, imported once by the forkserver before it forks the workers: the
# pipeline, and what its first solve would import in each worker (scipy's BLAS, which jax's
# CPU linear algebra loads when it first lowers a program; the special functions of the
# statistics' χ² and normal quantiles: ~0.1 s together).
# Last, this module: in the forkserver it sets up the quick exit (`_end_at_once`).
PRELOAD = ("jaxba._cli._batch_adjust", "jaxba._report._write", "jaxba._jax_setup",
           "scipy.linalg.cython_blas", "scipy.special", "jaxba._cli._batch_processes")


@dataclasses.dataclass(frozen=True)
class Share:
    """The projects one worker adjusts, and how (`run_batch`'s `chunk_size`)."""

    entries: list[BatchEntry]
    chunk_size: int | None


@dataclasses.dataclass(frozen=True)
class Workers:
    """Worker processes (`worker_processes`): the pool, the channel their messages come back
    on, how many there are, and the thread that starts them (`ready` waits for it)."""

    pool: concurrent.futures.ProcessPoolExecutor
    channel: object
    size: int
    starter: concurrent.futures.Future

    def ready(self) -> None:
        """Wait until every worker has been started; raise what stopped one."""
        self.starter.result()


@contextlib.contextmanager
def worker_processes(n: int) -> Iterator[Workers | None]:
    """`n` worker processes started now, on a thread, while the caller goes on (reading the
    projects): starting the first waits for the forkserver's imports (~1 s). Each worker
    sets up jax and imports the pipeline. Shut down when the block ends, after their work.
    None for n < 2 (nothing started: all in the calling process)."""
    if n < 2:
        yield None
        return
    context = _start_method()
    channel = context.Queue()
    with concurrent.futures.ProcessPoolExecutor(
            n, mp_context=context, initializer=_start_worker, initargs=(channel,)) as pool:
        starter: concurrent.futures.Future = concurrent.futures.Future()
        threading.Thread(target=_start_all, args=(pool, n, starter), daemon=True,
                         name="jaxba-worker-start").start()
        try:
            yield Workers(pool, channel, n, starter)
        finally:
            concurrent.futures.wait([starter])  # no shutdown while a start is under way


def _start_all(pool: concurrent.futures.ProcessPoolExecutor, n: int,
               starter: concurrent.futures.Future) -> None:
    """Start the `n` processes of `pool` (a process is started per task while none is idle);
    `starter` gets None, or the exception that stopped a start."""
    try:
        for _ in range(n):
            pool.submit(_started)
    except BaseException as error:  # noqa: BLE001 (handed to the caller, `Workers.ready`)
        starter.set_exception(error)
    else:
        starter.set_result(None)


def _start_method() -> multiprocessing.context.BaseContext:
    """How workers start: forked from a forkserver that imported `PRELOAD` (Linux), else
    spawned (macOS' system libraries are not safe to fork; Windows cannot)."""
    if sys.platform.startswith("linux"):
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(list(PRELOAD))
        return context
    return multiprocessing.get_context("spawn")


def _started() -> None:
    """A task that does nothing: submitting it starts a worker."""


def shares(entries: list[BatchEntry], jobs: int) -> list[list[BatchEntry]]:
    """`entries` cut into at most `jobs` contiguous shares of nearly equal length."""
    jobs = max(1, min(jobs, len(entries)))
    size, extra = divmod(len(entries), jobs)
    out, start = [], 0
    for k in range(jobs):
        stop = start + size + (k < extra)
        out.append(entries[start:stop])
        start = stop
    return [share for share in out if share]


def run_on_processes(
    entries: list[BatchEntry],
    workers: Workers,
    jobs: int,
    chunk_size: int | None,
    say: Callable[[str], None],
    finished: Callable[[], None],
) -> None:
    """Adjust the pending `entries` in `jobs` shares on `workers` (the in-process pipeline,
    `_batch_adjust.adjust_entries`, runs in each); fills in each entry's status, reason,
    mode and `row` (its summary row). A worker that dies (killed, out of memory) fails its
    projects that were not finished, with that reason; the others go on."""
    parts = shares(entries, jobs)
    _read_while_starting(parts, workers.starter)
    workers.ready()
    say(f"adjusting on {len(parts)} worker processes")
    futures = {workers.pool.submit(_adjust_share, Share(_portable(part), chunk_size)): part
               for part in parts}
    # A share's result can reach the pool before its last messages reach the channel
    # (a queue's feeder thread): relay until every share that returned said it was done.
    # (A worker killed in between never says so: wait for it at most LAST_MESSAGES s.)
    pending, shares_done, returned, last = set(futures), 0, 0, math.inf
    while pending or (shares_done < returned and time.monotonic() < last):
        shares_done += _relay(workers.channel, say, finished, timeout=0.1)
        done = {future for future in pending if future.done()}
        for future in done:
            returned += _record(futures[future], future)
        pending -= done
        if not pending and last == math.inf:
            last = time.monotonic() + LAST_MESSAGES


def _read_while_starting(parts: list[list[BatchEntry]],
                         starter: concurrent.futures.Future) -> None:
    """Read the tables of the shares' projects here, one project of each share in turn,
    until the workers are started (`starter` done): the forkserver's imports take ~1 s in
    which this process would wait. The workers read the others' tables. A project that
    cannot be read is left to its worker, which fails it with the reason."""
    for row in itertools.zip_longest(*parts):
        for entry in row:
            if starter.done():
                return
            if entry is not None and entry.spec is None:
                with contextlib.suppress(*PROJECT_ERRORS):
                    entry.spec = read_whole(entry)


def _portable(part: list[BatchEntry]) -> list[BatchEntry]:
    """The entries as a worker needs them: what was read, nothing built."""
    return [dataclasses.replace(entry, project=None, result=None) for entry in part]


def _relay(channel, say, finished, timeout: float) -> int:
    """Pass the workers' messages on, waiting at most `timeout` s for the first one; the
    number of shares they said were done."""
    shares_done = 0
    try:
        message = channel.get(timeout=timeout)
        while True:
            kind, text = message
            if kind == "say":
                say(text)
            elif kind == "finished":
                finished()
            else:
                shares_done += 1
            message = channel.get_nowait()
    except queue_module.Empty:
        return shares_done


def _record(part: list[BatchEntry], future: concurrent.futures.Future) -> bool:
    """The share's outcomes into its entries; whether its worker returned them."""
    returned = True
    try:
        outcomes = future.result()
    except concurrent.futures.process.BrokenProcessPool as error:
        returned = False
        outcomes = [("failed", f"its worker process ended unexpectedly ({error})", "", None)
                    for _ in part]
    for entry, (status, reason, mode, row) in zip(part, outcomes):
        entry.status, entry.reason, entry.mode, entry.row = status, reason, mode, row
    return returned


def _start_worker(channel) -> None:
    """A worker's start: jax set up as the command line does, the pipeline and the reports
    imported and frozen (`freeze_long_lived`: they live as long as the worker), the
    channel kept."""
    global _queue
    from .. import _report
    from .._gc import freeze_long_lived
    from .._jax_setup import setup_jax
    from . import _batch_adjust

    setup_jax()
    _batch_adjust.adjust_entries  # imported now, frozen with the rest
    _report.write_batch_reports
    freeze_long_lived()
    _queue = channel


def _adjust_share(share: Share) -> list[tuple]:
    """In a worker: adjust the share's projects and return (status, reason, mode, summary
    row) of each, in order."""
    from ._batch_adjust import adjust_entries

    adjust_entries(share.entries, lambda line: _queue.put(("say", line)),
                   lambda: _queue.put(("finished", "")), share.chunk_size, writers=1)
    _queue.put(("done", ""))  # after this share's messages: the channel keeps their order
    return [(entry.status, entry.reason, entry.mode, entry.row) for entry in share.entries]


def _end_at_once() -> None:
    """The forkserver's exit: its stdio flushed, then `os._exit`, without the interpreter's
    clean-up. The forkserver keeps the caller's stdout and stderr (inherited) open until it
    ends, and tearing down what it imported (jax, the pipeline, scipy) took ~0.2 s after the
    caller had finished; it holds no file of its own."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(0)


def _imported_by_a_forkserver() -> bool:
    """Whether this module is being imported by a forkserver's preload (a frame of
    `multiprocessing.forkserver.main` on the stack): only then is this process a
    forkserver (which has imported that module to run it)."""
    forkserver = sys.modules.get("multiprocessing.forkserver")
    if forkserver is None:
        return False
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code is forkserver.main.__code__:
            return True
        frame = frame.f_back
    return False


if _imported_by_a_forkserver():
    atexit.register(_end_at_once)
