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
and the static arguments. Classes and functions are named by module and qualified name, only
those of jaxba and the libraries (`_KNOWN`). Arguments whose structure holds anything else (a
user's class, a lambda, an arbitrary object) get no key: the program is traced as usual.

File: `<jax cache folder>/jaxba-programs/<name>-<key>.export`, a 32-byte BLAKE2b digest of the
rest, then `Exported.serialize()`'s bytes; written to a temporary file and renamed (atomic).

Safe by design: without jax's compilation cache folder (`jax_compilation_cache_dir` unset,
the cache or jit disabled) or the flatbuffers package (jax's serialization needs it) nothing
is exported and the program is traced as usual; a file that fails its digest, cannot be read
or deserialized, or does not fit the arguments is ignored and replaced; a program jax cannot
export (a host callback), or a failing call of a loaded export, falls back to the traced
program. Global configuration is only read, never set.
"""

import contextlib
import enum
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import pathlib
import sys
import tempfile
import types
from collections.abc import Callable

import equinox as eqx
import jax
import numpy as np

FOLDER = "jaxba-programs"  # inside jax's cache folder; jax's own entries end in "-cache"
_DIGEST = 32  # bytes of BLAKE2b at the head of a stored file
_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy")
# Modules whose code a key may name by qualified name: jaxba's (its source is in the key), the
# libraries' (their versions are), Python's own. A class or function of any other module (a
# user's camera model) may change between processes under the same name: no key.
_KNOWN = frozenset(("jaxba", *_LIBRARIES, "builtins", "abc", "collections", "typing"))
# jax's options that change a trace (the others change compilation, which jax keys itself).
_OPTIONS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_rank_promotion",
            "jax_numpy_dtype_promotion")
_loaded: dict[str, Callable] = {}  # key: the export's call, jitted, for this process
_traced: set[str] = set()  # keys of programs that could not be exported, in this process


class _NoKey(Exception):
    """The arguments hold something without a faithful textual form."""


def call_stored(name: str, program: Callable, args: tuple, static: tuple, outline: Callable,
                code: tuple = ()):
    """`program(*args, *static)`, called through its stored export where one can be used.

    - `name`: the program's name in file names (letters, digits, "_");
    - `program`: a jitted function (`eqx.filter_jit`) of jaxba's (only jaxba's source is in
      the key) of pytrees of arrays `args` and static arguments `static`;
    - `outline(*args)`: a pytree shaped like the program's output (its array leaves of any
      value, its other leaves and static data as the output's), built without tracing. The
      first process checks it against the traced output and stores nothing on a mismatch;
    - `code`: classes and functions the trace runs that the arguments only name (camera
      models named by strings): no key, and the program traced as usual, unless all are
      jaxba's or the libraries'.

    Returns what `program(*args, *static)` returns.
    """
    arrays, rest = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree.flatten(arrays)
    folder = _folder()
    try:
        key = None if folder is None else _key(name, program, tree, leaves, rest,
                                                (static, code))
    except _NoKey:
        key = None
    if key is None or key in _traced:
        return program(*args, *static)
    out_arrays, out_rest = eqx.partition(outline(*args), eqx.is_array)
    out_tree = jax.tree.structure(out_arrays)
    path = folder / f"{name}-{key}.export"
    call = _loaded.get(key)
    if call is None:
        exported = _load(path, leaves, out_tree.num_leaves)
        if exported is None:
            exported = _export(program, tree, rest, static, leaves, out_tree, out_rest)
            if exported is None:  # not exportable, or `outline` is wrong: store nothing
                _traced.add(key)  # and try no more in this process
                return program(*args, *static)
            _store(path, exported)
        call = _loaded[key] = jax.jit(exported.call)
    try:
        flat = call(*leaves)
    except Exception:  # a stale or broken export: trace as usual, drop the file
        _loaded.pop(key, None)
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        return program(*args, *static)
    return eqx.combine(jax.tree.unflatten(out_tree, flat), out_rest)


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


def _key(name: str, program: Callable, tree, leaves: list, rest, static: tuple) -> str:
    """The hex digest naming the export of `name` for these arguments; raises _NoKey."""
    code = getattr(program, "__wrapped__", program)
    parts = [name, getattr(code, "__module__", None), getattr(code, "__qualname__", None),
             jax.default_backend(), *(_canonical(getattr(jax.config, option)) for option in
                                       _OPTIONS), _describe(tree),
             _canonical(jax.tree.leaves(rest)), _canonical(static)]
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


def _load(path: pathlib.Path, leaves: list, n_out: int):
    """The stored export at `path`, or None where there is none or it is unusable (a
    digest, deserialization or signature mismatch)."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    head, body = blob[:_DIGEST], blob[_DIGEST:]
    if hashlib.blake2b(body, digest_size=_DIGEST).digest() != head:
        return None
    try:
        exported = jax.export.deserialize(bytearray(body))
    except Exception:  # any failure to read it: trace and store anew
        return None
    signature = [(tuple(np.shape(leaf)), np.dtype(leaf.dtype)) for leaf in leaves]
    if ([(tuple(a.shape), np.dtype(a.dtype)) for a in exported.in_avals] != signature
            or len(exported.out_avals) != n_out):
        return None
    return exported


def _export(program, tree, rest, static, leaves, out_tree, out_rest):
    """`program` exported as a function of the flat array leaves of its arguments; None
    where jax cannot export it or its output is not shaped like the outline (`out_tree`,
    `out_rest`)."""
    traced = {}

    def flat(*leaves):
        out = program(*eqx.combine(jax.tree.unflatten(tree, leaves), rest), *static)
        out_arrays, traced["rest"] = eqx.partition(out, eqx.is_array)
        out_leaves, traced["tree"] = jax.tree.flatten(out_arrays)
        return out_leaves

    specs = [jax.ShapeDtypeStruct(np.shape(leaf), leaf.dtype,
                                  weak_type=bool(getattr(leaf, "weak_type", False)))
             for leaf in leaves]
    try:
        exported = jax.export.export(jax.jit(flat))(*specs)
    except Exception:  # not exportable: the caller traces as usual
        return None
    if traced["tree"] != out_tree or not eqx.tree_equal(traced["rest"], out_rest):
        return None
    return exported


def _store(path: pathlib.Path, exported) -> None:
    """Write `exported` to `path` (digest, then the serialized export) atomically; nothing
    where it cannot be serialized or the folder cannot be written."""
    try:
        body = bytes(exported.serialize())
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    except Exception:  # not serializable, a read-only folder: skip
        return
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(hashlib.blake2b(body, digest_size=_DIGEST).digest() + body)
        os.replace(temporary, path)
    except OSError:  # a full disk: no file, no partial one
        pathlib.Path(temporary).unlink(missing_ok=True)
