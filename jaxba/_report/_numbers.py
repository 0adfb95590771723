"""Floats printed in bulk, byte for byte as printf-style `%.Nf` and `%.Ng` print them.

Each value becomes one cell of ASCII codes, a row of an (n, width) uint8 array (`%.Nf` right
aligned; `%.Ng` as `Cells`, with the bytes it prints marked); the table writers put these
side by side and decode the rows once. Digits come from integer arithmetic on round(|x| ·
10^k), four at a time from a table; a value whose scaled magnitude lies too near a rounding
tie to decide in float64 (or beyond its exact integers, or whose 10^k is not an exact double)
is printed by Python instead, so every cell is what `%` gives.
"""

import numpy as np

from ._cells import Cells

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
    for start in range(0, x.size, _CHUNK):
        chunk = slice(start, start + _CHUNK)
        for places in np.unique(d[chunk][finite[chunk]]).tolist():
            rows = np.flatnonzero((d[chunk] == places) & finite[chunk]) + start
            cells[rows] = _fixed(x[rows], places, width, pad[0])
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


def general_cells(values, digits: int) -> Cells:
    """`"%.{digits}g" % x` of every value (n,) as `Cells`, `digits` 1 to 15 (more would be
    beyond the exact integers); a non-finite value is an empty cell.

    The cell of a value: its sign, "0.000" (the lead of 1e-4 <= |x| < 1), the `digits` digits
    of round(|x| · 10^(digits - 1 - e)) each followed by a decimal point, and the exponent
    "e+XXX"; the kept bytes make the value as `%g` writes it (trailing zeros of the fraction
    and a bare point dropped; positional for -4 <= e < digits, else exponential).
    """
    x = np.asarray(values, dtype=float).ravel()
    finite, zero = np.isfinite(x), x == 0
    a = np.where(finite & ~zero, np.abs(x), 1.0)  # the others are not printed from digits
    e = np.floor(np.log10(a)).astype(np.int64)
    m, decided = _significand(a, e, digits)
    # e too small (log10 rounded down, or the digits rounded up to 10^digits) or too large.
    low, high = decided & (m < 10 ** (digits - 1)), decided & (m >= 10**digits)
    e = e + high - low
    m, decided = _significand(a, e, digits)
    decided &= (m >= 10 ** (digits - 1)) & (m < 10**digits) & finite & ~zero
    m = np.where(decided, m, 0)
    e = np.where(decided, e, 0)
    shown = np.full(x.size, 1)  # significant digits printed: trailing zeros dropped
    ascii_digits = _digits(m)[:, _MOST_DIGITS - digits:]  # (n, digits)
    nonzero = ascii_digits != ord("0")
    shown[decided] = digits - np.argmax(nonzero[decided, ::-1], axis=1)
    positional = (e >= -4) & (e < digits)
    count = np.where(positional & (e >= 0), np.maximum(e + 1, shown), shown)
    point = np.where(positional, e, 0)  # the digit the point follows (none for e < 0)
    magnitude = np.abs(e)
    exponent = np.stack([
        np.full(x.size, ord("e")), np.where(e < 0, ord("-"), ord("+")),
        ord("0") + magnitude // 100, ord("0") + magnitude // 10 % 10, ord("0") + magnitude % 10,
    ], axis=1).astype(np.uint8)
    chars = np.concatenate([
        np.full((x.size, 1), ord("-"), dtype=np.uint8),
        np.broadcast_to(np.frombuffer(b"0.000", dtype=np.uint8), (x.size, 5)),
        np.stack([ascii_digits, np.full_like(ascii_digits, ord("."))], axis=2)
        .reshape(x.size, 2 * digits),
        exponent,
    ], axis=1)
    places, count, point = np.arange(digits), count[:, None], point[:, None]
    with_point = (places == point) & (point >= 0) & (count > places + 1)  # a fraction follows
    keep = np.concatenate([
        (np.signbit(x) & (decided | zero))[:, None],
        np.arange(5) < np.where(positional & (e < 0), 1 - e, 0)[:, None],
        np.stack([places < count, with_point], axis=2).reshape(x.size, 2 * digits),
        # "e", its sign and at least two digits
        ~positional[:, None] & ((np.arange(5) != 2) | (magnitude >= 100)[:, None]),
    ], axis=1)
    keep[~(decided | zero)] = False
    for k in np.flatnonzero(finite & ~zero & ~decided).tolist():
        printed = np.frombuffer(b"%.*g" % (digits, float(x[k])), dtype=np.uint8)
        chars[k, :printed.size], keep[k, :printed.size] = printed, True
    return Cells(chars, keep)


def _significand(a: np.ndarray, e: np.ndarray, digits: int) -> tuple[np.ndarray, np.ndarray]:
    """round(a · 10^(digits - 1 - e)) (n,) int64 and where it is decided (`_decidable`, the
    power an exact double: the product or quotient rounded once)."""
    k = digits - 1 - e
    exact = np.abs(k) < _FLOAT_POWERS.size
    power = _FLOAT_POWERS[np.where(exact, np.abs(k), 0)]
    scaled = np.where(exact, np.where(k >= 0, a * power, a / power), 0.0)
    decided = exact & _decidable(scaled)
    return np.where(decided, np.rint(scaled), 0.0).astype(np.int64), decided
