"""Aligned text tables of the BASC-style reports: columns at least two spaces apart, texts
left aligned, numbers right aligned with fixed decimals; `table` for a few rows of strings,
`column_table` and `number_table` for many rows, laid out at once (`fixed_cells`, `joined`).
"""

import math

import numpy as np

from ._cells import constant, joined, texts, whole
from ._numbers import fixed_cells


def table(header: list[str], rows: list[list[str]], align: str, *, prefix: str = "  ") -> list[str]:
    """Aligned lines: `align` has one "l" or "r" per column; the header gets `prefix` too."""
    widths = [max(len(row[k]) for row in [header, *rows]) for k in range(len(header))]

    def line(cells):
        padded = [
            cell.ljust(width) if side == "l" else cell.rjust(width)
            for cell, width, side in zip(cells, widths, align)
        ]
        return "  ".join(padded).rstrip()

    return [prefix + line(header), *("  " + line(row) for row in rows)]


def column_table(
    header: list[str], texts: list[list[str]], numbers: np.ndarray, decimals: list[int],
    tail: list[list[str]] = (), *, prefix: str = "  ",
) -> list[str]:
    """`table` of many rows, the same lines: left-aligned text columns `texts` (lists of n
    str), then `numbers` (n, m) right aligned with `decimals[j]` decimals ("nan" where not
    finite, as `fixed`), then left-aligned text columns `tail`."""
    numbers = np.asarray(numbers, dtype=float).reshape(-1, len(decimals))
    numbers = np.where(np.isfinite(numbers), numbers, np.nan)
    n_text = len(texts)
    widths = [max(map(len, [name, *column])) for name, column in zip(header, texts)]
    widths += [
        max(len(name), _printed_width(numbers[:, j], d))
        for j, (name, d) in enumerate(zip(header[n_text:], decimals))
    ]
    widths += [max(map(len, [name, *column])) for name, column in zip(header[-len(tail):], tail)]
    n = len(numbers)
    places = np.broadcast_to(np.asarray(decimals, dtype=int), numbers.shape)
    body = _number_lines(numbers, places, widths[n_text:n_text + len(decimals)], b"nan")
    head_format = "  " + "".join(f"%-{w}s  " for w in widths[:n_text])
    tail_format = "".join(f"  %-{w}s" for w in widths[n_text + len(decimals):])
    rows = map(str.rstrip, map(
        "".join, zip(map(head_format.__mod__, zip(*texts)) if texts else [head_format] * n,
                     body, map(tail_format.__mod__, zip(*tail)) if tail else [""] * n)))
    sides = ["l"] * n_text + ["r"] * len(decimals) + ["l"] * len(tail)
    head = "  ".join(c.ljust(w) if side == "l" else c.rjust(w)
                     for c, w, side in zip(header, widths, sides))
    return [prefix + head.rstrip(), *rows]


def _number_lines(numbers: np.ndarray, places: np.ndarray, widths: list[int],
                  missing: bytes) -> list[str]:
    """One line per row of `numbers` (n, m): `_number_chars` decoded."""
    return _number_chars(numbers, places, widths, missing).tobytes().decode("ascii").splitlines()


def _number_chars(numbers: np.ndarray, places: np.ndarray, widths: list[int],
                  missing: bytes) -> np.ndarray:
    """The rows of `numbers` (n, m) as ASCII, (n, characters) uint8, each ending in a newline:
    column j right aligned in `widths[j]` with `places` (n, m) decimals, `missing` where not
    finite, columns two spaces apart; all printed at once (`fixed_cells`)."""
    n, most = len(numbers), max(widths, default=0)
    cells = fixed_cells(numbers, places, most, missing=missing).reshape(*numbers.shape, most)
    gap = np.full((n, 2), ord(" "), dtype=np.uint8)
    columns = [cells[:, j, most - width:] for j, width in enumerate(widths)]
    parts = [part for column in columns for part in (gap, column)][1:]
    return np.concatenate([*parts, np.full((n, 1), ord("\n"), dtype=np.uint8)], axis=1)


def _printed_width(values: np.ndarray, decimals: int) -> int:
    """Characters of the widest of `values` as `fixed` prints them ("nan" if not finite; the
    widest finite one is the smallest or the largest), 0 for no values."""
    finite = values[np.isfinite(values)]
    widths = [len(f"{v:.{decimals}f}") for v in (finite.min(), finite.max())] if finite.size else []
    return max(widths + [3] * (finite.size < values.size), default=0)


def decimals_for(stds: np.ndarray, *, digits: int = 2, low: int = 3, high: int = 12) -> int:
    """Decimals that show the smallest positive σ with `digits` significant digits."""
    positive = np.asarray(stds, dtype=float)
    positive = positive[np.isfinite(positive) & (positive > 0)]
    if positive.size == 0:
        return low + 3
    wanted = math.ceil(-math.log10(positive.min())) + digits - 1
    return int(min(max(wanted, low), high))


def fixed(value: float, decimals: int) -> str:
    return f"{value:.{decimals}f}" if math.isfinite(value) else "nan"


def scientific(value: float, digits: int) -> str:
    return f"{value:.{digits}e}" if math.isfinite(value) else "nan"


def _fixed_width(values: np.ndarray, decimals: int) -> int:
    """Characters of the widest of `values` printed with `decimals` decimals: 3 for "nan"
    among numbers, 1 for all NaN ("-"), 0 for no values."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return min(values.size, 1)
    widths = [len(f"{v:.{decimals}f}") for v in (finite.min(), finite.max())]
    return max(widths + [3] * (finite.size < values.size))


def number_table(
    header: list[str], labels: list[tuple[list[str], np.ndarray]], numbers: np.ndarray,
    decimals: list[list[int]], kind: np.ndarray, *, prefix: str = "# ",
) -> str:
    """Aligned lines as `table`, each ending in a newline, fast for many rows: the text
    columns `labels` ((strings, codes (n,)): row i shows strings[codes[i]], left aligned),
    then `numbers` (n, m) right aligned with `decimals[kind[i]][j]` decimals in row i, column
    j (`kind` (n,) int) and `-` where not finite; the rows laid out in one pass (`joined`)."""
    n_text = len(labels)
    numbers = np.where(np.isfinite(numbers), numbers, np.nan)
    n = len(numbers)
    rows = [numbers[kind == k] for k in range(len(decimals))]
    used = [[strings[k] for k in np.unique(codes).tolist()] for strings, codes in labels]
    widths = [max(map(len, [name, *column])) for name, column in zip(header, used)]
    widths += [
        max([len(name)] + [_fixed_width(r[:, j], places[j]) for r, places in zip(rows, decimals)])
        for j, name in enumerate(header[n_text:])
    ]
    places = np.asarray(decimals, dtype=int)[kind]  # (n, m) decimals of every entry
    gap = constant("  ", n)
    columns = [gap]
    for (strings, codes), width in zip(labels, widths):
        columns += [texts(strings, codes, width=width), gap]
    columns.append(whole(_number_chars(numbers, places, widths[n_text:], b"-")))
    cells = [c.ljust(w) for c, w in zip(header[:n_text], widths)]
    cells += [c.rjust(w) for c, w in zip(header[n_text:], widths[n_text:])]
    return prefix + "  ".join(cells).rstrip() + "\n" + (joined(columns) if n else "")
