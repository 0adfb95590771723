"""observations.csv: one row per observation with its residual, redundancy number and w.

Image points first (one row per point: x and y together, sorted by image like NAME.res), then
the scalar observations of the other groups (control, GNSS/INS, camera priors, distances), group
by group. Numbers are written with at most 10 significant digits (as `%.10g` rounds them, the
shortest text that reads back to the rounded value: `1e-7`, `65.0`); an empty field is a value
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
from ._shortest import number_rows, significant

TEXT_COLUMNS = ("type", "group", "image", "point", "point_b", "camera", "coordinate")
NUMBER_COLUMNS = ("x", "y", "vx", "vy", "rx", "ry", "wx", "wy", "v", "r", "w")
FLAG_COLUMNS = ("removed", "outlier")
COLUMNS = TEXT_COLUMNS + NUMBER_COLUMNS + FLAG_COLUMNS


def _field(text: str) -> str:
    """`text` as one CSV field: quoted when it holds a comma, a quote or a line break."""
    if "," in text or '"' in text or "\n" in text or "\r" in text:
        return '"' + text.replace('"', '""') + '"'
    return text


def _piece(text: str) -> str:
    """`text` as one CSV field followed by its comma."""
    return _field(text) + ","


def _lines(texts: list, numbers: np.ndarray, filled: tuple[str, ...]) -> str:
    """CSV lines of rows, each ending in a newline: the text fields, then the number and flag
    columns, `filled` ones from `numbers` (n, len(filled)), the others empty. Numbers at 10
    significant digits (`significant`), empty where not finite; flags 0, 1 or empty (NaN).

    `texts`: the pieces of the rows' text fields, column k the k-th piece of every row ((n,)
    str: `_piece`s, or several fields in one), put side by side. The filled number columns
    are consecutive ones of `NUMBER_COLUMNS`; their text comes from one `number_rows`."""
    numbers = np.asarray(numbers, dtype=float).reshape(-1, len(filled))
    flags = [j for j, name in enumerate(filled) if name in FLAG_COLUMNS]
    shown = [j for j, name in enumerate(filled) if name not in FLAG_COLUMNS]
    first = NUMBER_COLUMNS.index(filled[shown[0]])
    if tuple(filled[j] for j in shown) != NUMBER_COLUMNS[first:first + len(shown)]:
        raise ValueError(f"the number columns {filled} are not consecutive ones")
    given = np.isfinite(numbers[:, flags])
    states = np.where(given, numbers[:, flags], 2.0).astype(int)  # 2: empty
    if not np.all(~given | (states == 0) | (states == 1)):
        raise ValueError("a flag of observations.csv is neither 0 nor 1")
    # The columns after the numbers: empty number columns, then the flags, per flag state.
    after = "," * (len(NUMBER_COLUMNS) - first - len(shown))
    endings = np.array([after + "".join("," + "01"[s] if s < 2 else "," for s in kind) + "\n"
                        for kind in itertools.product(range(3), repeat=len(flags))],
                       dtype=object)
    pieces = np.empty((len(numbers), len(texts) + 2), dtype=object)
    for k, column in enumerate(texts):
        pieces[:, k] = column
    pieces[:, -2] = number_rows(significant(numbers[:, shown]), missing="")
    pieces[:, -1] = endings[states @ 3 ** np.arange(len(flags))[::-1]]
    if first:
        pieces[:, -2] = "," * first + pieces[:, -2]
    return "".join(pieces.ravel().tolist())


def _image_point_lines(project: Project, result: Adjustment) -> str:
    """Rows of the image points, each named by its group's part ("image_points:<camera>")."""
    residuals = image_residuals(project, result)
    parts = np.array([_piece("image_points") + _piece(part) for part in residuals.parts],
                     dtype=object)
    image_ids = np.array([_piece(i) for i in project.image_ids], dtype=object)
    # Each point followed by the empty point_b, each camera by the empty coordinate.
    point_ids = np.array([_piece(p) + "," for p in project.point_ids], dtype=object)
    cameras = np.array([_piece(project.spec.images[i].camera) + "," for i in project.image_ids],
                       dtype=object)
    texts = [parts[residuals.part_index], image_ids[residuals.image],
             point_ids[residuals.point], cameras[residuals.image]]
    numbers = np.column_stack([
        residuals.xy, residuals.v, residuals.redundancy, residuals.w, residuals.removed,
        residuals.outlier,
    ])
    return _lines(texts, numbers, NUMBER_COLUMNS[:8] + FLAG_COLUMNS)


def _scalar_lines(rows: list[ScalarObservation]) -> str:
    """Rows of the observations other than image points: their IDs, v, r, w and flags."""
    texts = [
        [_piece(value) for value in column]
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
    return _lines(texts, numbers, filled)


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
