"""Reading "Bundle Adjustment in the Large" problem files (plain, .bz2 or .gz).

Format (Agarwal, Snavely, Seitz, Szeliski, ECCV 2010; grail.cs.washington.edu/projects/bal):

    n_cameras n_points n_observations
    camera point x y                    (n_observations lines; pixels, origin at the image centre)
    r1 r2 r3 t1 t2 t3 f k1 k2           (9 values per camera, one per line)
    X Y Z                               (3 values per point, one per line)

Whitespace and blank lines are not significant. Plain Python/NumPy: no jax here.
"""

import bz2
import dataclasses
import gzip
import os
import pathlib

import numpy as np
from jaxtyping import Float, Int

CAMERA_PARAMETER_NAMES = ("r1", "r2", "r3", "t1", "t2", "t3", "f", "k1", "k2")


class BalFormatError(ValueError):
    """A BAL file that cannot be read: the message names the file, the line and what is wrong."""


@dataclasses.dataclass(frozen=True, eq=False)
class BalProblem:
    """A BAL problem as read from its file, NumPy float64 / int64.

    - `cameras`: (n_cameras, 9): Rodrigues rotation r (radians), translation t, focal
      length f (pixels), radial k1, k2 (`CAMERA_PARAMETER_NAMES` order);
    - `points`: (n_points, 3): X, Y, Z (object units);
    - `camera_index`, `point_index`: (n_observations,) rows of `cameras` / `points`;
    - `observed`: (n_observations, 2): measured x, y (pixels, origin at the image centre);
    - `path`: the file it was read from.
    """

    cameras: Float[np.ndarray, "n_cameras 9"]
    points: Float[np.ndarray, "n_points 3"]
    camera_index: Int[np.ndarray, " n_observations"]
    point_index: Int[np.ndarray, " n_observations"]
    observed: Float[np.ndarray, "n_observations 2"]
    path: pathlib.Path | None = None

    @property
    def n_cameras(self) -> int:
        return self.cameras.shape[0]

    @property
    def n_points(self) -> int:
        return self.points.shape[0]

    @property
    def n_observations(self) -> int:
        return self.observed.shape[0]


def read_bal(path: str | os.PathLike) -> BalProblem:
    """Read a BAL problem file; `.bz2` and `.gz` files are decompressed (by their suffix).

    Raises `FileNotFoundError` for a missing file and `BalFormatError` (naming the file,
    the line and the field) for a truncated or malformed file, an empty problem (a count of
    0 in the header) or out-of-range indices.
    """
    path = pathlib.Path(path)
    text = _read_text(path)
    tokens = text.split()
    counts = _header(path, text, tokens)
    n_cameras, n_points, n_observations = counts
    expected = 3 + 4 * n_observations + 9 * n_cameras + 3 * n_points
    try:
        if len(tokens) != expected:
            raise ValueError
        values = np.array(tokens[3:], dtype=np.float64)
    except ValueError:
        _diagnose(path, text, counts)  # raises with the line of the first problem
        raise  # pragma: no cover - _diagnose always raises when the fast path fails
    table = values[: 4 * n_observations].reshape(n_observations, 4)
    rest = values[4 * n_observations :]
    camera_index = _indices(path, table[:, 0], n_cameras, "camera")
    point_index = _indices(path, table[:, 1], n_points, "point")
    observed = table[:, 2:4].copy()
    cameras = rest[: 9 * n_cameras].reshape(n_cameras, 9)
    points = rest[9 * n_cameras :].reshape(n_points, 3)
    for name, array in (("observation", observed), ("camera", cameras), ("point", points)):
        bad = np.flatnonzero(~np.all(np.isfinite(array), axis=1))
        if bad.size:
            raise BalFormatError(f"{path}: {name} {bad[0]} has a non-finite value")
    return BalProblem(cameras, points, camera_index, point_index, observed, path)


def _read_text(path: pathlib.Path) -> str:
    """The file's text, decompressed by suffix (.bz2, .gz)."""
    opener = {".bz2": bz2.open, ".gz": gzip.open}.get(path.suffix, open)
    try:
        with opener(path, "rt", encoding="ascii") as stream:
            return stream.read()
    except (OSError, EOFError, UnicodeDecodeError) as error:
        if isinstance(error, FileNotFoundError):
            raise
        raise BalFormatError(f"{path}: cannot be read: {error}") from error


def _header(path: pathlib.Path, text: str, tokens: list[str]) -> tuple[int, int, int]:
    """(n_cameras, n_points, n_observations) from the first line."""
    first = text.lstrip().split("\n", 1)[0].split() if tokens else []
    line = text[: len(text) - len(text.lstrip())].count("\n") + 1
    if len(first) != 3:
        raise BalFormatError(
            f"{path}:{line}: the header must be 'n_cameras n_points n_observations'"
            f" (three integers), found {' '.join(first)!r}"
        )
    try:
        counts = tuple(int(token) for token in first)
    except ValueError:
        raise BalFormatError(
            f"{path}:{line}: the header must hold three integers, found {' '.join(first)!r}"
        ) from None
    if min(counts) < 0:
        raise BalFormatError(f"{path}:{line}: negative count in the header {counts}")
    if min(counts) == 0:
        raise BalFormatError(
            f"{path}:{line}: the header announces {counts[0]} cameras, {counts[1]} points and"
            f" {counts[2]} observations: a problem needs at least one of each"
        )
    return counts


def _indices(path: pathlib.Path, column: np.ndarray, size: int, what: str) -> np.ndarray:
    """Integer indices from a float column, each in [0, size), else an error naming its line."""
    in_range = np.isfinite(column) & (column >= 0) & (column < size)  # before the cast
    index = np.where(in_range, column, 0).astype(np.int64)
    bad = np.flatnonzero(~in_range | (index != column))
    if bad.size:
        k = int(bad[0])
        raise BalFormatError(
            f"{path}: observation {k} (line {_observation_line(path, k)}): {what} index"
            f" {column[k]:g} is not an integer in [0, {size})"
        )
    return index


def _observation_line(path: pathlib.Path, k: int) -> int:
    """The line number (1-based) of observation `k`, counting non-blank lines."""
    nonblank = 0
    for number, line in enumerate(_read_text(path).splitlines(), start=1):
        if line.strip():
            if nonblank == k + 1:
                return number
            nonblank += 1
    return -1


def _diagnose(path: pathlib.Path, text: str, counts: tuple[int, int, int]) -> None:
    """Walk the file line by line and raise a `BalFormatError` at the first problem."""
    n_cameras, n_points, n_observations = counts
    lines = [(n, line.split()) for n, line in enumerate(text.splitlines(), start=1)]
    lines = [(n, fields) for n, fields in lines if fields][1:]  # drop blanks and header
    for k in range(n_observations):
        if k >= len(lines):
            raise BalFormatError(
                f"{path}: truncated: the header announces {n_observations} observations,"
                f" the file ends after {k}"
            )
        number, fields = lines[k]
        if len(fields) != 4:
            raise BalFormatError(
                f"{path}:{number}: observation {k} must be 'camera point x y', found"
                f" {len(fields)} fields"
            )
        _floats(path, number, fields, f"observation {k}")
    n_values = 9 * n_cameras + 3 * n_points
    seen = 0
    for number, fields in lines[n_observations:]:
        if seen >= n_values:
            raise BalFormatError(
                f"{path}:{number}: unexpected content after the {n_cameras} cameras and"
                f" {n_points} points announced by the header"
            )
        _floats(path, number, fields, _parameter_name(seen, n_cameras))
        seen += len(fields)
    if seen != n_values:
        raise BalFormatError(
            f"{path}: truncated: expected {n_values} parameter values (9 x {n_cameras} cameras"
            f" + 3 x {n_points} points) after the observations, found {seen}"
            f" (missing from {_parameter_name(seen, n_cameras)} on)"
        )
    raise BalFormatError(f"{path}: malformed file")  # pragma: no cover


def _floats(path: pathlib.Path, number: int, fields: list[str], what: str) -> None:
    for field in fields:
        try:
            float(field)
        except ValueError:
            raise BalFormatError(f"{path}:{number}: {what}: {field!r} is not a number") from None


def _parameter_name(position: int, n_cameras: int) -> str:
    """Which value the `position`-th parameter value is, e.g. 'camera 3 f' or 'point 10 Y'."""
    if position < 9 * n_cameras:
        return f"camera {position // 9} {CAMERA_PARAMETER_NAMES[position % 9]}"
    position -= 9 * n_cameras
    return f"point {position // 3} {'XYZ'[position % 3]}"
