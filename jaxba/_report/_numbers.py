"""Floats printed in bulk, byte for byte as printf-style `%.Nf` and `%.Ng` print them.

Each value becomes one cell of ASCII codes, a row of an (n, width) uint8 array (right aligned
for `%f`; for `%g`, with the bytes that are printed marked, `Cells`); the table writers put
these side by side and decode the rows once. Digits come from round(|x| · 10^k), an integer
held exactly in a double, four at a time from a table; the cells are built a character (a row
of the transposed cells) at a time over all values. A value whose scaled magnitude lies too
near a rounding tie to decide in float64 (or beyond its exact integers) is printed by Python
instead, so every cell is what `%` gives.
"""

import numpy as np

from ._cells import Cells

_POWERS = 10 ** np.arange(19, dtype=np.int64)  # exact integers 10^0 .. 10^18
_FLOAT_POWERS = 10.0 ** np.arange(23)  # exact doubles 10^0 .. 10^22
_QUADS = np.array([b"%04d" % k for k in range(10_000)]).view(np.uint32)  # "0000" .. "9999"
_SPAN = 330  # powers of ten 10^-330 .. 10^330 (0 and inf beyond the doubles), for exponents
_TEN_TO = np.array([float(f"1e{k}") for k in range(-_SPAN, _SPAN + 1)])
_UP = np.array([10.0**k if k > 0 else 1.0 for k in range(-22, 23)])  # scale by 10^k: * UP / DOWN
_DOWN = np.array([10.0**-k if k < 0 else 1.0 for k in range(-22, 23)])
_QUAD_ZEROS = np.array([4] + [len(str(k)) - len(str(k).rstrip("0")) for k in range(1, 10_000)])
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
        printed = [b"%.*f" % (places, value) if np.isfinite(value) else missing
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
    scaled = np.where(finite, np.abs(x), 0.0) * _FLOAT_POWERS[places]
    decided = finite & _decidable(scaled)
    m = np.rint(np.where(decided, scaled, 0.0))  # an integer below 2^50
    whole = np.floor(m / _FLOAT_POWERS[places])  # exact: m / 10^places is 2^-50 from the next
    negative = np.signbit(x)
    digits = np.maximum(np.searchsorted(_FLOAT_POWERS, whole, side="right"), 1)
    whole_width = width - places - (places > 0)  # characters before the point
    if np.any(digits + negative > whole_width):
        raise ValueError(f"a number is wider than its column ({width} characters)")
    cells = np.empty((width, x.size), dtype=np.uint8)
    if places:
        cells[whole_width] = ord(".")
        fraction = m - whole * _FLOAT_POWERS[places]
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


def general_cells(values, digits: int) -> Cells:
    """`"%.{digits}g" % x` of every value (n,) as `Cells` (1 <= digits <= 15), left aligned;
    a non-finite value is an empty cell. The cells are built a character at a time over all
    values (transposed, (width, n): every step is on contiguous rows), in the order of their
    form (their rows taken together), then put back in order."""
    x = np.asarray(values, dtype=float).ravel()
    width = digits + 7  # "-" and the longest form: "0.0000" and the digits, or d.ddde-123
    nonzero = np.isfinite(x) & (x != 0)
    magnitude = np.abs(np.where(nonzero, x, 1.0))  # 0 and non-finite values printed apart
    # The exponent of the first significant digit (from the binary one, then checked), then
    # that digit at 10^(digits - 1): the value scaled by a power of ten in one rounding.
    exponent = ((magnitude.view(np.int64) >> 52) - 1023) * 78913 >> 18  # ⌊log10 2^binary⌋
    exponent += magnitude >= _TEN_TO[np.clip(exponent + 1, -_SPAN, _SPAN) + _SPAN]
    step = digits - 1 - exponent + 22  # 10^(step - 22) an exact double for 0 <= step <= 44
    fits = (step >= 0) & (step <= 44)
    step = np.clip(step, 0, 44)
    scaled = magnitude * _UP[step] / _DOWN[step]
    decided = fits & _decidable(np.where(fits, scaled, 0.0))
    scaled = np.rint(np.where(decided, scaled, _POWERS[digits - 1]))
    carry = scaled >= _POWERS[digits]  # rounded up to the next power of ten
    scaled[carry] = _POWERS[digits - 1]
    exponent += carry
    # The values of each layout together, in this order: fixed with each exponent from -4 to
    # digits - 1, scientific (digits), printed by Python or no digits (digits + 1).
    layout = np.where((exponent >= -4) & (exponent < digits), exponent, digits)
    layout[~(decided & nonzero)] = digits + 1
    order = np.argsort(layout.astype(np.int8), kind="stable")
    layout, exponent, scaled = layout[order], exponent[order], scaled[order]
    quads = _float_quads(scaled, digits)
    shown = _column_chars(quads, digits)  # (digits, n)
    significant = digits - _trailing_zeros(quads)
    bounds = np.searchsorted(layout, np.arange(-4, digits + 2)).tolist()
    # The characters in layout order; a row of each form's own width (cut by `keep`).
    chars = np.full((width, x.size), ord("0"), dtype=np.uint8)
    keep = np.zeros((width, x.size), dtype=bool)
    chars[0], keep[0] = ord("-"), np.signbit(x[order]) & np.isfinite(x[order])
    body, printed = chars[1:], keep[1:]
    places = np.arange(width - 1)[:, None]
    for e, start, stop in zip(range(-4, digits + 1), bounds[:-1], bounds[1:]):
        if start == stop:
            continue
        rows, kept = body[:, start:stop], significant[start:stop]
        if e >= digits:  # d.ddde+XX: the exponent's sign and at least two digits
            power = exponent[start:stop]
            rows[0], rows[1] = shown[0, start:stop], ord(".")
            rows[2:digits + 1], rows[digits + 1] = shown[1:, start:stop], ord("e")
            rows[digits + 2] = np.where(power < 0, ord("-"), ord("+"))
            rows[digits + 3:] = _column_chars(_float_quads(np.abs(power).astype(float), 3), 3)
            mantissa = np.where(kept > 1, kept + 1, 1)
            printed[:, start:stop] = (places < mantissa) | (places > digits)
            printed[digits + 3, start:stop] = np.abs(power) >= 100
            continue
        if e >= 0:  # d..d.ddd: the point after e + 1 digits, printed if a digit follows
            rows[:e + 1], rows[e + 1] = shown[:e + 1, start:stop], ord(".")
            rows[e + 2:digits + 1] = shown[e + 1:, start:stop]
            length = e + 1 + np.where(kept > e + 1, kept - e, 0)
        else:  # 0.000ddd
            rows[1] = ord(".")
            rows[1 - e:1 - e + digits] = shown[:, start:stop]
            length = 1 - e + kept
        printed[:, start:stop] = places < length
    # Back in the order of the values: rows of a transposed copy, each row moved whole.
    inverse = np.empty_like(order)
    inverse[order] = np.arange(order.size)
    chars, keep = (_rows(np.ascontiguousarray(a.T), inverse) for a in (chars, keep))
    keep[:, 1] |= x == 0  # "0" or "-0"
    for k in np.flatnonzero(nonzero & ~decided).tolist():  # near a tie, beyond exact powers
        text = np.frombuffer(b"%.*g" % (digits, abs(x[k])), dtype=np.uint8)
        chars[k, 1:1 + text.size] = text
        keep[k, 1:] = np.arange(width - 1) < text.size
    return Cells(chars, keep)


def _put_rows(table: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """`table[rows] = values` of a C-ordered (n, w) table, each row put as one item."""
    void = f"V{table.shape[1] * table.itemsize}"
    table.view(void).ravel()[rows] = np.ascontiguousarray(values).view(void).ravel()


def _rows(table: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """`table[rows]` of a C-ordered (n, w) table, each row taken as one item (many times
    faster than row by row for narrow tables)."""
    items = table.view(f"V{table.shape[1] * table.itemsize}").ravel()
    return items[rows].view(table.dtype).reshape(len(rows), table.shape[1])


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


def _decidable(scaled: np.ndarray) -> np.ndarray:
    """Where rounding `scaled` (a float64 product of one rounding) to an integer gives what
    rounding the exact product gives: far enough from a tie, within the exact integers."""
    distance = np.abs(scaled - np.floor(scaled) - 0.5)
    return (scaled < _EXACT) & (distance > 4 * np.spacing(scaled))


def _trailing_zeros(quads: list[np.ndarray]) -> np.ndarray:
    """How many decimal digits end the integers of `_quads` in 0 (16 for 0)."""
    zeros, done = np.zeros(len(quads[0]), dtype=np.int64), np.zeros(len(quads[0]), dtype=bool)
    for k, quad in enumerate(quads):
        zeros = np.where(done, zeros, 4 * k + _QUAD_ZEROS[quad])
        done |= quad != 0
    return zeros


def _put(cells: np.ndarray, where: np.ndarray, text, pad: bytes) -> None:
    """Overwrite the cells `where` (n,) with `text(k)` (bytes) right aligned, `pad` before."""
    width = cells.shape[1]
    for k in np.flatnonzero(where).tolist():
        printed = text(k)
        if len(printed) > width:
            raise ValueError(f"{printed!r} is wider than its column ({width} characters)")
        cells[k] = np.frombuffer(printed.rjust(width, pad), dtype=np.uint8)
