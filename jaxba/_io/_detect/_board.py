"""The calibration target: the `--board` grammar and the board's points in its own frame.

Grammar (`parse_board`), sizes as OpenCV counts them, SPACING a number with an optional unit
(mm, cm, m, in; the board's points are written in that unit, a bare number in "board units"):

- `chessboard:COLSxROWS:SPACING`: COLS x ROWS *inner* corners, SPACING the square's side.
- `circles:COLSxROWS:SPACING`: a symmetric grid of COLS x ROWS circles, SPACING centre to centre.
- `acircles:COLSxROWS:SPACING`: OpenCV's asymmetric grid (patternSize COLS x ROWS, such as
  4x11); circle (row r, column c) at ((2c + r mod 2) SPACING, r SPACING).
- `charuco:COLSxROWS:SQUARE:MARKER:DICT[:first=N][:legacy]`: COLS x ROWS *squares*, ArUco
  markers of side MARKER from OpenCV's dictionary DICT (`5X5_100` or `DICT_5X5_100`), marker
  ids from N on (default 0), `legacy` for boards drawn by OpenCV before 4.6 with an even
  number of rows. Its points are the (COLS - 1) x (ROWS - 1) inner corners.

Points lie in the board's plane Z = 0, X along the columns, Y along the rows, and are named
by their index in OpenCV's order ("0", "1", ...): row by row, COLS to a row (ChArUco: the
corner id). No OpenCV here; the detectors build OpenCV's objects from a `Board`.
"""

import dataclasses
import re

import numpy as np

KINDS = ("chessboard", "circles", "acircles", "charuco")
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
_LENGTH = re.compile(r"^(?P<value>[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(?P<unit>[a-z]*)$")
_SIZE = re.compile(r"^(?P<cols>[0-9]+)[xX](?P<rows>[0-9]+)$")


class BoardError(ValueError):
    """A `--board` text that does not follow the grammar."""


@dataclasses.dataclass(frozen=True)
class Board:
    """A calibration target (module docstring for the fields' meaning).

    `cols`, `rows`: as in the grammar (inner corners, circles or squares); `spacing`: the
    square side or circle spacing in `unit` ("" when none was given); `marker`, `dictionary`,
    `first_id`, `legacy`: ChArUco only.
    """

    kind: str
    cols: int
    rows: int
    spacing: float
    unit: str = ""
    marker: float = 0.0
    dictionary: str = ""
    first_id: int = 0
    legacy: bool = False

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(columns, rows) of the board's points: OpenCV's patternSize."""
        if self.kind == "charuco":
            return self.cols - 1, self.rows - 1
        return self.cols, self.rows

    @property
    def n_points(self) -> int:
        cols, rows = self.pattern_size
        return cols * rows

    @property
    def n_markers(self) -> int:
        """ArUco markers on a ChArUco board (on half its squares), 0 for other boards."""
        return self.cols * self.rows // 2 if self.kind == "charuco" else 0

    def points(self) -> np.ndarray:
        """The board's points (n_points, 3) in its frame, in `unit`, in OpenCV's order."""
        cols, rows = self.pattern_size
        r, c = np.divmod(np.arange(cols * rows), cols)
        x = (2 * c + r % 2) if self.kind == "acircles" else c + (self.kind == "charuco")
        y = r + (self.kind == "charuco")
        return np.column_stack([x * self.spacing, y * self.spacing, np.zeros(len(r))])

    def text(self) -> str:
        """The board as `parse_board` reads it."""
        size = f"{self.kind}:{self.cols}x{self.rows}:{self.spacing:g}{self.unit}"
        if self.kind != "charuco":
            return size
        options = ([f"first={self.first_id}"] if self.first_id else []) + (
            ["legacy"] if self.legacy else [])
        return ":".join([size, f"{self.marker:g}{self.unit}", self.dictionary, *options])


def _length(text: str, what: str, spec: str) -> tuple[float, str]:
    match = _LENGTH.match(text.strip())
    if match is None or match["unit"] not in ("", *UNITS_MM):
        raise BoardError(f"--board {spec}: {what} {text!r}: expected a number with an optional"
                         f" unit ({', '.join(UNITS_MM)}), e.g. 25mm")
    value = float(match["value"])
    if not value > 0:
        raise BoardError(f"--board {spec}: {what} {text!r} must be positive")
    return value, match["unit"]


def parse_board(spec: str) -> Board:
    """The `Board` of a `--board` text (module docstring); `BoardError` names the bad part."""
    parts = spec.split(":")
    kind = parts[0].strip().lower()
    if kind not in KINDS:
        raise BoardError(f"--board {spec}: unknown board {parts[0]!r}; expected one of"
                         f" {', '.join(KINDS)}")
    wanted = 5 if kind == "charuco" else 3
    if len(parts) < wanted or (kind != "charuco" and len(parts) > wanted):
        form = ("charuco:COLSxROWS:SQUARE:MARKER:DICT[:first=N][:legacy]" if kind == "charuco"
                else f"{kind}:COLSxROWS:SPACING")
        raise BoardError(f"--board {spec}: expected {form}")
    size = _SIZE.match(parts[1].strip())
    if size is None:
        raise BoardError(f"--board {spec}: size {parts[1]!r}: expected COLSxROWS, e.g. 9x6")
    cols, rows = int(size["cols"]), int(size["rows"])
    smallest = 3 if kind == "charuco" else 2
    if cols < smallest or rows < smallest:
        raise BoardError(f"--board {spec}: size {parts[1]!r}: a {kind} needs at least"
                         f" {smallest}x{smallest}")
    spacing, unit = _length(parts[2], "spacing" if kind != "charuco" else "square", spec)
    if kind != "charuco":
        return Board(kind, cols, rows, spacing, unit)

    marker, marker_unit = _length(parts[3], "marker", spec)
    if marker_unit != unit:
        if not (marker_unit and unit):
            raise BoardError(f"--board {spec}: give the square and the marker in one unit")
        marker *= UNITS_MM[marker_unit] / UNITS_MM[unit]
    if marker >= spacing:
        raise BoardError(f"--board {spec}: the marker ({parts[3]}) must be smaller than the"
                         f" square ({parts[2]})")
    dictionary = parts[4].strip().upper().removeprefix("DICT_")
    if not re.fullmatch(r"[0-9A-Z_]+", dictionary):
        raise BoardError(f"--board {spec}: dictionary {parts[4]!r}: expected an OpenCV ArUco"
                         " dictionary such as 5X5_100")
    first_id, legacy = 0, False
    for option in parts[5:]:
        option = option.strip().lower()
        if option == "legacy":
            legacy = True
        elif option.startswith("first=") and option[6:].isdigit():
            first_id = int(option[6:])
        else:
            raise BoardError(f"--board {spec}: unknown ChArUco option {option!r}; expected"
                             " first=N or legacy")
    return Board(kind, cols, rows, spacing, unit, marker, dictionary, first_id, legacy)
