"""Floats printed in bulk, byte for byte as printf-style `%.Nf` prints them.

Each value becomes one right-aligned cell of ASCII codes, a row of an (n, width) uint8 array;
the table writers put these side by side and decode the rows once. Digits come from integer
arithmetic on round(|x| · 10^k), four at a time from a table; a value whose scaled magnitude
lies too near a rounding tie to decide in float64 (or beyond its exact integers) is printed
by Python instead, so every cell is what `%` gives.
"""

import numpy as np

_POWERS = 10 ** np.arange(19, dtype=np.int64)  # exact integers 10^0 .. 10^18
_FLOAT_POWERS = 10.0 ** np.arange(23)  # exact doubles 10^0 .. 10^22
_QUADS = np.array([b"%04d" % k for k in range(10_000)]).view(np.uint32)  # "0000" .. "9999"
_EXACT = 2.0**50  # scaled magnitudes below: ulp at most 1/4, so round() decidable
_MOST_DIGITS = 16  # of an integer below _EXACT
_CHUNK = 1 << 14  # values printed together: their temporaries stay in the cache


def fixed_cells(values, decimals, width: int, *, missing: bytes = b"-",
                pad: bytes = b" ") -> np.ndarray:
    """`"%{width}.{d}f" % x` of every value (n of them, any shape, in C order) as an
    (n, width) uint8 array, `decimals` shaped like `values` or one int; non-finite values
    print as `missing`, right aligned; `pad` fills on the left. A value printed wider than
    `width` is an error (the caller sizes the columns)."""
    x = np.asarray(values, dtype=float).ravel()
    d = np.broadcast_to(np.asarray(decimals, dtype=np.int64), np.shape(values)).ravel()
    cells = np.empty((x.size, width), dtype=np.uint8)
    finite = np.isfinite(x)  # only these are sized by their digits (a column of NaN: "nan")
    lowest = int(d.min(initial=0))
    present = np.flatnonzero(np.bincount(d[finite] - lowest)) + lowest if finite.any() else []
    for places in np.asarray(present).tolist():  # the rows of each count of decimals, chunked
        rows = np.flatnonzero(finite & (d == places) if len(present) > 1 else finite)
        for start in range(0, rows.size, _CHUNK):
            chunk = rows[start:start + _CHUNK]
            cells[chunk] = _fixed(x[chunk], places, width, pad[0])
    _put(cells, ~finite, lambda k: missing, pad)
    return cells


def _fixed(x: np.ndarray, places: int, width: int, pad: int) -> np.ndarray:
    """`fixed_cells` of `x` (n,) with `places` decimals, non-finite values left to the caller."""
    finite = np.isfinite(x)
    scaled = np.where(finite, np.abs(x), 0.0) * _FLOAT_POWERS[places]
    decided = finite & _decidable(scaled)
    m = np.where(decided, np.rint(scaled), 0.0).astype(np.int64)
    digits = _digits(m)
    whole = width - places - (places > 0)  # characters before the point
    # The digits of m, the point `places` from the right, blanks left of the 16 digits.
    cells = np.full((x.size, width), pad, dtype=np.uint8)
    shown = min(whole, _MOST_DIGITS - places)
    cells[:, whole - shown:whole] = digits[:, _MOST_DIGITS - places - shown:_MOST_DIGITS - places]
    if places:
        cells[:, whole] = ord(".")
        cells[:, whole + 1:] = digits[:, _MOST_DIGITS - places:]
    # Leading zeros of the whole part are blank (one digit stays), a "-" before the first.
    start = whole - np.maximum(np.searchsorted(_POWERS, m // _POWERS[places], side="right"), 1)
    negative = np.signbit(x)
    if np.any(start - negative < 0):
        raise ValueError(f"a number is wider than its column ({width} characters)")
    np.putmask(cells[:, :whole], np.arange(whole) < start[:, None], pad)
    rows = np.flatnonzero(negative)
    cells[rows, start[rows] - 1] = ord("-")
    _put(cells, finite & ~decided, lambda k: b"%.*f" % (places, float(x[k])), bytes([pad]))
    return cells


def _decidable(scaled: np.ndarray) -> np.ndarray:
    """Where rounding `scaled` (a float64 product of one rounding) to an integer gives what
    rounding the exact product gives: far enough from a tie, within the exact integers."""
    distance = np.abs(scaled - np.floor(scaled) - 0.5)
    return (scaled < _EXACT) & (distance > 4 * np.spacing(scaled))


def _digits(m: np.ndarray) -> np.ndarray:
    """The 16 decimal digits of the integers `m` (n,), 0 <= m < 10^16, as ASCII, (n, 16)."""
    quads, rest = [], m
    for _ in range(_MOST_DIGITS // 4):
        rest, last = np.divmod(rest, 10_000)
        quads.append(_QUADS[last])
    return np.stack(quads[::-1], axis=1).view(np.uint8)


def _put(cells: np.ndarray, where: np.ndarray, text, pad: bytes) -> None:
    """Overwrite the cells `where` (n,) with `text(k)` (bytes) right aligned, `pad` before."""
    width = cells.shape[1]
    for k in np.flatnonzero(where).tolist():
        printed = text(k)
        if len(printed) > width:
            raise ValueError(f"{printed!r} is wider than its column ({width} characters)")
        cells[k] = np.frombuffer(printed.rjust(width, pad), dtype=np.uint8)
