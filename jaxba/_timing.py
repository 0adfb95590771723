"""Where a run's time goes: wall seconds per phase and the compilations inside each.

jax reports every trace, lowering and backend compilation (or load from the persistent
compilation cache) through `jax.monitoring`; `CompileLog` sums them while it is open, so a
phase's compile seconds can be told from its run seconds. One listener is registered once
per process and feeds every open log. At the end of every phase that compiled (or loaded)
a program the C heap's free pages are returned to the system (`jaxba._memory`): a phase's
compilations must not raise the next phase's memory. Phases that compile nothing (the
re-adjustments of variance components and data snooping) skip it: `malloc_trim` walks the
whole heap, 20-40 ms a call in a process that has compiled many programs.

A log holds its own thread's events. A program compiled ahead on a worker thread
(`jaxba._programs.compile_ahead`) counts where it is first called (`compiled_ahead`), with
the seconds the caller waited for it: the wall time its compilation cost the run, not its
work.
"""

import concurrent.futures
import contextlib
import dataclasses
import threading
import time
from collections.abc import Callable, Iterator

import jax

from ._memory import release_free_memory

# jax._src.dispatch's event names: tracing to a jaxpr, lowering to MLIR, backend compile
# (which includes looking the executable up in the persistent cache).
_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_COMPILE = "/jax/core/compile/backend_compile_duration"
_CACHE_HIT = "/jax/compilation_cache/cache_hits"
# A program that takes this long to lower is big: its compilation takes seconds.
_LONG_LOWERING = 0.05

_open_logs: list["CompileLog"] = []
_registered = False


def _thread_logs() -> list["CompileLog"]:
    """The logs open on the calling thread."""
    thread = threading.get_ident()
    return [log for log in _open_logs if log.thread == thread]


def _on_duration(event: str, duration: float, **kwargs) -> None:
    if event not in (_TRACE, _LOWER, _COMPILE):
        return
    for log in _thread_logs():
        log.seconds += duration
        if event == _LOWER and duration >= _LONG_LOWERING:
            log.announce()
        if event == _COMPILE:
            log.count += 1


def _on_event(event: str, **kwargs) -> None:
    if event == _CACHE_HIT:
        for log in _thread_logs():
            log.cache_hits += 1


def compiled_ahead(future: concurrent.futures.Future):
    """The result of `future`, (a program, the `CompileLog` it was compiled under on another
    thread), counted in this thread's open logs: its programs and cache hits, and the
    seconds this thread waited for it (their `on_compile` called first where it waits).
    Returns the program."""
    logs = _thread_logs()
    start = time.perf_counter()
    if not future.done():
        for log in logs:
            log.announce()
    program, compiled = future.result()
    seconds = time.perf_counter() - start
    for log in logs:
        log.seconds += seconds
        log.count += compiled.count
        log.cache_hits += compiled.cache_hits
    return program


def _register() -> None:
    global _registered
    if not _registered:
        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        jax.monitoring.register_event_listener(_on_event)
        _registered = True


@dataclasses.dataclass(eq=False)  # identity: nested logs must not be confused
class CompileLog:
    """Tracing + lowering + compiling seconds and the number of programs compiled (or loaded
    from the persistent cache: `cache_hits` of them) on the thread that opened it while the
    `with` block runs (`compiled_ahead`: programs compiled for it on another).
    `on_compile()` is called once, when the first big program (lowered in `_LONG_LOWERING`
    seconds or more) has been lowered, just before its backend compilation (or its look-up
    in the persistent cache) starts."""

    on_compile: Callable[[], None] | None = None
    seconds: float = 0.0
    count: int = 0
    cache_hits: int = 0
    announced: bool = False
    thread: int = 0  # the thread that opened it

    def __enter__(self) -> "CompileLog":
        _register()
        self.thread = threading.get_ident()
        _open_logs.append(self)
        return self

    def announce(self) -> None:
        """Call `on_compile`, once."""
        if not self.announced:
            self.announced = True
            if self.on_compile is not None:
                self.on_compile()

    def __exit__(self, *exc) -> None:
        _open_logs.remove(self)


@dataclasses.dataclass(frozen=True)
class Phase:
    """One phase of a run: wall `seconds`, of which `compile_seconds` tracing and compiling
    `compilations` programs (`cache_hits` of them loaded from the persistent cache)."""

    name: str
    seconds: float
    compile_seconds: float
    compilations: int
    cache_hits: int


@dataclasses.dataclass
class Timings:
    """The phases of a run in order (a phase timed twice adds up). `on_compile(name)` is
    called once per timed block, when phase `name` is about to compile its first big
    program (see `CompileLog`)."""

    phases: list[Phase] = dataclasses.field(default_factory=list)
    on_compile: Callable[[str], None] | None = None

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time the block as phase `name`."""
        start = time.perf_counter()
        notify = None if self.on_compile is None else (lambda: self.on_compile(name))
        with CompileLog(on_compile=notify) as log:
            yield
        if log.count:  # only compilations leave much free heap (malloc_trim: 20-40 ms)
            release_free_memory()
        self.add(Phase(name, time.perf_counter() - start, log.seconds, log.count,
                       log.cache_hits))

    def add(self, phase: Phase) -> None:
        for k, known in enumerate(self.phases):
            if known.name == phase.name:
                self.phases[k] = Phase(
                    phase.name, known.seconds + phase.seconds,
                    known.compile_seconds + phase.compile_seconds,
                    known.compilations + phase.compilations, known.cache_hits + phase.cache_hits)
                return
        self.phases.append(phase)

    def summary(self) -> dict[str, float]:
        """{phase: run seconds (compile excluded)} in order, then "compile" (all phases'
        compile seconds) and "total" (wall)."""
        out = {p.name: p.seconds - p.compile_seconds for p in self.phases}
        out["compile"] = sum(p.compile_seconds for p in self.phases)
        out["total"] = sum(p.seconds for p in self.phases)
        return out

    def text(self) -> str:
        """E.g. `seconds: read 0.02, start-up 1.1, solve 0.03, ...; compile 4.2 (31 programs,
        29 from the cache); total 5.4`: each phase's run seconds, compilation apart."""
        summary = self.summary()
        phases = ", ".join(
            f"{name} {seconds:.2f}" for name, seconds in summary.items()
            if name not in ("compile", "total"))
        return (
            f"seconds: {phases}; compile {summary['compile']:.2f} ({self.compilations}"
            f" programs, {self.cache_hits} from the cache); total {summary['total']:.2f}")

    @property
    def compilations(self) -> int:
        return sum(p.compilations for p in self.phases)

    @property
    def cache_hits(self) -> int:
        return sum(p.cache_hits for p in self.phases)
