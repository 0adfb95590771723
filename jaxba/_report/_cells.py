"""Text tables written in bulk: every column of n rows is n cells of bytes, the rows are the
cells side by side, taken out in one pass.

A column is `Cells`: `chars` (n, w) uint8 (UTF-8) and `keep` (n, w) bool, the bytes of each
cell that are printed (a cell is its kept bytes, in order); the table is one boolean take of
all columns side by side (`joined`; none where every byte is kept, rows of one width: ASCII
IDs), so no row is ever a Python object.
"""

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

_CHUNK = 1 << 13  # rows taken out together: their temporaries stay in the cache


class Cells(NamedTuple):
    """n cells: `chars` (n, w) uint8, `keep` (n, w) bool (or (1, w): the same for every row)."""

    chars: np.ndarray
    keep: np.ndarray


def whole(chars: np.ndarray) -> Cells:
    """Cells printed whole: `chars` (n, w) uint8, every byte kept."""
    return Cells(chars, np.ones((1, chars.shape[1]), dtype=bool))


def constant(text: str, n: int) -> Cells:
    """`text` in every one of n rows (a separator, a line end, an empty column)."""
    encoded = np.frombuffer(text.encode(), dtype=np.uint8)
    return whole(np.broadcast_to(encoded, (n, encoded.size)))


def texts(strings: Sequence[str], codes: np.ndarray, *, width: int = 0) -> Cells:
    """The cells `strings[codes[i]]` (codes (n,) int), each left justified to `width`
    characters as `str.ljust` does, in UTF-8; the strings are encoded once (all together when
    they are ASCII, the usual IDs)."""
    if "".join(strings).isascii():  # a character is a byte: pad as str, encode once
        most = max(width, max(map(len, strings), default=0))
        table = "".join(text.ljust(most) for text in strings).encode()
        lengths = np.maximum(np.fromiter(map(len, strings), dtype=np.int64, count=len(strings)),
                             width)
    else:
        encoded = [text.ljust(width).encode() for text in strings]
        most = max(map(len, encoded), default=0)
        table = b"".join(e.ljust(most, b" ") for e in encoded)
        lengths = np.fromiter(map(len, encoded), dtype=np.int64, count=len(encoded))
    table = np.frombuffer(table, dtype=np.uint8).reshape(len(strings), most)
    codes = np.asarray(codes, dtype=np.int64)
    if np.all(lengths == most):  # every cell as wide (ASCII IDs justified alike)
        return whole(table[codes])
    return Cells(table[codes], np.arange(most) < lengths[codes][:, None])


def joined(columns: Sequence[Cells]) -> str:
    """The rows of `columns` (each of n cells), one after the other, as text: row i is cell i
    of every column in order."""
    n = len(columns[0].chars)
    if all(len(c.keep) == 1 and c.keep.all() for c in columns):  # fixed width rows
        return np.concatenate([c.chars for c in columns], axis=1).tobytes().decode("utf-8")
    parts = []
    for start in range(0, n, _CHUNK):
        rows = slice(start, start + _CHUNK)
        chars = np.concatenate([c.chars[rows] for c in columns], axis=1)
        keep = np.concatenate([np.broadcast_to(c.keep if len(c.keep) == 1 else c.keep[rows],
                                               c.chars[rows].shape) for c in columns], axis=1)
        parts.append(chars.ravel()[np.flatnonzero(keep)].tobytes())  # faster than chars[keep]
    return b"".join(parts).decode("utf-8")
