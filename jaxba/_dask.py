"""Independent tasks run in this process, or spread over a Dask cluster.

`jaxba batch --scheduler` (`run_batch`) and `monte_carlo` / `bootstrap` (`scheduler=`) hand
their work out as tasks: a picklable value each, `function(task)` its result. `executor`
gives the runner, `InProcess` (no scheduler: one task after the other, here) or `OnDask`
(every task submitted at once, results as they finish); both give a task that raised its
exception as its result, so the caller decides what a failure means.

On Dask, tasks and results travel with NumPy arrays in place of jax arrays (`numpy_copy`):
a jax array unpickled on a worker before float64 is switched on would come back float32,
and nothing of a device is sent. Before its first task every worker process sets jax up as
the command line does (`setup_jax`: float64, one BLAS thread, the persistent compilation
cache, so each padded shape is compiled once per worker, or loaded). A worker that dies
loses nothing: the scheduler runs its tasks again on the others (distributed's
`allowed-failures`, 3 by default, then the task fails with `KilledWorker`).

Dask (`distributed`) is an optional extra, imported only when a scheduler is named.
"""

import asyncio
import contextlib
import dataclasses
import importlib.util
import io
import os
import pickle
import re
import threading
import warnings
from collections.abc import Callable, Iterator

DASK_EXTRA = "pip install 'jaxba[dask]'"
CONNECT_TIMEOUT_S = 30
_LOCAL = re.compile(r"local(?::(\d+))?")


class SchedulerError(ValueError):
    """A scheduler that cannot be used: Dask not installed, a malformed name, no answer."""


def _is_client(scheduler) -> bool:
    """Whether `scheduler` is a `distributed.Client` (Dask installed)."""
    from distributed import Client

    return isinstance(scheduler, Client)


def local_workers(scheduler: str) -> int | None:
    """The number of workers "local[:N]" asks for (N, else one per CPU); None for an
    address."""
    match = _LOCAL.fullmatch(scheduler)
    if match is None:
        return None
    return int(match.group(1)) if match.group(1) else (os.cpu_count() or 1)


def check_scheduler(scheduler) -> None:
    """Raise `SchedulerError` unless Dask is installed and `scheduler` is "local",
    "local:N" (N >= 1 worker processes on this machine), a scheduler's address
    ("tcp://host:8786", "host:8786") or a `distributed.Client`. Connects to nothing."""
    if importlib.util.find_spec("distributed") is None:
        raise SchedulerError(
            f"scheduler {scheduler!r}: Dask is not installed; install the optional extra:"
            f" {DASK_EXTRA}")
    if _is_client(scheduler):
        return
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise SchedulerError(f"scheduler {scheduler!r}: give 'local', 'local:N' or a Dask"
                             " scheduler's address (tcp://host:8786)")
    if scheduler == "local" or scheduler.startswith("local:"):  # not "localhost:8786"
        match = _LOCAL.fullmatch(scheduler)
        if match is None or (match.group(1) is not None and int(match.group(1)) < 1):
            raise SchedulerError(f"scheduler {scheduler!r}: 'local' or 'local:N' with N >= 1"
                                 " worker processes")


@dataclasses.dataclass(frozen=True)
class InProcess:
    """Tasks one after the other in this process, in order."""

    description: str = "this process"
    workers: int = 1

    def map(self, function: Callable, tasks: list) -> Iterator[tuple[int, object]]:
        """(k, function(tasks[k])) in order; an exception a task raised is its result."""
        for k, task in enumerate(tasks):
            try:
                result = function(task)
            except Exception as error:  # the caller's to judge, as on Dask
                result = error
            yield k, result


class OnDask:
    """Tasks on the workers of a `distributed.Client`, all submitted at once."""

    def __init__(self, client):
        self.client = client

    @property
    def workers(self) -> int:
        return len(self.client.nthreads())

    @property
    def description(self) -> str:
        # The dashboard shows only where bokeh is installed (not in the dask extra).
        dashboard = (self.client.scheduler_info().get("services", {}).get("dashboard")
                     and importlib.util.find_spec("bokeh") is not None)
        where = f", dashboard {self.client.dashboard_link}" if dashboard else ""
        return f"Dask scheduler {self.client.scheduler.address} ({self.workers} workers{where})"

    def map(self, function: Callable, tasks: list) -> Iterator[tuple[int, object]]:
        """(k, result of function(tasks[k])) as the tasks finish; an exception a task
        raised (`KilledWorker` for one whose workers kept dying) is its result. Tasks still
        pending when the caller stops are cancelled."""
        from distributed import as_completed

        futures = {self.client.submit(_on_worker, function, numpy_copy(task), pure=False): k
                   for k, task in enumerate(tasks)}
        try:
            for future in as_completed(list(futures)):
                k = futures.pop(future)
                try:
                    result = future.result()
                except (Exception, asyncio.CancelledError) as error:  # the scheduler gone
                    result = error
                future.release()
                yield k, result
        finally:
            if futures:
                self.client.cancel(list(futures))


@contextlib.contextmanager
def executor(scheduler=None) -> Iterator[InProcess | OnDask]:
    """The runner for `scheduler`: None, in this process; "local" or "local:N", a Dask
    cluster of that many single-threaded worker processes on this machine, started here and
    closed at the end; an address, the scheduler there (its cluster stays); a
    `distributed.Client`, used as it is. Raises `SchedulerError` (`check_scheduler`, or no
    answer from the address within `CONNECT_TIMEOUT_S`)."""
    if scheduler is None:
        yield InProcess()
        return
    check_scheduler(scheduler)
    if _is_client(scheduler):
        yield OnDask(scheduler)
        return
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        n_workers = local_workers(scheduler)
        if n_workers is not None:
            cluster = stack.enter_context(LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=True,
                dashboard_address=":0"))
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout=CONNECT_TIMEOUT_S))
            except (OSError, TimeoutError, ValueError) as error:
                raise SchedulerError(
                    f"scheduler {scheduler!r}: no Dask scheduler answered: {error}") from None
        yield OnDask(client)


class _NumpyPickler(pickle.Pickler):
    """Pickles a jax array as the NumPy array of its values."""

    def __init__(self, file):
        import jax
        import numpy as np

        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._jax_array, self._asarray = jax.Array, np.asarray

    def reducer_override(self, obj):
        if isinstance(obj, self._jax_array):
            return self._asarray, (self._asarray(obj),)
        return NotImplemented


def numpy_copy(value):
    """A deep copy of `value` (anything picklable: dataclasses, equinox modules, lists)
    with every jax array a NumPy array."""
    buffer = io.BytesIO()
    _NumpyPickler(buffer).dump(value)
    return pickle.loads(buffer.getvalue())


_setup_lock = threading.Lock()
_set_up = False


def _on_worker(function: Callable, task):
    """`function(task)` on a Dask worker, jax set up first (once per process); the result
    with NumPy arrays."""
    global _set_up
    with _setup_lock:
        if not _set_up:
            from ._jax_setup import setup_jax

            setup_jax()
            # Workers sharing a cache folder: one may read an entry another is still
            # writing (jax writes in place); jax then compiles the program itself.
            warnings.filterwarnings(
                "ignore", "Error reading persistent compilation cache entry", UserWarning)
            _set_up = True
    return numpy_copy(function(task))
