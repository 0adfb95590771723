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


def resolved(paths: Iterable[os.PathLike]) -> frozenset[pathlib.Path]:
    """`paths` resolved, as a set: the `inputs` of `check_targets` and `check_outputs` when
    many outputs are checked against the same inputs (each resolved once, not per check)."""
    return frozenset(pathlib.Path(path).resolve() for path in paths)


def check_targets(paths: Iterable[pathlib.Path], inputs: Iterable[os.PathLike], owner: str) -> None:
    """Raise `OutputError` naming the first of `paths` that is one of `inputs` (compared
    resolved; a frozenset is taken as already `resolved`) or a folder; `owner` (e.g.
    "project 'lab'") says whose inputs they are."""
    inputs = inputs if isinstance(inputs, frozenset) else resolved(inputs)
    for path in paths:
        if path.resolve() in inputs:
            raise OutputError(
                f"{path}: report file would overwrite an input file of {owner}; choose"
                " another output folder (--out) or rename the input"
            )
        if path.is_dir():
            raise OutputError(f"{path}: report file name is taken by a folder")
