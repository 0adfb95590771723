"""Phase timings: compilations are counted inside the phase that triggers them, announced
before a big one, and not counted again for a program already compiled."""

import platform
import subprocess
import threading

import jax
import jax.numpy as jnp
import pytest

from jaxba._memory import _glibc, tune_allocator
from jaxba._timing import CompileLog, Phase, Timings

N_OPS = 3000  # enough operations that lowering the program takes well over _LONG_LOWERING


def _big(x):
    for k in range(N_OPS):
        x = jnp.sin(x) + k
    return x


def test_phases_count_compilations_and_announce_big_ones():
    announced = []
    timings = Timings(on_compile=announced.append)
    big = jax.jit(_big)
    with timings.phase("first"):
        big(jnp.ones(3)).block_until_ready()
    with timings.phase("again"):
        big(jnp.ones(3)).block_until_ready()  # compiled already: nothing to count
    first, again = timings.phases
    assert announced == ["first"]
    assert first.compilations >= 1 and 0 < first.compile_seconds <= first.seconds
    assert again.compilations == 0 and again.compile_seconds == 0.0
    summary = timings.summary()
    assert summary["compile"] == pytest.approx(first.compile_seconds)
    assert summary["total"] == pytest.approx(first.seconds + again.seconds)


def test_nested_logs_both_count_and_a_repeated_phase_adds_up():
    timings = Timings()
    with CompileLog() as outer:
        with timings.phase("solve"):
            jax.jit(lambda x: x * 3.0 + 1.0)(jnp.ones(4)).block_until_ready()
    assert outer.count == timings.compilations >= 1
    timings.add(Phase("solve", 1.0, 0.5, 2, 1))
    (solve,) = timings.phases
    assert solve.compilations == outer.count + 2 and solve.cache_hits >= 1


def test_only_phases_that_compile_release_free_memory(monkeypatch):
    """malloc_trim (20-40 ms in a process that has compiled much) runs after a phase that
    compiled a program, not after one that only ran compiled ones."""
    released = []
    monkeypatch.setattr("jaxba._timing.release_free_memory", lambda: released.append(1))
    timings = Timings()
    double = jax.jit(lambda x: 2.0 * x - 1.0)
    with timings.phase("compiles"):
        double(jnp.ones(5)).block_until_ready()
    assert len(released) == 1
    with timings.phase("runs"):
        double(jnp.ones(5)).block_until_ready()
    assert len(released) == 1


def test_a_log_counts_its_own_threads_compilations_only():
    """A program compiled on another thread while a log is open is not this thread's
    compile time (`compiled_ahead` counts it where it is called)."""
    with CompileLog() as log:
        worker = threading.Thread(
            target=lambda: jax.jit(lambda x: x * 5.0 - 2.0)(jnp.ones(7)).block_until_ready())
        worker.start()
        worker.join()
    assert log.count == 0 and log.seconds == 0.0
    with CompileLog() as log:
        jax.jit(lambda x: x * 5.0 - 3.0)(jnp.ones(7)).block_until_ready()
    assert log.count == 1 and log.seconds > 0.0


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc_trim and mallopt")
def test_the_c_library_is_found_without_starting_a_process(monkeypatch):
    """glibc comes from the process's own symbols: `ctypes.util.find_library` spawned
    `ldconfig -p` at every start-up."""
    def no_process(*args, **kwargs):
        raise AssertionError("a process was started")

    monkeypatch.setattr(subprocess.Popen, "__init__", no_process)
    _glibc.cache_clear()
    try:
        libc = _glibc()
        assert libc is not None
        assert libc.malloc_trim(0) in (0, 1)  # glibc's: 1 where memory was released
        tune_allocator()
    finally:
        _glibc.cache_clear()
