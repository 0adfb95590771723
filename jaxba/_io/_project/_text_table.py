"""The whitespace-separated text tables of a project (images, points, image points, distances,
frames), read column by column.

A data line has either the required columns or all of them (the optional ones are σ, `-`
when left out); `#` starts a comment, blank lines are skipped. Each rule (a number, a σ, an ID
known elsewhere, a unique key) is written once here and checks a whole column; it notes the
first row it fails in, and `TextTable.check` raises the first noted failure in file order
(rules of one row in the order they were applied), so the message names the line and column
that a reader going row by row would stop at: `file:line: column X: ...`.
"""

import dataclasses
import itertools
import math
import re
from collections.abc import Callable, Container, Hashable, Iterator

import numpy as np

from ..._project._errors import ProjectError
from ..._project._spec import InputFile
from ._toml import read_bytes

# The largest magnitude of a number in a text table (coordinates, angles, image points,
# distances): anything larger is a typo or a unit mistake, and would overflow the model
# (a squared 1e200 is inf) instead of being reported where it was written.
MAX_MAGNITUDE = 1e12


class TextTable:
    """The data rows of a text table as columns of tokens, and the failures noted so far.

    `columns` names the columns in order; a row has the first `n_required` of them or all.
    `data`: the file's content, if it was read already. `lines` (n,) holds the line numbers
    of the n data rows.
    """

    def __init__(self, file: InputFile, columns: tuple[str, ...], n_required: int,
                 data: bytes | None = None):
        self.name, self.columns = file.name, columns
        self._failures: list[tuple[int, int, str, int | None]] = []
        text = _table_text(file, read_bytes(file.path, file.name) if data is None else data)
        self._read_rows(text, n_required, sorted({n_required, len(columns)}))

    def _read_rows(self, text: str, n_required: int, counts: list[int]) -> None:
        """Read `text` line by line, a failure noted at the first row of a wrong count (not
        one of `counts`)."""
        rows = list(map(str.split, text.split("\n")))
        sizes = np.fromiter(map(len, rows), dtype=int, count=len(rows))
        self.lines = np.flatnonzero(sizes) + 1
        rows, sizes = list(filter(None, rows)), sizes[sizes > 0]
        layout = " ".join(self.columns[:n_required])
        if n_required < len(self.columns):
            layout += " [" + " ".join(self.columns[n_required:]) + "]"
        self.fail((sizes != counts[0]) & (sizes != counts[-1]), lambda r: (
            f"expected {' or '.join(map(str, counts))} columns ({layout}), got {sizes[r]}"))
        self._columns = _as_columns(rows, sizes, len(self.columns))

    def __len__(self) -> int:
        return len(self.lines)

    def column(self, k: int) -> tuple[str, ...]:
        """The tokens of column `k`, `-` where a row left it out."""
        return self._columns[k]

    def numbers(self, columns: tuple[int, ...], *, positive: bool = False,
                where: np.ndarray | None = None) -> np.ndarray:
        """The `columns` as finite numbers of magnitude at most `MAX_MAGNITUDE` (> 0 with
        `positive`), float (n, len(columns)), read in the rows `where` (bool (n,), default
        all)."""
        values = self._floats(columns)
        bad = ~(np.abs(values) <= MAX_MAGNITUDE) | (positive & (values <= 0))
        if where is not None:
            bad &= where[:, None]
        if not bad.any():
            return values
        where = np.ones(len(self), dtype=bool) if where is None else where
        expected = "a number > 0" if positive else "a number"
        for k, column in zip(columns, values.T):  # each column's rules, as a reader meets them
            tokens = self._columns[k]
            finite = np.isfinite(column) & ~(positive & (column <= 0))
            self.fail(~finite & where, lambda r: f"expected {expected}, got {tokens[r]!r}", k)
            self.fail((np.abs(column) > MAX_MAGNITUDE) & where, lambda r: (
                f"{tokens[r]} is out of range: numbers must be at most 1e12 in magnitude (a"
                " typo or a unit mistake?)"), k)
        return values

    def sigmas(self, columns: tuple[int, ...], *, fixed: bool = True) -> np.ndarray:
        """The `columns` as σ, float (n, len(columns)): NaN for `-` (none given), 0 for fixed
        (only if `fixed`), or a finite number > 0."""
        tokens = [self._columns[k] for k in columns]
        if all(column.count("-") == len(column) for column in tokens):
            return np.full((len(self), len(columns)), math.nan)
        values = self._floats(columns)
        valid = np.isfinite(values) & ((values >= 0) if fixed else (values > 0))
        if valid.all():
            return values
        expected = "a number, '0' or '-'" if fixed else "a number > 0 or '-'"
        for k, column, valid_k in zip(columns, tokens, valid.T):
            if column.count("-") == len(column):
                continue
            given = np.fromiter((token != "-" for token in column), dtype=bool,
                                count=len(column))
            self.fail(given & ~valid_k, lambda r: f"expected {expected}, got {column[r]!r}", k)
        return values

    def known(self, k: int, ids: Container[str], message: Callable[[str], str]) -> None:
        """Every ID in column `k` is in `ids`; `message(ID)` at the first that is not."""
        tokens = self._columns[k]
        if not all(map(ids.__contains__, set(tokens))):
            bad = np.fromiter((token not in ids for token in tokens), dtype=bool,
                              count=len(tokens))
            self.fail(bad, lambda r: message(tokens[r]), k)

    def unique(self, columns: tuple[int, ...], what: Callable[[Hashable], str]) -> None:
        """No key (the tokens of `columns` in a row; one column: the token) repeats:
        "duplicate `what(key)`" at the first repeat, with the line of the first."""
        keys = (self._columns[columns[0]] if len(columns) == 1
                else zip(*(self._columns[k] for k in columns)))
        distinct = set(keys)
        if len(distinct) == len(self):
            return
        keys = (self._columns[columns[0]] if len(columns) == 1
                else list(zip(*(self._columns[k] for k in columns))))
        first: dict[Hashable, int] = {}
        for r, key in enumerate(keys):
            if key in first:
                self._note(r, f"duplicate {what(key)} (first on line {self.lines[first[key]]})")
                return
            first[key] = r

    def fail(self, bad: np.ndarray, message: Callable[[int], str], column: int | None = None
             ) -> None:
        """Note a rule that fails in the rows `bad` (bool (n,)): `message(row)` at the first."""
        if bad.any():
            row = int(np.argmax(bad))
            self._note(row, message(row), column)

    def check(self) -> None:
        """Raise the first failure noted, in file order."""
        if self._failures:
            row, _, message, column = min(self._failures)
            raise self.error(row, message, column)

    def rows(self) -> Iterator["Row"]:
        """The rows in order, for a reader whose rules depend on the rows before it; the first
        failure noted is raised at its row."""
        stop = min(self._failures)[0] if self._failures else len(self)
        for row in range(stop):
            yield Row(self, row)
        self.check()

    def error(self, row: int, message: str, column: int | None = None) -> ProjectError:
        """A `ProjectError` located at data row `row` (and `column`)."""
        field = "" if column is None else f"column {self.columns[column]}: "
        return ProjectError(f"{self.name}:{self.lines[row]}: {field}{message}")

    def _note(self, row: int, message: str, column: int | None = None) -> None:
        self._failures.append((row, len(self._failures), message, column))

    def _floats(self, columns: tuple[int, ...]) -> np.ndarray:
        """The numbers the tokens of `columns` spell, float (n, len(columns)); NaN where one
        spells none (`-` too)."""
        count = len(self) * len(columns)
        tokens = itertools.chain.from_iterable(self._columns[k] for k in columns)
        try:
            values = np.fromiter(map(float, tokens), dtype=float, count=count)
        except ValueError:
            tokens = itertools.chain.from_iterable(self._columns[k] for k in columns)
            values = np.fromiter(map(_float, tokens), dtype=float, count=count)
        return values.reshape(len(columns), len(self)).T.copy()


@dataclasses.dataclass(frozen=True)
class Row:
    """One data row of a `TextTable`."""

    table: TextTable
    index: int

    @property
    def tokens(self) -> tuple[str, ...]:
        return tuple(column[self.index] for column in self.table._columns)

    def error(self, message: str, column: int | None = None) -> ProjectError:
        """A `ProjectError` located at this row (and column)."""
        return self.table.error(self.index, message, column)


def _table_text(file: InputFile, data: bytes) -> str:
    """The text of a table, its content `data`: comments cut, BOM dropped, any line ending
    read as "\\n"."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ProjectError(f"{file.name}: cannot read {file.path}: {error}") from None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return _COMMENT.sub("", text) if "#" in text else text


_COMMENT = re.compile("#[^\n]*")  # from "#" to the end of its line


def _as_columns(rows: list[list[str]], sizes: np.ndarray, n: int) -> list[tuple[str, ...]]:
    """`rows` (of `sizes` tokens) as `n` columns, short rows padded with `-` (the optional
    columns left out) and long ones cut (their failure is noted)."""
    if len(rows) and (sizes == sizes[0]).all() and sizes[0] <= n:  # one layout: no padding
        return list(zip(*rows)) + [("-",) * len(rows)] * (n - int(sizes[0]))
    padding = ["-"] * n
    columns = list(zip(*(row if len(row) == n else (row + padding)[:n] for row in rows)))
    return columns or [()] * n


def _float(token: str) -> float:
    if token == "-":
        return math.nan
    try:
        return float(token)
    except ValueError:
        return math.nan
