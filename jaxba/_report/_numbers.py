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


def fixed_cells(values, decimals, width: int, *, missing: bytes = b"-",
                pad: bytes = b" ") -> np.ndarray:
    """`"%{width}.{d}f" % x` of every value (n of them, any shape, in C order) as an
    (n, width) uint8 array, `decimals` shaped like `values` or one int; non-finite values
    print as `missing`, right aligned; `pad` fills on the left. A value printed wider than
    `width` is an error (the caller sizes the columns)."""
    x = np.asarray(values, dtype=float).ravel()
    if np.ndim(decimals) == 0:
        cells = _fixed(x, int(decimals), width, pad[0])
    else:
        d = np.asarray(decimals, dtype=np.int64).ravel()
        cells = np.empty((x.size, width), dtype=np.uint8)
        for places in np.unique(d).tolist():
            rows = d == places
            cells[rows] = _fixed(x[rows], places, width, pad[0])
    _put(cells, ~np.isfinite(x), lambda k: missing, pad)
    return cells


def _fixed(x: np.ndarray, places: int, width: int, pad: int) -> np.ndarray:
    """`fixed_cells` of `x` (n,) with `places` decimals, non-finite values left to the caller."""
    finite = np.isfinite(x)
    scaled = np.where(finite, np.abs(x), 0.0) * _FLOAT_POWERS[places]
    decided = finite & _decidable(scaled)
    m = np.where(decided, np.rint(scaled), 0.0).astype(np.int64)
    whole, fraction = np.divmod(m, _POWERS[places])
    parts = [_integer_cells(whole, np.signbit(x), width - places - (places > 0), pad)]
    if places:
        parts += [np.full((x.size, 1), ord("."), dtype=np.uint8), _digits(fraction, places)]
    cells = np.concatenate(parts, axis=1)
    _put(cells, finite & ~decided, lambda k: b"%.*f" % (places, float(x[k])), bytes([pad]))
    return cells


def _decidable(scaled: np.ndarray) -> np.ndarray:
    """Where rounding `scaled` (a float64 product of one rounding) to an integer gives what
    rounding the exact product gives: far enough from a tie, within the exact integers."""
    distance = np.abs(scaled - np.floor(scaled) - 0.5)
    return (scaled < _EXACT) & (distance > 4 * np.spacing(scaled))


def _digits(m: np.ndarray, count: int) -> np.ndarray:
    """The last `count` (at most 16) decimal digits of the integers `m` (n,) >= 0 as ASCII,
    (n, count)."""
    quads, rest = [], m
    for _ in range(-(-count // 4)):
        rest, last = np.divmod(rest, 10_000)
        quads.append(_QUADS[last])
    digits = np.stack(quads[::-1], axis=1).view(np.uint8)
    return digits[:, digits.shape[1] - count:]


def _integer_cells(m: np.ndarray, negative: np.ndarray, width: int, pad: int) -> np.ndarray:
    """The integers `m` (n,) >= 0 (below 10^16) right aligned in `width` characters, "-"
    before where `negative`, `pad` before that."""
    start = width - np.maximum(np.searchsorted(_POWERS, m, side="right"), 1)
    if np.any(start - negative < 0):
        raise ValueError(f"a number is wider than its column ({width} characters)")
    count = min(width, _MOST_DIGITS)
    digits = _digits(m, count)
    if width > count:
        digits = np.concatenate([np.full((m.size, width - count), pad, np.uint8), digits], 1)
    position = np.arange(width)
    sign = np.where(negative, ord("-"), pad).astype(np.uint8)[:, None]
    cells = np.where(position < start[:, None], np.uint8(pad), digits)
    return np.where(position == start[:, None] - 1, sign, cells)


def _put(cells: np.ndarray, where: np.ndarray, text, pad: bytes) -> None:
    """Overwrite the cells `where` (n,) with `text(k)` (bytes) right aligned, `pad` before."""
    width = cells.shape[1]
    for k in np.flatnonzero(where).tolist():
        printed = text(k)
        if len(printed) > width:
            raise ValueError(f"{printed!r} is wider than its column ({width} characters)")
        cells[k] = np.frombuffer(printed.rjust(width, pad), dtype=np.uint8)
