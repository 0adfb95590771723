"""Floats printed in bulk, byte for byte as printf-style `%.Nf` and `%.10g` print them.

Each value becomes one right-aligned cell of ASCII codes, a column of a (width, n) uint8
array; the table writers stack these (line k of the text is column k) and decode once.
Digits come from integer arithmetic on round(|x| · 10^k); a value whose scaled magnitude lies
too near a rounding tie to decide in float64 (or beyond its exact integers), and any `%.10g`
that prints in exponent notation, is printed by Python instead, so every cell is what `%`
gives.
"""

import numpy as np

_POWERS = 10 ** np.arange(19, dtype=np.int64)  # exact integers 10^0 .. 10^18
_FLOAT_POWERS = 10.0 ** np.arange(23)  # exact doubles 10^0 .. 10^22
_EXACT = 2.0**50  # scaled magnitudes below: ulp at most 1/4, so round() decidable
_SIGNIFICANT = 10  # digits of `%.10g`
_PLACES = _SIGNIFICANT + 3  # its most decimals: 0.0001234567891
GENERAL_WIDTH = 1 + _SIGNIFICANT + 1 + _PLACES  # cells of `general_cells`, NUL padded


def fixed_cells(values, decimals, width: int, *, missing: bytes = b"-",
                pad: bytes = b" ") -> np.ndarray:
    """`"%{width}.{d}f" % x` of every value as a (width, n) uint8 array, `decimals` (n,) or
    one int; non-finite values print as `missing`, right aligned; `pad` fills on the left.
    A value printed wider than `width` is an error (the caller sizes the columns)."""
    x = np.asarray(values, dtype=float).ravel()
    d = np.broadcast_to(np.asarray(decimals, dtype=np.int64), x.shape)
    if np.ndim(decimals) == 0:
        cells = _fixed(x, int(decimals), width, pad[0])
    else:
        cells = np.empty((width, x.size), dtype=np.uint8)
        for places in np.unique(d).tolist():
            rows = d == places
            cells[:, rows] = _fixed(x[rows], places, width, pad[0])
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
        parts += [np.full((1, x.size), ord("."), dtype=np.uint8), _digits(fraction, places)]
    cells = np.concatenate(parts)
    _put(cells, finite & ~decided, lambda k: b"%.*f" % (places, float(x[k])), bytes([pad]))
    return cells


def general_cells(values) -> np.ndarray:
    """`"%.10g" % x` of every value, right aligned in a (GENERAL_WIDTH, n) uint8 array with
    NUL (0) wherever nothing is printed (remove the NULs after decoding); non-finite values:
    all NUL (an empty field)."""
    x = np.asarray(values, dtype=float).ravel()
    finite = np.isfinite(x)
    magnitude = np.where(finite, np.abs(x), 0.0)
    positive = magnitude > 0
    exponent = np.floor(np.log10(magnitude, where=positive, out=np.zeros_like(x)))
    exponent = np.clip(exponent, -5, 10).astype(np.int64)
    # log10 may miss by one near a power of ten: the rounded mantissa must have 10 digits.
    first = magnitude * _FLOAT_POWERS[np.clip(_SIGNIFICANT - 1 - exponent, 0, 22)]
    m = np.rint(first)
    exponent += (m >= 1e10).astype(np.int64) - ((m < 1e9) & positive)
    places = np.where(positive, _SIGNIFICANT - 1 - exponent, 0)
    scaled = magnitude * _FLOAT_POWERS[np.clip(places, 0, 22)]
    m = np.rint(scaled)
    plain = ~positive | ((places >= 0) & (places <= _PLACES) & (m >= 1e9) & (m < 1e10))
    decided = finite & plain & _decidable(scaled) & _decidable(first)
    m = np.where(decided, m, 0.0).astype(np.int64)
    places = np.where(decided, places, 0)
    whole, fraction = np.divmod(m, _POWERS[places])
    digits = _digits(fraction * _POWERS[_PLACES - places], _PLACES)
    # Trailing zeros of the decimals are not printed, nor a point without decimals.
    trailing = np.logical_and.accumulate(digits[::-1] == ord("0"), axis=0)[::-1]
    digits = np.where(trailing, np.uint8(0), digits)
    point = np.where(trailing[:1], np.uint8(0), np.uint8(ord(".")))
    cells = np.concatenate(
        [_integer_cells(whole, np.signbit(x), _SIGNIFICANT + 1, 0), point, digits])
    _put(cells, ~finite, lambda k: b"", b"\0")
    _put(cells, finite & ~decided, lambda k: b"%.10g" % float(x[k]), b"\0")
    return cells


def _decidable(scaled: np.ndarray) -> np.ndarray:
    """Where rounding `scaled` (a float64 product of one rounding) to an integer gives what
    rounding the exact product gives: far enough from a tie, within the exact integers."""
    distance = np.abs(scaled - np.floor(scaled) - 0.5)
    return (scaled < _EXACT) & (distance > 4 * np.spacing(scaled))


def _digits(m: np.ndarray, count: int) -> np.ndarray:
    """The last `count` decimal digits of the integers `m` (n,) >= 0 as ASCII, (count, n)."""
    digits = np.empty((count, m.size), dtype=np.uint8)
    rest = m.copy()
    for k in range(count - 1, -1, -1):
        quotient = rest // 10
        digits[k] = rest - 10 * quotient
        rest = quotient
    digits += ord("0")
    return digits


def _integer_cells(m: np.ndarray, negative: np.ndarray, width: int, pad: int) -> np.ndarray:
    """The integers `m` (n,) >= 0 right aligned in `width` characters, "-" before where
    `negative`, `pad` before that."""
    start = width - np.maximum(np.searchsorted(_POWERS, m, side="right"), 1)
    if np.any(start - negative < 0):
        raise ValueError(f"a number is wider than its column ({width} characters)")
    position = np.arange(width)[:, None]
    sign = np.where(negative, ord("-"), pad).astype(np.uint8)
    cells = np.where(position < start, np.uint8(pad), _digits(m, width))
    return np.where(position == start - 1, sign, cells)


def _put(cells: np.ndarray, where: np.ndarray, text, pad: bytes) -> None:
    """Overwrite the cells `where` (n,) with `text(k)` (bytes) right aligned, `pad` before."""
    width = cells.shape[0]
    for k in np.flatnonzero(where).tolist():
        printed = text(k)
        if len(printed) > width:
            raise ValueError(f"{printed!r} is wider than its column ({width} characters)")
        cells[:, k] = np.frombuffer(printed.rjust(width, pad), dtype=np.uint8)
