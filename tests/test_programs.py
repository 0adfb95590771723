"""Stored programs (`jaxba._programs`): a program called through its stored export gives the
traced program's results (bit for bit; the batch's to `EXPORT_RTOL`); a corrupt, stale or
unusable file, an unexportable program, arguments without a key or no cache folder fall back
to tracing; a changed structure gets a new key."""

import os
import pathlib
import subprocess
import sys
import textwrap
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array, Float

import jaxba
from jaxba import _programs
from jaxba._adjust import _batch
from jaxba._timing import CompileLog

ROOT = pathlib.Path(jaxba.__file__).resolve().parents[1]

# The exported and the traced programs compile to the same arithmetic: bit-identical with
# XLA's default flags. Under the tests' cheaper compilation (conftest.py) XLA compiles some
# loops and sums apart in an export and in the traced program, so that they round
# differently, ~2e-16 of an array's scale. A residual, a difference of two coordinates,
# carries the coordinates' rounding: 2e-15 mm of 10 mm on a residual of 3e-6 mm.
EXPORT_RTOL = 1e-12


class Box(eqx.Module):
    x: Float[Array, " n"]
    scale: float = eqx.field(static=True)


@eqx.filter_jit
def _program(box: Box, y, power: int):
    return Box(box.x * box.scale + y**power, box.scale), jnp.sum(jnp.sin(y))


_TESTS = Box.__module__.partition(".")[0]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """Exports stored in a folder of this test's own; none loaded in this process yet; this
    module's classes keyed like jaxba's."""
    monkeypatch.setattr(_programs, "_KNOWN", _programs._KNOWN | {_TESTS})
    monkeypatch.setattr(_programs, "_cache_folder", lambda: tmp_path)
    monkeypatch.setattr(_programs, "_loaded", {})
    monkeypatch.setattr(_programs, "_traced", set())
    return tmp_path / _programs.FOLDER


def _call(box, y, power=2, program=_program):
    return _programs.call_stored("test_box", program, (box, y), (power,))


def _equal(a, b) -> bool:
    leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
    return (jax.tree.structure(a) == jax.tree.structure(b)
            and all(np.array_equal(p, q) for p, q in zip(leaves_a, leaves_b)))


def _close(a, b) -> bool:
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.allclose(p, q, rtol=EXPORT_RTOL, atol=0.0)
        for p, q in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def _assert_residuals_close(result, reference, observed: float):
    """The residuals observed - computed equal to `EXPORT_RTOL` of the largest observation
    `observed` (not entry by entry: see `EXPORT_RTOL`)."""
    for got, expected in zip(result.residuals, reference.residuals, strict=True):
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=EXPORT_RTOL * observed)


def _largest_observation(problem) -> float:
    return max(float(np.max(np.abs(np.asarray(value)[np.isfinite(value)]), initial=0.0))
               for group in problem.groups
               for value in [getattr(group, "measured", getattr(group, "observed", 0.0))])


def _usable(path, box, y) -> bool:
    """A stored export that fits `_call(box, y)`'s arguments (digest, signature)."""
    leaves = jax.tree.leaves(eqx.filter((box, y), eqx.is_array))
    return _programs._load(path, leaves) is not None


def _box(n=5, scale=1.5, dtype=np.float64):
    return Box(jax.device_put(np.linspace(0.1, 1.0, n).astype(dtype)), scale)


def test_no_cache_folder_or_an_unwritable_one(tmp_path, monkeypatch):
    """No cache folder: traced, nothing written. A folder that cannot be made (under a
    file): the export is called, nothing written, no error."""
    monkeypatch.setattr(_programs, "_KNOWN", _programs._KNOWN | {_TESTS})
    monkeypatch.setattr(_programs, "_loaded", {})
    monkeypatch.setattr(_programs, "_traced", set())
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    monkeypatch.setattr(_programs, "_cache_folder", lambda: None)
    assert _equal(_call(box, y), _program(box, y, 2)) and not _programs._loaded
    blocked = tmp_path / "a file"
    blocked.write_text("")
    monkeypatch.setattr(_programs, "_cache_folder", lambda: blocked)
    assert _equal(_call(box, y), _program(box, y, 2))
    assert list(tmp_path.iterdir()) == [blocked]


def test_a_stored_program_gives_the_traced_results(folder):
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    traced = _program(box, y, 2)
    first = _call(box, y)  # exported, stored, called
    (path,) = folder.iterdir()
    _programs._loaded.clear()  # a later process: read from the file
    second = _call(box, y)
    assert _equal(first, traced) and _equal(second, traced)
    assert list(folder.iterdir()) == [path]
    assert second[0].scale == box.scale


def test_forgotten_programs_are_loaded_again(folder):
    """`forget_loaded` drops the programs this process loaded, as `jax.clear_caches` drops
    jax's: the next call loads the stored export again and counts it, as a fresh process."""
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    first = _call(box, y)
    with CompileLog() as kept:
        _call(box, y)
    _programs.forget_loaded()
    jax.clear_caches()
    assert not _programs._loaded
    with CompileLog() as again:
        second = _call(box, y)
    assert kept.count == 0 and again.count == 1
    assert _equal(first, second) and _programs._loaded


def test_a_changed_structure_gets_a_new_key(folder):
    y = jax.device_put(np.linspace(-1.0, 2.0, 5))
    _call(_box(), y)
    _call(_box(), y)  # same key: no new file
    assert len(list(folder.iterdir())) == 1
    variants = [
        (_box(scale=2.0), y, 2),  # a static field
        (_box(), y, 3),  # a static argument
        (_box(n=6), jax.device_put(np.linspace(-1.0, 2.0, 6)), 2),  # shapes
        (_box(dtype=np.float32), jax.device_put(np.linspace(-1.0, 2.0, 5, dtype=np.float32)),
         2),  # dtypes
    ]
    for k, (box, y_, power) in enumerate(variants):
        assert _equal(_call(box, y_, power), _program(box, y_, power))
        assert len(list(folder.iterdir())) == 2 + k


def test_a_corrupt_file_is_ignored_and_replaced(folder):
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    _call(box, y)
    (path,) = folder.iterdir()
    good = path.read_bytes()
    for bad in (good[:-1] + bytes([good[-1] ^ 1]), good[: len(good) // 2], b""):
        path.write_bytes(bad)
        assert not _usable(path, box, y)
        _programs._loaded.clear()
        assert _equal(_call(box, y), _program(box, y, 2))
        assert _usable(path, box, y)  # stored anew


def test_a_stale_file_is_ignored_and_replaced(folder):
    """A file whose export does not fit the arguments (another program's, with a valid
    digest) is not called: the program is exported and stored anew."""
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    _call(_box(n=6), jax.device_put(np.linspace(-1.0, 2.0, 6)))
    (other,) = folder.iterdir()
    _call(box, y)
    (path,) = set(folder.iterdir()) - {other}
    path.write_bytes(other.read_bytes())
    assert not _usable(path, box, y)
    _programs._loaded.clear()
    assert _equal(_call(box, y), _program(box, y, 2))
    assert _usable(path, box, y)


def test_a_failing_call_falls_back_and_drops_the_file(folder, monkeypatch):
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    _call(box, y)
    (path,) = folder.iterdir()

    def broken(*args):
        raise RuntimeError("an export that cannot run")

    key = next(iter(_programs._loaded))
    _programs._loaded[key] = (broken, *_programs._loaded[key][1:])
    assert _equal(_call(box, y), _program(box, y, 2))
    assert not path.exists() and key not in _programs._loaded


def test_no_export_where_none_can_be_made_or_used(folder, monkeypatch):
    """No file, the traced results: with jit disabled, for arguments without a faithful key
    (a function in a static field), while a registry that traces look classes up in holds
    one from outside jaxba and its libraries (a user's camera model: here a class of
    pathlib), for a program jax cannot export (a host callback) and for an output that
    cannot be pickled (a function made inside the program)."""
    y = jax.device_put(np.linspace(-1.0, 2.0, 5))
    with monkeypatch.context() as patch:  # a registry holding a user's class
        patch.setattr(_programs, "_lookups", [*_programs._lookups, lambda: (pathlib.PurePath,)])
        user = _programs.call_stored("test_box", _program, (_box(), y), (2,))
    assert _equal(user, _program(_box(), y, 2)) and not _programs._loaded
    with jax.disable_jit():
        assert _equal(_call(_box(), y), _program(_box(), y, 2))

    class WithFunction(eqx.Module):
        x: Float[Array, " n"]
        f: object = eqx.field(static=True)

    odd = WithFunction(y, np.sin)
    plus_one = _programs.call_stored("test_odd", eqx.filter_jit(lambda w: w.x + 1), (odd,))
    assert np.array_equal(plus_one, np.asarray(y) + 1)

    traces = []

    @eqx.filter_jit
    def with_callback(box, y, power):
        traces.append(1)
        host = jax.pure_callback(np.cos, jax.ShapeDtypeStruct(y.shape, y.dtype), y)
        return Box(box.x + host, box.scale), jnp.sum(y)

    box = _box()
    called = _programs.call_stored("test_callback", with_callback, (box, y), (2,))
    assert _equal(called, with_callback(box, y, 2))
    first = len(traces)
    for _ in range(2):  # no second try at exporting it in this process
        _programs.call_stored("test_callback", with_callback, (box, y), (2,))
    assert len(traces) == first

    @eqx.filter_jit
    def unpicklable(box, y, power):
        return WithFunction(box.x * y**power, lambda v: v)

    local = _programs.call_stored("test_local", unpicklable, (box, y), (2,))
    assert np.array_equal(local.x, unpicklable(box, y, 2).x)
    assert not folder.exists() or not list(folder.iterdir())


def test_the_batch_program_is_stored_then_loaded(folder, tmp_path, monkeypatch):
    """`adjust_padded` of two projects: the first call exports and stores the batch's
    program, a later process (nothing loaded yet) reads it and exports nothing; both equal
    the traced program's adjustments: estimates, covariance and σ̂0² entry by entry to
    `EXPORT_RTOL`, the residuals to `EXPORT_RTOL` of the largest observation."""
    problems = [
        jaxba.build_project(jaxba.read_project(jaxba.write_synthetic_project(
            tmp_path / f"p{k}", name=f"p{k}", seed=50 + k, n_images=6, n_targets=20,
        ).project_file)).problem
        for k in range(2)
    ]
    batch = _batch.pad_problems(problems)
    stored = _batch.adjust_padded(batch, max_steps=30)
    assert len(list(folder.glob("batch_adjust-*"))) == 1
    _programs._loaded.clear()
    monkeypatch.setattr(_programs, "_export", None)  # an export now would fail the test
    loaded = _batch.adjust_padded(batch, max_steps=30)
    monkeypatch.setattr(_programs, "_cache_folder", lambda: None)
    traced = _batch.adjust_padded(batch, max_steps=30)
    assert all(t.converged for t in traced)

    def estimates(result):
        return (jaxba.advanced.flatten(result.parameters), result.precision.covariance,
                result.precision.sigma0_squared)

    for results in (stored, loaded):
        for result, reference, problem in zip(results, traced, problems, strict=True):
            assert _close(estimates(result), estimates(reference))
            _assert_residuals_close(result, reference, _largest_observation(problem))


@pytest.mark.parametrize("backend", ["dense", "schur"])
def test_an_adjustment_is_stored_then_loaded(folder, tmp_path, monkeypatch, backend):
    """`jaxba.adjust` with every step reported (as the command line runs it): the first call
    stores its programs (the steps among them), a later process reads them and exports
    nothing; both equal the traced programs' estimates and σ to `EXPORT_RTOL` of each
    array's largest value (not of every entry, see `EXPORT_RTOL`), and their residuals to
    `EXPORT_RTOL` of the largest observation."""
    project = jaxba.build_project(jaxba.read_project(jaxba.write_synthetic_project(
        tmp_path / "p", name="p", seed=7, n_images=6, n_targets=20).project_file))
    heard = []

    def adjust():
        heard.append([])
        return jaxba.adjust(project.problem, solver=backend, on_iteration=heard[-1].append)

    stored = adjust()
    names = {path.name.rpartition("-")[0] for path in folder.iterdir()}
    assert {"lm_init", "lm_step", "solve_setup" if backend == "dense" else "normal_equations",
            "whitened_residuals" if backend == "dense" else "schur_cofactors"} <= names
    _programs._loaded.clear()
    monkeypatch.setattr(_programs, "_export", None)  # an export now would fail the test
    loaded = adjust()
    monkeypatch.setattr(_programs, "_cache_folder", lambda: None)
    traced = adjust()
    assert traced.converged and traced.backend == backend
    assert stored.steps == loaded.steps == traced.steps
    assert len(heard[0]) == len(heard[1]) == len(heard[2]) > 1

    def estimates(result):
        return (jaxba.advanced.flatten(result.parameters),
                jaxba.advanced.flatten(result.precision.std), result.precision.sigma0_squared)

    for result in (stored, loaded):
        for got, expected in zip(estimates(result), estimates(traced), strict=True):
            np.testing.assert_allclose(got, expected, rtol=0.0,
                                       atol=EXPORT_RTOL * np.abs(expected).max())
        _assert_residuals_close(result, traced, _largest_observation(project.problem))


def test_a_registry_changed_by_the_trace_stores_nothing(folder, monkeypatch):
    """A trace that resolves a class by a new name (a camera model first named in it)
    changes what a key holds: nothing is stored under the key made before; the next call,
    the registry settled, stores its export."""
    entries = []
    monkeypatch.setattr(_programs, "_lookups", [*_programs._lookups, lambda: tuple(entries)])

    @eqx.filter_jit
    def resolving(box, y, power):
        if Box not in entries:
            entries.append(Box)
        return _program(box, y, power)

    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    first = _programs.call_stored("test_resolving", resolving, (box, y), (2,))
    assert _equal(first, _program(box, y, 2))
    assert entries == [Box] and (not folder.exists() or not list(folder.iterdir()))
    second = _programs.call_stored("test_resolving", resolving, (box, y), (2,))
    assert _equal(second, _program(box, y, 2)) and len(list(folder.iterdir())) == 1


def test_under_a_transformation_the_program_is_nested(folder):
    """Called on tracers (inside `jax.grad`, `jax.jit`): the program itself, nested in the
    caller's trace, so that derivatives and jit pass through it (an export has neither)."""
    box = _box()

    def total(scale):
        moved, _ = _call(Box(box.x * scale, box.scale), jnp.linspace(-1.0, 2.0, 5) * scale)
        return jnp.sum(moved.x)

    step = 1e-6
    numeric = (total(1.0 + step) - total(1.0 - step)) / (2 * step)
    assert np.isclose(jax.grad(total)(1.0), numeric, rtol=1e-6)
    assert np.isclose(jax.jit(total)(1.0), total(1.0))


def test_a_program_compiled_ahead_is_compiled_once_and_counted_where_called(folder,
                                                                            monkeypatch):
    """`compile_ahead` with shapes only (`jax.ShapeDtypeStruct`): the worker exports and
    compiles; the later call with arrays of those shapes compiles nothing more, gives the
    traced results and counts the program (and the seconds waited) in the caller's log,
    none in a log of the worker's thread's events. Stored by an earlier process: no job."""
    monkeypatch.setattr(_programs, "_ahead", {})
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    shapes = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), (box, y))
    compiled = []

    def on_duration(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(threading.get_ident())

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    try:
        with CompileLog() as before:
            _programs.compile_ahead("test_box", _program, shapes, (2,))
            _programs.compile_ahead("test_box", _program, shapes, (2,))  # on its way: no job
        with CompileLog() as log:
            first = _call(box, y)
        second = _call(box, y)
    finally:
        jax.monitoring.unregister_event_duration_listener(on_duration)
    assert _equal(first, _program(box, y, 2)) and _equal(second, first)
    assert len(compiled) == 1 and compiled[0] != threading.get_ident()  # the worker's
    assert before.count == 0 and log.count == 1 and log.seconds >= 0.0
    assert not _programs._ahead and len(list(folder.iterdir())) == 1
    _programs._loaded.clear()  # a later process: stored already, nothing to compile ahead
    _programs.compile_ahead("test_box", _program, shapes, (2,))
    assert not _programs._ahead


def test_nothing_compiled_ahead_without_a_key(folder, monkeypatch):
    """Arguments without a key (a lambda) or no cache folder: no job, the call traces."""
    monkeypatch.setattr(_programs, "_ahead", {})
    box, y = _box(), jax.device_put(np.linspace(-1.0, 2.0, 5))
    _programs.compile_ahead("test_box", _program, (box, y), (lambda: 2,))
    monkeypatch.setattr(_programs, "_cache_folder", lambda: None)
    _programs.compile_ahead("test_box", _program, (box, y), (2,))
    assert not _programs._ahead and not _programs._loaded


def test_a_process_ending_while_a_program_compiles_ahead_ends_cleanly(tmp_path):
    """A process that exits (an error, a refused datum) while the worker traces or compiles
    exits with its own status: the running job is waited for (a thread compiling while the
    interpreter finalized crashed the process: SIGSEGV, SIGABRT)."""
    script = tmp_path / "exit.py"
    script.write_text(textwrap.dedent(f"""
        import sys
        import time
        import equinox as eqx
        import jax
        import jax.numpy as jnp
        jax.config.update("jax_enable_x64", True)
        jax.config.update("jax_compilation_cache_dir", {str(tmp_path / "cache")!r})
        from jaxba import _programs
        _programs._KNOWN = _programs._KNOWN | {{"__main__"}}

        @eqx.filter_jit
        def program(x):
            for k in range(60):  # some kernels: a compilation of a second or so
                x = jnp.sin(x) * k + jnp.cos(x * 0.5 + k)
                x = x.at[k % 50].set(jnp.sum(x))
            return x

        _programs.compile_ahead("exiting", program, (jax.ShapeDtypeStruct((50,), float),))
        (ahead,) = _programs._ahead.values()
        while not ahead.running():
            time.sleep(0.01)
        time.sleep(0.3)  # traced by now: compiling
        sys.exit(3)
    """))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=300)
    assert done.returncode == 3, done.stderr
