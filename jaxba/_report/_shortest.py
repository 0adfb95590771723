"""Floats printed in bulk as their shortest round-trip decimals, by orjson (compiled).

Python prints such a float (`repr`, what the json module writes) in ~0.6 µs; orjson prints a
whole array in ~0.1 µs a value. Its texts are JSON numbers that read back to the very same
double, though not always in repr's spelling (`1e-7` where repr writes `1e-07`, `0.00002`
where repr writes `2e-05`).
"""

import numpy as np
import orjson

from ._numbers import EXACT_POWERS, decidable

_DECADE = 330
with np.errstate(over="ignore"):
    _DECADES = 10.0 ** np.arange(-_DECADE, _DECADE + 1)  # 10^k, k = -330 .. 330 (inf past 308)


def number_rows(values, missing: str = "null") -> list[str]:
    """The JSON numbers of each row of `values` (n, m) joined by commas, a str per row;
    `missing` where a value is not finite."""
    table = np.ascontiguousarray(values, dtype=float)
    n, m = table.shape
    if n == 0 or m == 0:
        return [""] * n
    text = orjson.dumps(table, option=orjson.OPT_SERIALIZE_NUMPY)[2:-2].decode()
    return (text if missing == "null" else text.replace("null", missing)).split("],[")


def number_texts(values) -> list[str]:
    """The JSON number of every value of `values` (any shape, C order) as a str; `null` where
    a value is not finite."""
    flat = np.ascontiguousarray(values, dtype=float).ravel()
    if flat.size == 0:
        return []
    return orjson.dumps(flat, option=orjson.OPT_SERIALIZE_NUMPY)[1:-1].decode().split(",")


def significant(values, digits: int = 10) -> np.ndarray:
    """`values` rounded to `digits` significant digits (1 to 15): each the double nearest a
    decimal of at most `digits` significant digits, so its shortest text has at most that
    many: as `%.{digits}g` rounds them (a value too near a tie to decide in float64 is rounded
    by Python). Zeros and non-finite values stay as they are."""
    x = np.asarray(values, dtype=float)
    magnitude = np.abs(x)
    usable = np.isfinite(x) & (magnitude > 0)
    safe = np.where(usable, magnitude, 1.0)
    # Decimals to keep (negative: tens to drop), corrected where log10 rounded across a decade.
    keep = digits - 1 - np.floor(np.log10(safe)).astype(np.int64)
    estimate = safe * _DECADES[np.clip(keep, -_DECADE, _DECADE) + _DECADE]  # ~digits digits
    keep -= estimate >= 10.0**digits
    keep += estimate < 10.0 ** (digits - 1)
    exact = usable & (np.abs(keep) <= 22)
    factor = EXACT_POWERS[np.where(exact, np.abs(keep), 0)]
    up = keep >= 0
    scaled = np.where(exact, np.where(up, safe * factor, safe / factor), 0.0)  # one rounding
    exact &= decidable(scaled)  # not within a rounding error of a tie
    whole = np.rint(scaled)
    rounded = np.where(exact, np.copysign(np.where(up, whole / factor, whole * factor), x), x)
    left = np.flatnonzero(usable & ~exact)  # near a tie, below ~1e-13 or above ~1e22: Python
    if left.size:
        rounded.flat[left] = [float(f"{v:.{digits}g}") for v in x.flat[left].tolist()]
    return rounded
