"""The per-observation tables written in one pass (NAME.res: `number_table`, its text cells;
observations.csv: `_csv._lines`) against the plain way to write them, one row at a time with
Python's `%`.

The values are awkward on purpose: signed zeros, NaN and infinities, huge and tiny magnitudes,
exact rounding ties; the IDs long, non-ASCII (their width counted in characters, as
`str.ljust` does, not in bytes) and, in the CSV, holding commas and quotes.
"""

import csv
import io
import math

import numpy as np
import pytest
from helpers import significant_digits

from jaxba._report._cells import texts
from jaxba._report._csv import FLAG_COLUMNS, NUMBER_COLUMNS, _lines, _piece
from jaxba._report._text_tables import number_table

IDS = ["P1", "p" * 70, "Pünkt-7", "点12", "ñ", "📷cam", 'a,b', 'say "x"', "x" * 3]


def _awkward(n: int, columns: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(n, columns)) * 10.0 ** rng.integers(-12, 12, (n, columns))
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e300, -1e-300, 5e-324, 0.5, 2.5,
                        -0.0005, 123456789.5, 1e16, 9.99999999995, 1e-5, 0.0001, 1e10])
    spots = rng.integers(0, values.size, 3 * special.size)
    values.ravel()[spots] = np.tile(special, 3)
    return values


def _reference_res(header, labels, numbers, decimals, kind, prefix="# "):
    """Row by row: each label left aligned, each number right aligned (`-` when not
    finite), columns as wide as their widest entry (a column of a kind with a finite number
    keeps room for "nan"), two spaces apart."""
    texts = [[strings[k] for k in codes.tolist()] for strings, codes in labels]
    cells = [[f"{x:.{decimals[t][j]}f}" if math.isfinite(x) else "-"
              for j, x in enumerate(row)] for row, t in zip(numbers.tolist(), kind.tolist())]
    widths = [max(len(name), *map(len, column)) for name, column in zip(header, texts)]
    for j, name in enumerate(header[len(labels):]):
        width = len(name)
        for t in range(len(decimals)):
            mine = [row[j] for row, k in zip(cells, kind.tolist()) if k == t]
            finite = [c for c in mine if c != "-"]
            missing = [3 if finite else 1] * (len(finite) < len(mine))
            width = max([width, *map(len, finite)] + missing)
        widths.append(width)
    lines = [prefix + "  ".join(
        [h.ljust(w) for h, w in zip(header[:len(labels)], widths)]
        + [h.rjust(w) for h, w in zip(header[len(labels):], widths[len(labels):])]).rstrip()]
    for i, row in enumerate(cells):
        left = [column[i].ljust(w) for column, w in zip(texts, widths)]
        right = [c.rjust(w) for c, w in zip(row, widths[len(labels):])]
        lines.append("  " + "".join(f"{c}  " for c in left) + "  ".join(right))
    return "\n".join(lines) + "\n"


def test_residual_table_is_the_row_by_row_table():
    n = 400
    rng = np.random.default_rng(5)
    numbers = _awkward(n, 5, seed=1)
    numbers[:, 2] = np.where(rng.random(n) < 0.5, np.nan, numbers[:, 2])  # r unavailable
    labels = [(IDS, rng.integers(0, len(IDS), n)), (IDS[::-1], rng.integers(0, len(IDS), n))]
    kind = rng.integers(0, 2, n)
    decimals = [[6, 6, 3, 2, 0], [4, 4, 3, 2, 0]]
    header = ["image_id", "point_id", "x", "vx", "rx", "wx", "outlier"]
    expected = _reference_res(header, labels, numbers, decimals, kind)
    assert number_table(header, labels, numbers, decimals, kind) == expected


def test_residual_table_of_ascii_ids_and_of_no_rows():
    """ASCII IDs make rows of one width in bytes (laid out without a take); no rows leave
    the header alone."""
    rng = np.random.default_rng(2)
    numbers = _awkward(50, 2, seed=3)
    labels = [(["a", "bb", "ccc"], rng.integers(0, 3, 50))]
    kind = np.zeros(50, dtype=int)
    expected = _reference_res(["id", "x", "y"], labels, numbers, [[3, 0]], kind)
    assert number_table(["id", "x", "y"], labels, numbers, [[3, 0]], kind) == expected
    empty = number_table(["id", "x"], [(["a"], np.zeros(0, dtype=int))], np.zeros((0, 1)),
                         [[3]], np.zeros(0, dtype=int))
    assert empty == "# id  x\n"


@pytest.mark.parametrize("finite", [False, True])  # rows of many kinds, or of a few
def test_observation_lines_are_the_row_by_row_csv(finite):
    """Each row's text (IDs with commas, quotes and `%`), then its numbers and flags: each
    number the value of its `%.10g` in at most 10 significant digits."""
    n = 300
    rng = np.random.default_rng(9)
    filled = NUMBER_COLUMNS[:8] + FLAG_COLUMNS
    numbers = _awkward(n, len(filled), seed=4)
    numbers[:, -2:] = rng.integers(0, 2, (n, 2))
    numbers[::7, -1] = np.nan  # a flag not available: empty
    if finite:
        numbers = np.where(np.isfinite(numbers), numbers, -0.0)
    ids = [*IDS, "5%d", "100%", "%%s"]
    codes = [rng.integers(0, len(ids), n) for _ in range(7)]
    texts = [[_piece(ids[k]) for k in column.tolist()] for column in codes]
    lines = _lines(texts, numbers, filled)
    assert lines.endswith("\n") and lines.count("\n") == n
    for i, (row, values) in enumerate(zip(csv.reader(io.StringIO(lines)), numbers.tolist())):
        assert row[:7] == [ids[column[i]] for column in codes]
        for name, text in zip(NUMBER_COLUMNS + FLAG_COLUMNS, row[7:], strict=True):
            x = values[filled.index(name)] if name in filled else math.nan
            if not math.isfinite(x):
                assert text == ""
            elif name in FLAG_COLUMNS:
                assert text == str(int(x))
            else:
                assert float(text) == float(f"{x:.10g}"), (text, x)
                assert significant_digits(text) <= 10


def test_observation_lines_of_scalar_rows_leave_the_image_columns_empty():
    """v, r, w filled: the eight image-point columns before them empty, one row per kind of
    flags."""
    filled = ("v", "r", "w", *FLAG_COLUMNS)
    numbers = np.array([[0.25, 0.5, -1.5, 0.0, 1.0], [np.nan, 0.5, 2.0, 1.0, np.nan]])
    assert _lines([["a,", "b,"]], numbers, filled) == (
        "a," + "," * 8 + "0.25,0.5,-1.5,0,1\n" + "b," + "," * 8 + ",0.5,2.0,1,\n")
    with pytest.raises(ValueError, match="not consecutive"):
        _lines([["a,"]], np.zeros((1, 2)), ("x", "vx"))


def test_observation_lines_of_no_rows_and_of_flags_not_0_or_1():
    filled = ("v", "r", "w", *FLAG_COLUMNS)
    assert _lines([], np.zeros((0, 5)), filled) == ""
    with pytest.raises(ValueError, match="neither 0 nor 1"):
        _lines([["a,"]], np.array([[1.0, 0.5, 0.2, 0.0, 2.0]]), filled)


@pytest.mark.parametrize("strings", [["a", "bb", "a-much-longer-id", ""], IDS])
@pytest.mark.parametrize("width", [0, 2, 20])
def test_text_cells_are_the_strings_left_justified(strings, width):
    """ASCII strings (encoded all at once) and any others, some longer than `width`, some
    used by no row: each cell is its string as `str.ljust(width)` makes it, in UTF-8."""
    codes = np.random.default_rng(1).integers(0, 2, 50)  # the first two strings only
    cells = texts(strings, codes, width=width)
    assert cells.chars.shape[0] == 50
    expected = [strings[k].ljust(width).encode() for k in codes.tolist()]
    kept = np.broadcast_to(cells.keep, cells.chars.shape)
    assert [row[keep].tobytes() for row, keep in zip(cells.chars, kept)] == expected
