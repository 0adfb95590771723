"""Compiled programs stored as jax exports beside jax's persistent compilation cache, so that
a later process calls them without tracing them again (`call_stored`).

A warm process reads every executable from jax's persistent cache, but jax first traces and
lowers each program to find its cache key, in every process: for the batch's solve and
statistics of ten Zhang-size calibrations that was 3.3 CPU seconds before the first result.
Called through its stored export (`jax.export`), the same program took 0.5-0.75 s, with
bit-identical results (benchmarks/program_loads.py --batch).

The first process traces the program once, exports it as a function of the flat array leaves
of its arguments, writes the export and calls it; the export then has a compilation-cache
entry of its own. A later process with the same key reads the file, checks it and calls it.

The key is a BLAKE2b digest of everything the trace depends on: the program's name, module
and qualified name, jaxba's version and a digest of its source, the versions of Python, jax,
jaxlib, equinox, optimistix, lineax and numpy, the platform, jax's options that change a
trace (`_OPTIONS`: `jax_enable_x64`, ...), the structure of the arguments (pytree node types
and their static data, the non-array leaves), every array leaf's shape, dtype and weak type,
the static arguments, and the classes of the registries that traces look up by name
(`register_lookup`: the camera models). Classes and functions are named by module and
qualified name, only those of jaxba and the libraries (`_KNOWN`). Arguments or registries
that hold anything else (a user's class, a lambda, an arbitrary object) get no key: the
program is traced as usual.

The output's structure cannot come from the export (its pytree nodes are equinox Modules):
the first process pickles the output with an empty array in place of each array (its
"skeleton", checked to unpickle to the same structure) and a later process rebuilds the
output from it and the export's flat results.

File: `<jax cache folder>/jaxba-programs/<name>-<key>.export`, a 32-byte BLAKE2b digest of the
rest, the skeleton's pickle (8 bytes of length first), then `Exported.serialize()`'s bytes;
written to a temporary file and renamed (atomic). The files are jaxba's own, like jax's
compiled executables beside them: whoever may write them may change what a process runs.

Safe by design: without jax's compilation cache folder (`jax_compilation_cache_dir` unset,
the cache or jit disabled) or the flatbuffers package (jax's serialization needs it) nothing
is exported and the program is traced as usual; a file that fails its digest, cannot be read
or deserialized, or does not fit the arguments is ignored and replaced; a program jax cannot
export (a host callback), or a failing call of a loaded export, falls back to the traced
program. Global configuration is only read, never set.

Compiled ahead: `compile_ahead` (a stored program's `ahead`) makes a program ready on a
worker thread for arguments of given shapes while the caller does other work (XLA's
compilation releases the GIL; the machines have two cores or more); the later call with
arrays of those shapes waits for it instead of compiling (`jaxba._timing.compiled_ahead`
counts it there, with the seconds waited).
"""

import atexit
import concurrent.futures
import contextlib
import enum
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import pathlib
import pickle
import queue
import sys
import tempfile
import threading
import types
from collections.abc import Callable, Iterable

import equinox as eqx
import jax
import numpy as np

from ._timing import CompileLog, compiled_ahead

FOLDER = "jaxba-programs"  # inside jax's cache folder; jax's own entries end in "-cache"
_DIGEST = 32  # bytes of BLAKE2b at the head of a stored file
_LENGTH = 8  # bytes of the skeleton pickle's length after it
_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy")
# Modules whose code a key may name by qualified name: jaxba's (its source is in the key), the
# libraries' (their versions are), Python's own. A class or function of any other module (a
# user's camera model) may change between processes under the same name: no key.
_KNOWN = frozenset(("jaxba", *_LIBRARIES, "builtins", "abc", "collections", "typing"))
# jax's options that change a trace (the others change compilation, which jax keys itself).
_OPTIONS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_rank_promotion",
            "jax_numpy_dtype_promotion")
_loaded: dict[str, tuple] = {}  # key: `_prepare`'s (call, output tree, rest, avals), this process
_traced: set[str] = set()  # keys of programs that could not be exported, in this process
_ahead: dict[str, concurrent.futures.Future] = {}  # key: `compile_ahead`'s job, not yet called
_lookups: list[Callable[[], Iterable]] = []  # `register_lookup`'s registries


class _NoKey(Exception):
    """The arguments hold something without a faithful textual form."""


def register_lookup(entries: Callable[[], Iterable]) -> None:
    """Name a registry that traces look classes up in by name (camera models by their
    `model` string): `entries()` lists the classes it holds now. Every key holds them all,
    and nothing is stored while one of them is neither jaxba's nor a library's (a user's
    camera model)."""
    _lookups.append(entries)


def forget_loaded() -> None:
    """Drop the programs this process has loaded or prepared (their executables freed once
    nothing else holds them), as `jax.clear_caches` drops jax's: the next call of each
    loads it again, from its stored export, as a fresh process would (and counts it)."""
    _loaded.clear()
    _traced.clear()
    _ahead.clear()


def stored(name: str) -> Callable[[Callable], Callable]:
    """Decorator: the jitted `program` called through `call_stored` under `name`; the call's
    `ahead(*args)` is `compile_ahead(name, program, args)`, its `output_shapes(*args)`
    `output_shapes(name, program, args)`, its `nothing_to_compile(*args)` that of
    `nothing_to_compile`."""

    def decorate(program: Callable) -> Callable:
        @functools.wraps(program)
        def call(*args):
            return call_stored(name, program, args)

        call.ahead = lambda *args: compile_ahead(name, program, args)
        call.output_shapes = lambda *args: output_shapes(name, program, args)
        call.nothing_to_compile = lambda *args: nothing_to_compile(name, program, args)
        return call

    return decorate


def call_stored(name: str, program: Callable, args: tuple, static: tuple = ()):
    """`program(*args, *static)`, called through its stored export where one can be used.

    - `name`: the program's name in file names (letters, digits, "_");
    - `program`: a jitted function (`eqx.filter_jit`, `solver_jit`) of jaxba's (only jaxba's
      source is in the key) of pytrees of arrays `args` and static arguments `static`. A
      program compiled with options of its own (`solver_jit`) gives its function jitted
      without them as `nested` (the export traces that) and its options as
      `compiler_options()` (the stored program's call is compiled with them).

    The output's structure (its pytree nodes and non-array leaves) is stored beside the
    export, pickled with empty arrays in place of its arrays: a later process rebuilds the
    output without tracing. A program `compile_ahead` is compiling for these arguments'
    shapes is waited for, not compiled again. Returns what `program(*args, *static)`
    returns.
    """
    arrays, rest = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree.flatten(arrays)
    if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        # Under a caller's transformation (jit, vmap, grad): a nested call, as traced (an
        # export has no derivative, and its primal outputs would be tracers too).
        return program(*args, *static)
    folder = _folder()
    key = None if folder is None else _key(name, program, tree, leaves, rest, static)
    if key is None or key in _traced:
        return program(*args, *static)
    path = folder / f"{name}-{key}.export"
    ahead = _ahead.pop(key, None)  # first called: counted here, however far it got
    loaded = _loaded.get(key) if ahead is None else compiled_ahead(ahead)
    if loaded is None and key not in _traced:  # (its compilation ahead failed: again here)
        loaded = _prepare(name, program, key, path, tree, leaves, rest, static)
    if loaded is None:  # not exportable
        return program(*args, *static)
    call, out_tree, out_rest, _ = loaded
    try:
        flat = call(*leaves)
    except Exception:  # a stale or broken export: trace as usual, drop the file
        _loaded.pop(key, None)
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        return program(*args, *static)
    return eqx.combine(jax.tree.unflatten(out_tree, flat), out_rest)


def compile_ahead(name: str, program: Callable, args: tuple, static: tuple = ()) -> None:
    """Start making `call_stored(name, program, args, static)`'s program ready (its export
    read or traced and stored, then compiled, or read from jax's persistent cache) on a
    worker thread, while the caller goes on: XLA's compilation releases the GIL, so a second
    core compiles while the first traces, compiles or runs other programs. `args` as
    `call_stored`'s, any array leaf a `jax.ShapeDtypeStruct` (weak type included) of the
    array the later call passes. One worker, jobs in order. Nothing where `call_stored`
    would not store the program, where it is ready or on its way already, or where an
    earlier process stored it (a warm cache: nothing to compile). The worker traces
    under jax's global configuration: where the caller's key holds a thread-local option
    (`jax.enable_x64` as a context), the worker's differs, nothing is stored and the call
    traces as usual."""
    if nothing_to_compile(name, program, args, static):
        return
    arrays, rest = eqx.partition(args, _is_array_or_shape)
    leaves, tree = jax.tree.flatten(arrays)
    key = _key(name, program, tree, leaves, rest, static)
    path = _folder() / f"{name}-{key}.export"

    def job():
        with CompileLog() as log:
            return _prepare(name, program, key, path, tree, leaves, rest, static,
                            compile=True), log

    future = _ahead[key] = concurrent.futures.Future()
    _jobs().put((future, job))


def nothing_to_compile(name: str, program: Callable, args: tuple, static: tuple = ()) -> bool:
    """Whether `compile_ahead(name, program, args, static)` has nothing to do: the program
    is not stored (no key, not exportable), is ready or on its way in this process, or an
    earlier process stored it. Stored, its executable is in jax's cache: loading it is
    mostly Python (the GIL), and on a worker it slowed the caller's own work (the
    close-range block, warm: datum check 1.4-1.6 -> 3.2-3.4 s) for no gain."""
    arrays, rest = eqx.partition(args, _is_array_or_shape)
    leaves, tree = jax.tree.flatten(arrays)
    folder = _folder()
    key = None if folder is None else _key(name, program, tree, leaves, rest, static)
    return (key is None or key in _traced or key in _loaded or key in _ahead
            or (folder / f"{name}-{key}.export").exists())


def output_shapes(name: str, program: Callable, args: tuple, static: tuple = ()):
    """What `call_stored(name, program, args, static)` returns, a `jax.ShapeDtypeStruct`
    for each array (`returned_shapes`), where that program is ready in this process (called
    before, or compiled ahead): read from its export, nothing traced. Else None."""
    arrays, rest = eqx.partition(args, _is_array_or_shape)
    leaves, tree = jax.tree.flatten(arrays)
    key = None if _folder() is None else _key(name, program, tree, leaves, rest, static)
    loaded = None if key is None else _loaded.get(key)
    if loaded is None:
        return None
    _, out_tree, out_rest, out_avals = loaded
    shapes = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in out_avals]
    return eqx.combine(jax.tree.unflatten(out_tree, shapes), out_rest)


def returned_shapes(tree):
    """`tree` (arrays, `jax.ShapeDtypeStruct`s: `jax.eval_shape`'s) with a
    `jax.ShapeDtypeStruct` for each array as a stored program returns it: not weakly typed
    (an export's results never are; `eval_shape` of the traced program says a Python
    scalar's are)."""
    return jax.tree.map(
        lambda leaf: jax.ShapeDtypeStruct(np.shape(leaf), leaf.dtype)
        if _is_array_or_shape(leaf) else leaf, tree)


def _is_array_or_shape(leaf) -> bool:
    return eqx.is_array(leaf) or isinstance(leaf, jax.ShapeDtypeStruct)


@functools.cache
def _jobs() -> queue.SimpleQueue:
    """`compile_ahead`'s queue of (future, job), served by one daemon thread. At exit the
    jobs not started are cancelled and the one running is waited for (`_drain`): a thread
    still tracing or compiling while the interpreter finalizes crashed the process."""
    jobs, busy = queue.SimpleQueue(), threading.Lock()

    def serve():
        while True:
            future, job = jobs.get()
            with busy:
                if future.set_running_or_notify_cancel():
                    try:
                        future.set_result(job())
                    except Exception:  # e.g. XLA out of memory: the caller compiles as usual
                        future.set_result((None, CompileLog()))

    threading.Thread(target=serve, name="jaxba-compile-ahead", daemon=True).start()
    atexit.register(_drain, jobs, busy)
    return jobs


def _drain(jobs: queue.SimpleQueue, busy: threading.Lock) -> None:
    """Cancel the jobs not started, wait for the one running; no job runs after."""
    with contextlib.suppress(queue.Empty):
        while True:
            jobs.get_nowait()[0].cancel()
    busy.acquire()


def _prepare(name, program, key, path, tree, leaves, rest, static, compile=False):
    """(the stored program's call, its output's tree, the output's non-array leaves, the
    export's output avals), kept for `key` in this process: the export read from `path`,
    else traced and stored there; with `compile`, compiled for `leaves`' shapes. None where
    it cannot be exported (noted: no second try in this process)."""
    stored = _load(path, leaves)
    if stored is None:
        made = _export(getattr(program, "nested", program), tree, rest, static, leaves)
        if made is None or _key(name, program, tree, leaves, rest, static) != key:
            # not exportable, its output not picklable, or the trace looked up a class
            # by a name never resolved before (a registry changed): no file
            _traced.add(key)
            return None
        *stored, body = made
        _store(path, body)
    exported, skeleton = stored
    options = getattr(program, "compiler_options", None)
    out_arrays, out_rest = eqx.partition(skeleton, eqx.is_array)
    # One sharding for every input: an export's outputs are committed to their device,
    # NumPy inputs are not, and jit compiled the call again for each mix of the two.
    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    call = jax.jit(_named(exported.call, name), in_shardings=device,
                   compiler_options=None if options is None else options())
    if compile:
        call = call.lower(*(_shape(leaf) for leaf in leaves)).compile()
    loaded = _loaded[key] = (call, jax.tree.structure(out_arrays), out_rest,
                             exported.out_avals)
    return loaded


def _named(call: Callable, name: str) -> Callable:
    """`call` under `name`: jax's compile logs and events name the program by it."""

    def program(*leaves):
        return call(*leaves)

    program.__name__ = program.__qualname__ = name
    return program


def _folder() -> pathlib.Path | None:
    """Where exports are stored: a folder inside jax's persistent compilation cache, or None
    where there is none, jit is disabled or exports cannot be serialized (jax needs the
    flatbuffers package for that)."""
    if (jax.config.jax_disable_jit or not jax.config.jax_enable_compilation_cache
            or not _serializable()):
        return None
    cache = _cache_folder()
    return None if cache is None else cache / FOLDER


def _cache_folder() -> pathlib.Path | None:
    """jax's persistent compilation cache folder; None where it is unset or not a local
    folder (a remote store)."""
    cache = jax.config.jax_compilation_cache_dir
    if not cache or "://" in str(cache):
        return None
    return pathlib.Path(cache).expanduser()


@functools.cache
def _serializable() -> bool:
    return importlib.util.find_spec("flatbuffers") is not None


@functools.cache
def _environment() -> bytes:
    """jaxba's version and source digest, the traced libraries' and Python's versions, once
    per process (BLAKE2b of every .py file of the package: a few milliseconds)."""
    digest = hashlib.blake2b()
    root = pathlib.Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    for library in ("jaxba", *_LIBRARIES):
        try:
            version = importlib.metadata.version(library)
        except importlib.metadata.PackageNotFoundError:
            version = "?"
        digest.update(f"{library} {version};".encode())
    digest.update(sys.version.encode())
    return digest.digest()


def _key(name: str, program: Callable, tree, leaves: list, rest, static: tuple) -> str | None:
    """The hex digest naming the export of `name` for these arguments; None where they or a
    registry hold something without a faithful textual form."""
    try:
        return _digest(name, program, tree, leaves, rest, static)
    except _NoKey:
        return None


def _digest(name: str, program: Callable, tree, leaves: list, rest, static: tuple) -> str:
    code = getattr(program, "__wrapped__", program)
    parts = [name, getattr(code, "__module__", None), getattr(code, "__qualname__", None),
             jax.default_backend(), *(_canonical(getattr(jax.config, option)) for option in
                                       _OPTIONS), _describe(tree),
             _canonical(jax.tree.leaves(rest)), _canonical(static),
             [_canonical(entry) for entries in _lookups for entry in entries()]]
    parts += [(np.shape(leaf), np.dtype(leaf.dtype).str, bool(getattr(leaf, "weak_type", False)))
              for leaf in leaves]
    digest = hashlib.blake2b(_environment(), digest_size=20)
    digest.update(repr(parts).encode())
    return digest.hexdigest()


def _describe(tree) -> tuple:
    """A pytree structure as nested tuples of node types and their static data."""
    data = tree.node_data()
    if data is None:
        return ("*",)
    kind, aux = data
    return (_canonical(kind), _canonical(aux), *(_describe(child) for child in tree.children()))


def _canonical(value):
    """`value` in a form whose repr is faithful and the same in every process; raises
    _NoKey for anything else (functions, arbitrary objects)."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes)):
        return value
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, *(_canonical(v) for v in value))
    if isinstance(value, dict):
        return ("dict", *((_canonical(k), _canonical(v)) for k, v in value.items()))
    if isinstance(value, type):  # itself and every class it inherits code from
        return tuple(_qualified(base) for base in value.__mro__)
    if isinstance(value, types.FunctionType) and "<" not in value.__qualname__:
        return _qualified(value)  # a module-level function (no lambda, no closure)
    if isinstance(value, enum.Enum):
        return f"{_canonical(type(value))}.{value.name}"
    if isinstance(value, (np.ndarray, np.generic)):
        value = np.asarray(value)
        return ("array", value.dtype.str, value.shape,
                hashlib.blake2b(np.ascontiguousarray(value).tobytes()).hexdigest())
    kind = type(value)
    if kind.__name__ == "_Missing" and kind.__module__.startswith("equinox."):
        return "equinox.MISSING"  # equinox's marker in a Module's static data
    raise _NoKey(kind)


def _qualified(code) -> str:
    """`module.qualname` of a class or function of a `_KNOWN` module; raises _NoKey."""
    if code.__module__.partition(".")[0] not in _KNOWN:
        raise _NoKey(code)
    return f"{code.__module__}.{code.__qualname__}"


def _load(path: pathlib.Path, leaves: list):
    """(export, output skeleton) stored at `path`, or None where there is none or it is
    unusable (a digest, unpickling, deserialization or signature mismatch)."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    head, body = blob[:_DIGEST], blob[_DIGEST:]
    if hashlib.blake2b(body, digest_size=_DIGEST).digest() != head:
        return None
    size = int.from_bytes(body[:_LENGTH], "little")
    try:
        skeleton = pickle.loads(body[_LENGTH:_LENGTH + size])
        exported = jax.export.deserialize(bytearray(body[_LENGTH + size:]))
    except Exception:  # any failure to read it: trace and store anew
        return None
    signature = [(tuple(np.shape(leaf)), np.dtype(leaf.dtype)) for leaf in leaves]
    n_out = jax.tree.structure(eqx.filter(skeleton, eqx.is_array)).num_leaves
    if ([(tuple(a.shape), np.dtype(a.dtype)) for a in exported.in_avals] != signature
            or len(exported.out_avals) != n_out):
        return None
    return exported, skeleton


def _export(program, tree, rest, static, leaves):
    """(`program` exported as a function of the flat array leaves of its arguments, its
    output's skeleton: the output with an empty array for each array, the file's body:
    the skeleton's pickle, its length first, and the serialized export); None where jax
    cannot export or serialize it or the skeleton does not survive pickling unchanged.
    The export and the skeleton are the ones read back from the body, as a later process
    reads them: the export's call lowers to the same module, so both find the same
    compiled executable in jax's cache (the freshly traced export's did not: every program
    compiled twice)."""
    traced = {}

    def flat(*leaves):
        out = program(*eqx.combine(jax.tree.unflatten(tree, leaves), rest), *static)
        out_arrays, traced["rest"] = eqx.partition(out, eqx.is_array)
        out_leaves, traced["tree"] = jax.tree.flatten(out_arrays)
        return out_leaves

    specs = [_shape(leaf) for leaf in leaves]
    try:
        serialized = bytes(jax.export.export(jax.jit(flat))(*specs).serialize())
        exported = jax.export.deserialize(bytearray(serialized))
        empty = [np.empty(0, aval.dtype) for aval in exported.out_avals]
        pickled = pickle.dumps(eqx.combine(jax.tree.unflatten(traced["tree"], empty),
                                           traced["rest"]))
        skeleton = pickle.loads(pickled)
    except Exception:  # not exportable or not picklable: the caller traces as usual
        return None
    arrays, rest = eqx.partition(skeleton, eqx.is_array)
    if jax.tree.structure(arrays) != traced["tree"] or not eqx.tree_equal(rest, traced["rest"]):
        return None
    return exported, skeleton, len(pickled).to_bytes(_LENGTH, "little") + pickled + serialized


def _shape(leaf) -> jax.ShapeDtypeStruct:
    return jax.ShapeDtypeStruct(np.shape(leaf), leaf.dtype,
                                weak_type=bool(getattr(leaf, "weak_type", False)))


def _store(path: pathlib.Path, body: bytes) -> None:
    """Write `path`: a digest of `body`, then `body` (`_export`'s); atomically. Nothing
    where the folder cannot be written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    except OSError:  # a read-only folder: skip
        return
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(hashlib.blake2b(body, digest_size=_DIGEST).digest() + body)
        os.replace(temporary, path)
    except OSError:  # a full disk: no file, no partial one
        pathlib.Path(temporary).unlink(missing_ok=True)
