"""observations.csv: one row per observation with its residual, redundancy number and w.

Image points first (one row per point: x and y together, sorted by image like NAME.res), then
the scalar observations of the other groups (control, GNSS/INS, camera priors, distances), group
by group. Numbers are written with 10 significant digits (`%.10g`); an empty field is a value
that does not apply to the row's type or is not available (no reliability computed, the r of
an observation removed by data snooping).
"""

import csv
import io
import pathlib

import numpy as np

from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._cells import Cells, constant, joined, texts as text_cells
from ._collect import ScalarObservation, image_residuals, other_observations
from ._numbers import general_cells

TEXT_COLUMNS = ("type", "group", "image", "point", "point_b", "camera", "coordinate")
NUMBER_COLUMNS = ("x", "y", "vx", "vy", "rx", "ry", "wx", "wy", "v", "r", "w")
FLAG_COLUMNS = ("removed", "outlier")
COLUMNS = TEXT_COLUMNS + NUMBER_COLUMNS + FLAG_COLUMNS


def _field(text: str) -> str:
    """`text` as one CSV field: quoted when it holds a comma, a quote or a line break."""
    if "," in text or '"' in text or "\n" in text or "\r" in text:
        return '"' + text.replace('"', '""') + '"'
    return text


def _lines(labels: list[tuple[list[str], np.ndarray]], numbers: np.ndarray,
           filled: tuple[str, ...]) -> str:
    """CSV lines of n rows, each ending in a newline: the text fields `labels` ((strings,
    codes (n,)): row i holds strings[codes[i]], already a CSV field), then the number and flag
    columns, `filled` ones from `numbers` (n, len(filled)) as `%.10g` (flags 0/1), empty where
    not finite, the others empty; all rows laid out in one pass (`joined`)."""
    n = len(numbers)
    if not n:
        return ""
    numbers = np.asarray(numbers, dtype=float).reshape(n, len(filled))
    fields = [*([(strings, codes)] for strings, codes in labels)]
    for name in NUMBER_COLUMNS + FLAG_COLUMNS:
        j = filled.index(name) if name in filled else None
        if j is None:
            fields.append("")
        elif name in FLAG_COLUMNS:
            fields.append([(["0", "1"], numbers[:, j].astype(int))])
        elif isinstance(fields[-1], list) or not fields[-1] or fields[-1][-1] != j - 1:
            fields.append((j,))  # a run of numbers, columns of `numbers` side by side
        else:
            fields[-1] += (j,)
    columns, separator = [], ""
    for k, field in enumerate(fields):
        end = "\n" if k == len(fields) - 1 else ","
        if field == "":
            separator += end
            continue
        if separator:
            columns.append(constant(separator, n))
        if isinstance(field, list):
            columns.append(text_cells(*field[0]))
            separator = end
        else:  # each number's cell and the separator after it, the run as one column
            cells = general_cells(numbers[:, list(field)], 10)
            chars = np.empty((n, len(field), cells.chars.shape[1] + 1), dtype=np.uint8)
            keep = np.ones(chars.shape, dtype=bool)
            chars[:, :, :-1], keep[:, :, :-1] = (a.reshape(n, len(field), -1) for a in cells)
            chars[:, :, -1] = ord(",")
            chars[:, -1, -1] = ord(end)
            columns.append(Cells(chars.reshape(n, -1), keep.reshape(n, -1)))
            separator = ""
    return joined([*columns, *([constant(separator, n)] if separator else [])])


def _image_point_lines(project: Project, result: Adjustment) -> str:
    """Rows of the image points, each named by its group's part ("image_points:<camera>")."""
    residuals = image_residuals(project, result)
    none = np.zeros(len(residuals.image), dtype=np.intp)
    cameras = [_field(project.spec.images[i].camera) for i in project.image_ids]
    labels = [
        (["image_points"], none),
        ([_field(part) for part in residuals.parts], residuals.part_index),
        ([_field(i) for i in project.image_ids], residuals.image),
        ([_field(p) for p in project.point_ids], residuals.point),
        ([""], none),
        (cameras, residuals.image),
        ([""], none),
    ]
    numbers = np.column_stack([
        residuals.xy, residuals.v, residuals.redundancy, residuals.w, residuals.removed,
        residuals.outlier,
    ])
    return _lines(labels, numbers, NUMBER_COLUMNS[:8] + FLAG_COLUMNS)


def _scalar_lines(rows: list[ScalarObservation]) -> str:
    """Rows of the observations other than image points: their IDs, v, r, w and flags."""
    fields = [
        (row.kind, row.group, row.ids.get("image", ""),
         row.ids.get("point", row.ids.get("point_a", "")), row.ids.get("point_b", ""),
         row.ids.get("camera", ""), row.ids.get("coordinate", ""))
        for row in rows
    ]
    each = np.arange(len(rows))
    labels = [([_field(value) for value in column], each) for column in zip(*fields)]
    filled = ("v", "r", "w") + FLAG_COLUMNS
    numbers = np.array(
        [[row.v, row.r, row.w, row.removed, row.outlier] for row in rows], dtype=float,
    ).reshape(len(rows), len(filled))
    return _lines(labels, numbers, filled)


def observations_csv(project: Project, result: Adjustment) -> str:
    """observations.csv as text: header `COLUMNS`, image points, then the other observations."""
    return (",".join(COLUMNS) + "\n" + _image_point_lines(project, result)
            + _scalar_lines(other_observations(project, result)))


def read_observations(path) -> dict[str, np.ndarray]:
    """observations.csv as columns: `COLUMNS` names -> (n,) arrays.

    Text columns are str arrays ("" where empty), numbers float (NaN where empty), removed and
    outlier bool.
    """
    text = pathlib.Path(path).read_text(encoding="utf-8")
    header, *rows = list(csv.reader(io.StringIO(text)))
    columns = dict(zip(header, map(list, zip(*rows)))) if rows else {name: [] for name in header}
    table = {}
    for name in header:
        values = np.array(columns[name], dtype=str)
        if name in TEXT_COLUMNS:
            table[name] = values
        else:
            numbers = np.where(values == "", "nan", values).astype(float)
            table[name] = numbers.astype(bool) if name in FLAG_COLUMNS else numbers
    return table
