"""observations.csv: one row per observation with its residual, redundancy number and w.

Image points first (one row per point: x and y together, sorted by image like NAME.res), then
the scalar observations of the other groups (control, GNSS/INS, camera priors, distances), group
by group. Numbers are written with 10 significant digits (`%.10g`); an empty field is a value
that does not apply to the row's type or is not available (no reliability computed, the r of
an observation removed by data snooping).
"""

import csv
import io
import itertools
import pathlib

import numpy as np

from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._collect import ScalarObservation, image_residuals, other_observations

TEXT_COLUMNS = ("type", "group", "image", "point", "point_b", "camera", "coordinate")
NUMBER_COLUMNS = ("x", "y", "vx", "vy", "rx", "ry", "wx", "wy", "v", "r", "w")
FLAG_COLUMNS = ("removed", "outlier")
COLUMNS = TEXT_COLUMNS + NUMBER_COLUMNS + FLAG_COLUMNS


def _field(text: str) -> str:
    """`text` as one CSV field: quoted when it holds a comma, a quote or a line break."""
    if "," in text or '"' in text or "\n" in text or "\r" in text:
        return '"' + text.replace('"', '""') + '"'
    return text


def _lines(texts: list[list[str]], numbers: np.ndarray, filled: tuple[str, ...]) -> str:
    """CSV lines of rows, each ending in a newline: the text fields `texts` (one list per
    column, already CSV fields), then the number and flag columns, `filled` ones from
    `numbers` (n, len(filled)) as `%.10g` (flags 0/1), empty where not finite, the others
    empty. One `%` over all rows when every number is finite; otherwise the numbers first
    (their "nan" and "inf" then cut), the rows around them in a second `%`."""
    numbers = np.asarray(numbers, dtype=float).reshape(-1, len(filled))
    fmt = ",".join(
        "" if name not in filled else "%d" if name in FLAG_COLUMNS else "%.10g"
        for name in NUMBER_COLUMNS + FLAG_COLUMNS
    )
    if np.isfinite(numbers).all():  # the fields of every row side by side, taken row by row
        fields = np.empty((len(numbers), len(texts) + len(filled)), dtype=object)
        for k, column in enumerate(texts):
            fields[:, k] = column
        fields[:, len(texts):] = numbers
        row = "%s," * len(texts) + fmt + "\n"
        return row * len(numbers) % tuple(fields.ravel().tolist())
    formatted = (fmt + "\n") * len(numbers) % tuple(numbers.ravel().tolist())
    # Only numbers are in `formatted`: "nan" and "inf" can only be non-finite values.
    formatted = formatted.replace("-inf", "").replace("inf", "").replace("nan", "")
    row = "%s," * len(texts) + "%s\n"
    fields = zip(*texts, formatted.split("\n")[:-1])
    return row * len(numbers) % tuple(itertools.chain.from_iterable(fields))


def _image_point_lines(project: Project, result: Adjustment) -> str:
    """Rows of the image points, each named by its group's part ("image_points:<camera>")."""
    residuals = image_residuals(project, result)
    n = len(residuals.image)
    image_ids = np.array([_field(i) for i in project.image_ids], dtype=object)
    point_ids = np.array([_field(p) for p in project.point_ids], dtype=object)
    cameras = np.array([_field(project.spec.images[i].camera) for i in project.image_ids],
                       dtype=object)
    empty = [""] * n
    parts = np.array([_field(part) for part in residuals.parts], dtype=object)
    texts = [
        ["image_points"] * n,
        parts[residuals.part_index].tolist(),
        image_ids[residuals.image].tolist(),
        point_ids[residuals.point].tolist(),
        empty,
        cameras[residuals.image].tolist(),
        empty,
    ]
    numbers = np.column_stack([
        residuals.xy, residuals.v, residuals.redundancy, residuals.w, residuals.removed,
        residuals.outlier,
    ])
    return _lines(texts, numbers, NUMBER_COLUMNS[:8] + FLAG_COLUMNS)


def _scalar_lines(rows: list[ScalarObservation]) -> str:
    """Rows of the observations other than image points: their IDs, v, r, w and flags."""
    texts = [
        [_field(value) for value in column]
        for column in zip(*(
            (row.kind, row.group, row.ids.get("image", ""),
             row.ids.get("point", row.ids.get("point_a", "")), row.ids.get("point_b", ""),
             row.ids.get("camera", ""), row.ids.get("coordinate", ""))
            for row in rows
        ))
    ]
    filled = ("v", "r", "w") + FLAG_COLUMNS
    numbers = np.array(
        [[row.v, row.r, row.w, row.removed, row.outlier] for row in rows], dtype=float,
    ).reshape(len(rows), len(filled))
    return _lines(texts or [[]] * len(TEXT_COLUMNS), numbers, filled)


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
