"""Output paths checked before anything is computed: a writable folder, no input overwritten
(no jax here)."""

import os
import pathlib
import tempfile
from collections.abc import Iterable


class OutputError(ValueError):
    """A report file cannot be written where asked (it would replace an input file, ...)."""


def check_folder(out_dir) -> None:
    """Raise `OutputError` unless `out_dir` is a writable folder or can be made one.

    Writable is tried, not inferred from permission bits: a temporary file is made (and
    removed at once) in `out_dir` or, where it does not exist yet, in its nearest existing
    parent folder.
    """
    out_dir = pathlib.Path(out_dir)
    existing = out_dir
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{out_dir}: output folder: {existing} is not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        reason = error.strerror or str(error)
        raise OutputError(f"{out_dir}: output folder: cannot write into {existing}: {reason}")


def resolved(paths: Iterable[os.PathLike]) -> frozenset[str]:
    """`paths` resolved (`os.path.realpath`), as a set of strings: the `inputs` of
    `check_targets` and `check_outputs` when many outputs are checked against the same
    inputs (each resolved once, not per check)."""
    folders: dict[str, str] = {}
    return frozenset(resolve(os.fspath(path), folders) for path in paths)


def resolve(path: str, folders: dict[str, str]) -> str:
    """`os.path.realpath(path)`, each folder on the way resolved once for all the paths that
    share `folders` (folder -> resolved): a name that is not a symbolic link resolves to its
    resolved folder joined with it, one `lstat` instead of one per component (a batch's
    thousands of reports in a few folders)."""
    head, name = os.path.split(path)
    if name in ("", ".", ".."):
        return os.path.realpath(path)
    folder = folders.get(head)
    if folder is None:
        folder = folders[head] = resolve(head, folders) if head else os.path.realpath(".")
    joined = os.path.join(folder, name)
    return os.path.realpath(joined) if os.path.islink(joined) else joined


def check_targets(paths: Iterable[pathlib.Path], inputs: Iterable[os.PathLike], owner: str,
                  folders: dict[str, str] | None = None) -> None:
    """Raise `OutputError` naming the first of `paths` that is one of `inputs` (compared
    resolved; a frozenset is taken as already `resolved`) or a folder; `owner` (e.g.
    "project 'lab'") says whose inputs they are. `folders`: resolved folders kept across
    calls (`resolve`), for many checks of paths in the same folders."""
    inputs = inputs if isinstance(inputs, frozenset) else resolved(inputs)
    folders = {} if folders is None else folders
    for path in paths:
        if resolve(os.fspath(path), folders) in inputs:
            raise OutputError(
                f"{path}: report file would overwrite an input file of {owner}; choose"
                " another output folder (--out) or rename the input"
            )
        if path.is_dir():
            raise OutputError(f"{path}: report file name is taken by a folder")
