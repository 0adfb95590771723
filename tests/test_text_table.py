"""Tests of the text tables' reading (`TextTable`): every table gives the tokens and line
numbers that splitting each line (comments cut) gives, and the errors name the line and
column; the cameras and points read before come back equal, in fresh containers."""

import math
import pathlib

import numpy as np
import pytest

from jaxba._io._project._cameras import read_cameras
from jaxba._io._project._tables import read_points
from jaxba._io._project._text_table import TextTable
from jaxba._project._errors import ProjectError
from jaxba._project._spec import InputFile

COLUMNS = ("id", "x", "y", "sx", "sy")


def _expected(text: str) -> tuple[list[list[str]], list[int]]:
    """The data rows (padded with '-' to five columns) and their line numbers, line by line
    in plain Python: the reference."""
    text = text.lstrip("\ufeff").replace("\r\n", "\n").replace("\r", "\n")
    rows, lines = [], []
    for number, line in enumerate(text.split("\n"), start=1):
        tokens = line.split("#", 1)[0].split()
        if tokens:
            rows.append((tokens + ["-"] * 5)[:5])
            lines.append(number)
    return rows, lines


TABLES = {
    "plain": "a 1.5 2\nb -3 4e-3\n",
    "comments and blank lines": "# header\n\na 1 2  # note\n   \nb 3 4\n#end",
    "crlf, tabs, no last newline": "a\t1\t2\r\nb 3  4",
    "cr only": "a 1 2\rb 3 4\r",
    "split's other spaces": "a\x0b1\x0c2\nb\x1c3\x1f4\n",
    "bom": "\ufeffa 1 2\nb 3 4\n",
    "sigma columns": "a 1 2 0.1 0.2\nb 3 4 - -\n",
    "mixed layouts": "a 1 2\nb 3 4 0.1 0.2\n",
    "non-ASCII IDs": "ä 1 2\nb 3 4\n",
    "non-ASCII comment": "a 1 2  # café\nb 3 4\n",
    "one row": "a 1 2",
}


@pytest.mark.parametrize("text", TABLES.values(), ids=TABLES.keys())
def test_tokens_and_lines(tmp_path, text):
    path = tmp_path / "t.txt"
    path.write_bytes(text.encode())
    table = TextTable(InputFile(path, "t.txt"), COLUMNS, 3)
    rows, lines = _expected(text)
    assert table.lines.tolist() == lines
    assert [list(table.column(k)) for k in range(5)] == [list(c) for c in zip(*rows)]
    values = table.numbers((1, 2))
    assert values.shape == (len(rows), 2)
    assert values.tolist() == [[float(row[1]), float(row[2])] for row in rows]
    table.check()


@pytest.mark.parametrize("text, message", [
    ("a 1 2\nb 3\n", "t.txt:2: expected 3 or 5 columns (id x y [sx sy]), got 2"),
    ("a 1 2\nb 3 4 5 6 7\n", "t.txt:2: expected 3 or 5 columns (id x y [sx sy]), got 6"),
    ("# only\n\na 1 2 3\n", "t.txt:3: expected 3 or 5 columns (id x y [sx sy]), got 4"),
    ("a 1 2\nb 3 x\n", "t.txt:2: column y: expected a number, got 'x'"),
    ("a 1 2\nb 3 nan\n", "t.txt:2: column y: expected a number, got 'nan'"),
    ("a 1 2\nb inf 2\n", "t.txt:2: column x: expected a number, got 'inf'"),
    ("a 1 2\nb 1e13 2\n", "t.txt:2: column x: 1e13 is out of range"),
])
def test_errors_name_the_line_and_column(tmp_path, text, message):
    path = tmp_path / "t.txt"
    path.write_text(text)
    table = TextTable(InputFile(path, "t.txt"), COLUMNS, 3)
    table.numbers((1, 2))
    with pytest.raises(ProjectError) as error:
        table.check()
    assert str(error.value).startswith(message)


def test_sigmas_dash_zero_and_errors(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("a 1 2 0 -\nb 3 4 0.5 0.25\n")
    table = TextTable(InputFile(path, "t.txt"), COLUMNS, 3)
    sigma = table.sigmas((3, 4))
    assert sigma[:, 0].tolist() == [0.0, 0.5]
    assert math.isnan(sigma[0, 1]) and sigma[1, 1] == 0.25
    table.check()
    assert np.isnan(table.sigmas((3, 4), fixed=False)[0, 1])
    with pytest.raises(ProjectError, match=r"t.txt:1: column sx: expected a number > 0 or '-'"):
        table.check()


CAMERAS = """\
[C1]
model = "opencv"
sensor = [640, 480]
fx = 800.0
fy = 800.0
free = ["fx", "fy"]
"""


def test_cameras_read_again_are_equal_and_fresh(tmp_path):
    first, second = pathlib.Path(tmp_path / "a.toml"), pathlib.Path(tmp_path / "b.toml")
    first.write_text(CAMERAS)
    second.write_text(CAMERAS)
    one = read_cameras(InputFile(first, "cameras.toml"), "pixel", "p.toml")
    two = read_cameras(InputFile(second, "cameras.toml"), "pixel", "p.toml")
    assert one == two and one is not two
    assert two["C1"].values["fx"] == 800.0 and two["C1"].free == {"fx", "fy"}
    second.write_text(CAMERAS.replace("fx = 800.0", "fx = 810.0"))
    assert read_cameras(InputFile(second, "cameras.toml"), "pixel", "p.toml")["C1"].values[
        "fx"] == 810.0
    first.write_text(CAMERAS.replace("sensor = [640, 480]\n", ""))
    for _ in range(2):  # an error is not kept: raised again
        with pytest.raises(ProjectError, match=r"cameras.toml: \[C1\] sensor: missing"):
            read_cameras(InputFile(first, "cameras.toml"), "pixel", "p.toml")


def test_points_read_again_are_equal_and_fresh(tmp_path):
    path = tmp_path / "points.txt"
    path.write_text("# board\n1 0 0 0 0 0 0\n2 0.5 0 0 0 0 0\n")
    first = read_points(InputFile(path, "points.txt"))
    first.pop("1")
    again = read_points(InputFile(path, "points.txt"))
    assert list(again) == ["1", "2"] and again["2"].xyz == (0.5, 0.0, 0.0)
    assert again["2"].sigma == (0.0, 0.0, 0.0) and again["2"].line == 3
    path.write_text("1 0 0 0 0 0 0\n2 0.5 0 0 0 0 0\n")  # the same points, other lines
    assert read_points(InputFile(path, "points.txt"))["2"].line == 2
