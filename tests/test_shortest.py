"""Floats printed in bulk (`jaxba._report._shortest`) against Python printing them one by one:
`%.Ng` for the rounding, `float` reading every text back."""

import math

import numpy as np
import pytest
from helpers import significant_digits

from jaxba._report._shortest import number_rows, number_texts, significant

SPECIAL = [0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 2.2250738585072014e-308,
           1.7976931348623157e308, 1e-300, 1e300, 0.1, 1 / 3, 0.5, 2.5, 1e-5, 1e-4, 1e16,
           1e22, 1.2345678901234e23, 9.99999999995, 9999999999.5, 0.99999999996, 123456789.5,
           2.1513342955, -2.1513342955]


def _awkward(seed: int) -> np.ndarray:
    """Magnitudes from subnormal to 1e300, decimal rounding ties of several lengths, and
    `SPECIAL`."""
    rng = np.random.default_rng(seed)
    wide = rng.normal(size=20_000) * 10.0 ** rng.uniform(-300, 300, 20_000)
    usual = rng.normal(size=20_000) * 10.0 ** rng.integers(-8, 12, 20_000)
    ties = np.concatenate([  # k + 0.5 in the last place kept: ties as decimals, not as doubles
        (rng.integers(10**(d - 1), 10**d, 2_000) + 0.5) * 10.0 ** rng.integers(-d - 3, 3, 2_000)
        for d in (1, 6, 10, 15)])
    return np.concatenate([wide, usual, ties, -ties, SPECIAL])


@pytest.mark.parametrize("digits", [1, 6, 10, 15])
def test_significant_rounds_as_percent_g(digits):
    """Every value rounds to the double `%.{digits}g` reads back as, and prints in at most
    `digits` significant digits; zeros keep their sign, NaN and infinities stay."""
    values = _awkward(digits)
    rounded = significant(values, digits)
    for x, mine in zip(values.tolist(), rounded.tolist()):
        expected = float(f"{x:.{digits}g}")
        assert mine == expected or (math.isnan(mine) and math.isnan(expected)), (x, mine)
        assert math.copysign(1, mine) == math.copysign(1, x)
    texts = number_texts(rounded)
    assert max(significant_digits(t) for t in texts if t != "null") <= digits


def test_significant_keeps_the_shape():
    values = np.arange(12.0).reshape(3, 4) / 7
    assert significant(values, 3).shape == (3, 4)
    assert significant(np.zeros(0)).shape == (0,)


def test_number_texts_read_back_to_every_value():
    """Each text is a JSON number that `float` reads back to the very same double; `null`
    for NaN and infinities, in C order."""
    values = _awkward(3)
    values = values[values.size % 7:].reshape(-1, 7)  # `SPECIAL` last: kept
    texts = number_texts(values)
    assert len(texts) == values.size
    for x, text in zip(values.ravel().tolist(), texts):
        assert text == "null" if not math.isfinite(x) else float(text) == x and "n" not in text
    assert number_texts(np.zeros((0, 3))) == []


def test_number_rows_join_each_row_and_name_the_missing():
    values = np.array([[1.0, np.nan, -2.5], [3e-7, np.inf, 0.0]])
    assert number_rows(values) == ["1.0,null,-2.5", f"{number_texts(3e-7)[0]},null,0.0"]
    assert number_rows(values, missing="") == ["1.0,,-2.5", f"{number_texts(3e-7)[0]},,0.0"]
    assert number_rows(np.zeros((0, 2))) == []
    assert number_rows(np.zeros((2, 0))) == ["", ""]
