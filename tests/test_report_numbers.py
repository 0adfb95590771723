"""`jaxba._report._numbers.fixed_cells` against Python's own `%` on the same floats.

Seeded values over many magnitudes, exact halves (ties at every decimal count), values a
hair either side of a tie, signed zeros, non-finite values and values too large for the
integer path: every finite cell must be byte for byte what `"%{width}.{d}f" % x` prints (the
same as `f"{x:{width}.{d}f}"`), every other the missing text.
"""

import numpy as np
import pytest

from jaxba._report._numbers import fixed_cells


def _values() -> np.ndarray:
    rng = np.random.default_rng(7)
    spread = rng.normal(size=4000) * 10.0 ** rng.integers(-10, 12, 4000)
    halves = rng.integers(-10**6, 10**6, 2000) / 1000 + 0.0005  # near a tie at 3 decimals
    eighths = rng.integers(-4000, 4000, 1000) / 8.0  # exact ties at 0..2 decimals
    near = np.nextafter(halves, np.inf)
    special = [0.0, -0.0, 0.5, 1.5, 2.5, -0.5, -0.0004, 9.9999999995, 0.125, 1e-9,
               2.0**49, -(2.0**50), 1e15, 123456789.123456789]
    return np.concatenate([spread, halves, eighths, near, special])


@pytest.mark.parametrize("places", [0, 1, 2, 3, 4, 6, 9, 12])
def test_fixed_cells_print_as_percent_f(places):
    values = _values()
    values = values[np.abs(values) * 10.0**places < 1e17]
    values = np.concatenate([values, [np.nan, np.inf, -np.inf]])
    width = 40
    cells = fixed_cells(values, places, width, missing=b"nan")
    printed = [row.tobytes().decode("ascii") for row in cells]
    expected = [(f"{x:.{places}f}" if np.isfinite(x) else "nan").rjust(width)
                for x in values.tolist()]
    assert printed == expected


def test_fixed_cells_decimals_per_value_and_missing_text():
    values = _values()[:3000].reshape(1000, 3)
    values[::7, 1] = np.nan
    places = np.random.default_rng(3).integers(0, 8, values.shape)
    cells = fixed_cells(values, places, 30).reshape(1000, 3, 30)
    for k, (row, decimals) in enumerate(zip(values.tolist(), places.tolist())):
        for j, (x, d) in enumerate(zip(row, decimals)):
            expected = f"{x:.{d}f}" if np.isfinite(x) else "-"
            assert cells[k, j].tobytes().decode("ascii") == expected.rjust(30)


@pytest.mark.parametrize("copies", [1, 500])  # printed one by one, and all at once
def test_fixed_cells_refuse_a_number_wider_than_its_column(copies):
    with pytest.raises(ValueError, match="wider than its column"):
        fixed_cells(np.full(copies, -123.25), 2, 6)
    assert fixed_cells(np.full(copies, -123.25), 2, 7).tobytes() == b"-123.25" * copies


def test_fixed_cells_of_a_few_values_as_of_many():
    """A few values are printed one by one (below the arrays' fixed costs): the same cells,
    the missing text and the padding included."""
    values = _values()[:3000]
    values[::11] = np.nan
    places = np.random.default_rng(5).integers(0, 9, values.size)
    many = fixed_cells(values, places, 30, missing=b"n/a", pad=b"*")
    few = [fixed_cells(values[k:k + 7], places[k:k + 7], 30, missing=b"n/a", pad=b"*")
           for k in range(0, values.size, 7)]
    assert np.array_equal(np.concatenate(few), many)


def test_fixed_cells_of_missing_values_need_only_the_missing_text_s_width():
    """A column of σ that are all unavailable (NaN) is as wide as "nan", whatever decimals
    its numbers would have had."""
    cells = fixed_cells(np.array([np.nan, np.inf, np.nan]), 8, 3, missing=b"nan")
    assert [row.tobytes() for row in cells] == [b"nan"] * 3
