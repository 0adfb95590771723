"""Floats printed in bulk, byte for byte as printf-style `%.Nf` prints them.

Each value becomes one right-aligned cell of ASCII codes, a row of an (n, width) uint8 array;
the table writers put these side by side and decode the rows once. Digits come from
round(|x| · 10^k), an integer held exactly in a double, four at a time from a table; the cells
are built a character (a row of the transposed cells) at a time over all values. A value whose
scaled magnitude lies too near a rounding tie to decide in float64 (or beyond its exact
integers) is printed by Python instead, so every cell is what `%` gives.
"""

import math

import numpy as np

EXACT_POWERS = 10.0 ** np.arange(23)  # exact doubles 10^0 .. 10^22
_QUADS = np.array([b"%04d" % k for k in range(10_000)]).view(np.uint32)  # "0000" .. "9999"
_EXACT = 2.0**50  # scaled magnitudes below: ulp at most 1/4, so round() decidable
_CHUNK = 1 << 14  # values printed together: their temporaries stay in the cache
_FEW = 100  # values printed one by one by Python: faster than the arrays' fixed costs


def fixed_cells(values, decimals, width: int, *, missing: bytes = b"-",
                pad: bytes = b" ") -> np.ndarray:
    """`"%{width}.{d}f" % x` of every value (n of them, any shape, in C order) as an
    (n, width) uint8 array, `decimals` shaped like `values` or one int; non-finite values
    print as `missing`, right aligned; `pad` fills on the left. A value printed wider than
    `width` is an error (the caller sizes the columns)."""
    x = np.asarray(values, dtype=float).ravel()
    d = np.broadcast_to(np.asarray(decimals, dtype=np.int64), np.shape(values)).ravel()
    if x.size <= _FEW:
        printed = [b"%.*f" % (places, value) if math.isfinite(value) else missing
                   for value, places in zip(x.tolist(), d.tolist())]
        if max(map(len, printed), default=0) > width:
            raise ValueError(f"a number is wider than its column ({width} characters)")
        text = b"".join(cell.rjust(width, pad) for cell in printed)
        return np.frombuffer(text, dtype=np.uint8).reshape(x.size, width).copy()
    cells = np.empty((x.size, width), dtype=np.uint8)
    finite = np.isfinite(x)  # only these are sized by their digits (a column of NaN: "nan")
    lowest = int(d.min(initial=0))
    present = np.flatnonzero(np.bincount(d[finite] - lowest)) + lowest if finite.any() else []
    for places in np.asarray(present).tolist():  # the rows of each count of decimals, chunked
        rows = np.flatnonzero(finite & (d == places) if len(present) > 1 else finite)
        for start in range(0, rows.size, _CHUNK):
            chunk = rows[start:start + _CHUNK]
            _put_rows(cells, chunk, _fixed(x[chunk], places, width, pad[0]))
    _put(cells, ~finite, lambda k: missing, pad)
    return cells


def _fixed(x: np.ndarray, places: int, width: int, pad: int) -> np.ndarray:
    """`fixed_cells` of `x` (n,) with `places` decimals, non-finite values left to the caller.

    Built a character at a time over all values (a row of the transposed cells), then
    transposed: the integer part and the decimals apart, digits four at a time."""
    finite = np.isfinite(x)
    scaled = np.where(finite, np.abs(x), 0.0) * EXACT_POWERS[places]
    decided = finite & decidable(scaled)
    m = np.rint(np.where(decided, scaled, 0.0))  # an integer below 2^50
    whole = np.floor(m / EXACT_POWERS[places])  # exact: m / 10^places is 2^-50 from the next
    negative = np.signbit(x)
    digits = np.maximum(np.searchsorted(EXACT_POWERS, whole, side="right"), 1)
    whole_width = width - places - (places > 0)  # characters before the point
    if np.any(digits + negative > whole_width):
        raise ValueError(f"a number is wider than its column ({width} characters)")
    cells = np.empty((width, x.size), dtype=np.uint8)
    if places:
        cells[whole_width] = ord(".")
        fraction = m - whole * EXACT_POWERS[places]
        cells[whole_width + 1:] = _column_chars(_float_quads(fraction, places), places)
    # Digit k of the integer part (10^k) in row whole_width - 1 - k where k < digits, a "-"
    # where k == digits for a negative value, `pad` elsewhere.
    most = int(digits.max(initial=1))
    shown = _column_chars(_float_quads(whole, most), most)  # (most, n), 10^(most - 1) first
    sign = np.where(negative, ord("-"), pad).astype(np.uint8)
    cells[:max(whole_width - most - 1, 0)] = pad
    for k in range(min(most + 1, whole_width)):
        row = whole_width - 1 - k
        beyond = np.where(k == digits, sign, pad) if k else sign
        cells[row] = np.where(k < digits, shown[most - 1 - k], beyond) if k < most else beyond
    cells = np.ascontiguousarray(cells.T)
    _put(cells, finite & ~decided, lambda k: b"%.*f" % (places, float(x[k])), bytes([pad]))
    return cells


def _put_rows(table: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """`table[rows] = values` of a C-ordered (n, w) table, each row put as one item."""
    void = f"V{table.shape[1] * table.itemsize}"
    table.view(void).ravel()[rows] = np.ascontiguousarray(values).view(void).ravel()


def _float_quads(m: np.ndarray, digits: int) -> list[np.ndarray]:
    """The integers `m` (k,) float, 0 <= m < 10^digits, in base 10^4: (k,) int arrays, the last
    digits first (float arithmetic, exact below 2^53)."""
    quads, rest = [], m
    for _ in range(-(-digits // 4)):
        high = np.floor(rest / 1e4)
        quads.append((rest - high * 1e4).astype(np.intp))
        rest = high
    return quads


def _column_chars(quads: list[np.ndarray], digits: int) -> np.ndarray:
    """The last `digits` decimal digits of `_float_quads` as ASCII, transposed: (digits, k)."""
    codes = [_QUADS[quad] for quad in quads[::-1]]
    rows = [(code >> (8 * b)).astype(np.uint8) for code in codes for b in range(4)]
    return np.stack(rows[len(rows) - digits:])


def decidable(scaled: np.ndarray) -> np.ndarray:
    """Where rounding `scaled` (a float64 product of one rounding) to an integer gives what
    rounding the exact product gives: far enough from a tie, within the exact integers."""
    distance = np.abs(scaled - np.floor(scaled) - 0.5)
    return (scaled < _EXACT) & (distance > 4 * np.spacing(scaled))


def _put(cells: np.ndarray, where: np.ndarray, text, pad: bytes) -> None:
    """Overwrite the cells `where` (n,) with `text(k)` (bytes) right aligned, `pad` before."""
    width = cells.shape[1]
    for k in np.flatnonzero(where).tolist():
        printed = text(k)
        if len(printed) > width:
            raise ValueError(f"{printed!r} is wider than its column ({width} characters)")
        cells[k] = np.frombuffer(printed.rjust(width, pad), dtype=np.uint8)
