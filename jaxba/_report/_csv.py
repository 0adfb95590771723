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
    measured = [j for j, name in enumerate(filled) if name not in FLAG_COLUMNS]
    general = general_cells(numbers[:, measured], 10)
    general = Cells(*(cells.reshape(n, len(measured), -1) for cells in general))
    columns, separator = [], ""
    for strings, codes in labels:
        columns += [*([constant(separator, n)] if separator else []), text_cells(strings, codes)]
        separator = ","
    for name in NUMBER_COLUMNS + FLAG_COLUMNS:
        if name in filled:
            j = filled.index(name)
            cells = (text_cells(["0", "1"], numbers[:, j].astype(int)) if name in FLAG_COLUMNS else
                     Cells(*(c[:, measured.index(j)] for c in general)))
            columns += [constant(separator, n), cells]
            separator = ","
        else:
            separator += ","
    return joined([*columns, constant(separator[1:] + "\n", n)])


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
