"""DBAT's comma-separated text tables, read by the format string a script gives them.

A format names the columns in order, e.g. `id,label,x,y,z,sx,sy,sz` (whitespace ignored);
`#` starts a comment line, blank lines are skipped (DBAT's loadctrlpts, loadimagepts,
loadimagetable and loadeotable). Every problem names the file and line. Plain Python.
"""

import dataclasses
import math
import pathlib

CONTROL_PARTS = ("id", "label", "dummy", "x", "y", "z", "sx", "sy", "sz", "sxy", "sxyz")
IMAGE_PARTS = ("id", "label", "path", "dummy")
MARK_PARTS = ("id", "im", "ignored", "x", "y", "sx", "sy", "sxy")
EO_PARTS = ("id", "ignored", "x", "y", "z", "sx", "sy", "sz", "sxy", "sxyz",
            "omega", "phi", "kappa", "so", "sp", "sk")
ANGLE_UNITS = {"radian": math.degrees(1.0), "degrees": 1.0, "gon": 0.9}  # -> degrees


@dataclasses.dataclass(frozen=True)
class ControlPoint:
    """A DBAT control (or check) point: label, coordinates and σ per coordinate (0: fixed)."""

    id: str
    label: str
    xyz: tuple[float, float, float]
    sigma: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class MarkPoint:
    """One DBAT image measurement, in DBAT's pixels (corner origin, row down), σ per axis."""

    image: str
    point: str
    col: float
    row: float
    sigma: tuple[float, float]


@dataclasses.dataclass(frozen=True)
class PriorEo:
    """A DBAT prior exterior orientation: station (object units) and omega, phi, kappa
    (degrees; None when the file gives no angles), σ of each (0 where not given)."""

    image: str
    station: tuple[float, float, float]
    angles: tuple[float, float, float] | None
    sigma: tuple[float, float, float, float, float, float]


def parse_format(text: str | None, known: tuple[str, ...], where: str) -> list[str]:
    """The column names of a format string, each one of `known`."""
    if not text:
        raise ValueError(f"{where}: missing format attribute")
    parts = [part.strip() for part in text.split(",")]
    unknown = [part for part in parts if part not in known]
    if unknown:
        raise ValueError(f"{where}: format {text!r}: unknown column {unknown[0]!r}; known: "
                         f"{','.join(known)}")
    return parts


def read_rows(path: pathlib.Path, parts: list[str]) -> list[tuple[int, dict[str, str]]]:
    """(line number, {column: text}) of every data line of `path`."""
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    rows = []
    for number, line in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        values = [value.strip() for value in text.split(",")]
        if len(values) != len(parts):
            raise ValueError(f"{path}:{number}: expected {len(parts)} comma-separated fields "
                             f"({','.join(parts)}), got {len(values)}")
        rows.append((number, dict(zip(parts, values))))
    return rows


def number(row: dict[str, str], part: str, path: pathlib.Path, line: int) -> float:
    try:
        value = float(row[part])
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"{path}:{line}: {part}: expected a number, got {row[part]!r}")
    return value


def identifier(row: dict[str, str], part: str, path: pathlib.Path, line: int) -> str:
    """An integer ID (DBAT's are integers) as jaxba's string ID: `007` -> `7`."""
    try:
        return str(int(row[part]))
    except ValueError:
        raise ValueError(f"{path}:{line}: {part}: expected an integer ID, got {row[part]!r}")


def _sigmas(row, parts, names, path, line) -> list[float]:
    """σ of the coordinates `names` (e.g. x y z) from columns s<name>, sxy, sxyz; 0 if none."""
    sigma = [0.0] * len(names)
    for part in parts:
        if part in ("sxy", "sxyz") and names[0] == "x":
            cover = names[:len(part) - 1]
        elif part.startswith("s") and part[1:] in names:
            cover = [part[1:]]
        else:
            continue
        for name in cover:
            sigma[names.index(name)] = number(row, part, path, line)
    if any(s < 0 for s in sigma):
        raise ValueError(f"{path}:{line}: a negative standard deviation")
    return sigma


def read_control_points(path: pathlib.Path, fmt: str) -> dict[str, ControlPoint]:
    """Control (or check) points of `path` in DBAT's format `fmt` (`CONTROL_PARTS`); σ 0
    (fixed, DBAT's default) where the format gives none."""
    path = pathlib.Path(path)
    parts = parse_format(fmt, CONTROL_PARTS, str(path))
    missing = [p for p in ("id", "x", "y", "z") if p not in parts]
    if missing:
        raise ValueError(f"{path}: format {fmt!r} has no {missing[0]!r} column")
    points = {}
    for line, row in read_rows(path, parts):
        pid = identifier(row, "id", path, line)
        if pid in points:
            raise ValueError(f"{path}:{line}: point {pid} given twice")
        xyz = tuple(number(row, axis, path, line) for axis in "xyz")
        sigma = tuple(_sigmas(row, parts, ["x", "y", "z"], path, line))
        points[pid] = ControlPoint(pid, row.get("label", ""), xyz, sigma)
    return points


def read_images(path: pathlib.Path, fmt: str) -> dict[str, str]:
    """DBAT image table -> {DBAT image id: jaxba image id}: the label, else the path's file
    stem; images without an `id` column are numbered 1, 2, ... in file order."""
    path = pathlib.Path(path)
    parts = parse_format(fmt, IMAGE_PARTS, str(path))
    if "label" not in parts and "path" not in parts:
        raise ValueError(f"{path}: format {fmt!r} names the images by neither label nor path")
    images = {}
    for k, (line, row) in enumerate(read_rows(path, parts), start=1):
        dbat_id = identifier(row, "id", path, line) if "id" in parts else str(k)
        name = row.get("label") or pathlib.PurePosixPath(row["path"].replace("\\", "/")).stem
        if dbat_id in images or name in images.values() or not name or " " in name:
            raise ValueError(f"{path}:{line}: image {dbat_id} ({name!r}): a repeated or "
                             "empty ID or name, or one with a space")
        images[dbat_id] = name
    return images


def read_mark_points(path: pathlib.Path, fmt: str = "im,id,x,y,sxy",
                     sigma: dict[str, float] | None = None) -> list[MarkPoint]:
    """DBAT mark points (pixels, corner origin) in file order; `sigma`: the file element's
    `sxy`, `sx`, `sy` attributes, which replace the columns' σ (as in DBAT)."""
    path = pathlib.Path(path)
    parts = parse_format(fmt, MARK_PARTS, str(path))
    missing = [p for p in ("id", "im", "x", "y") if p not in parts]
    if missing:
        raise ValueError(f"{path}: format {fmt!r} has no {missing[0]!r} column")
    override = sigma or {}
    marks = []
    for line, row in read_rows(path, parts):
        s = _sigmas(row, parts, ["x", "y"], path, line)
        s = [override.get("sxy", s[0]), override.get("sxy", s[1])]
        s = [override.get("sx", s[0]), override.get("sy", s[1])]
        if min(s) <= 0:
            raise ValueError(f"{path}:{line}: no standard deviation > 0: give sxy (or sx, sy)"
                             " in the format or as an attribute of <file>")
        marks.append(MarkPoint(identifier(row, "im", path, line),
                               identifier(row, "id", path, line),
                               number(row, "x", path, line), number(row, "y", path, line),
                               (s[0], s[1])))
    return marks


def read_prior_eo(path: pathlib.Path, fmt: str, units: str | None) -> dict[str, PriorEo]:
    """DBAT prior EO table; angles (and their σ) in `units` ("radian", "degrees", "gon",
    required when the format has angles) are returned in degrees."""
    path = pathlib.Path(path)
    parts = parse_format(fmt, EO_PARTS, str(path))
    missing = [p for p in ("id", "x", "y", "z") if p not in parts]
    if missing:
        raise ValueError(f"{path}: format {fmt!r} has no {missing[0]!r} column")
    angles = [p for p in ("omega", "phi", "kappa") if p in parts]
    if angles and len(angles) != 3:
        raise ValueError(f"{path}: format {fmt!r}: give all of omega, phi, kappa or none")
    if angles and units not in ANGLE_UNITS:
        raise ValueError(f"{path}: the format has angles: the units attribute must be one of "
                         f"{', '.join(ANGLE_UNITS)}, got {units!r}")
    scale = ANGLE_UNITS.get(units, 1.0)
    eos = {}
    for line, row in read_rows(path, parts):
        image = identifier(row, "id", path, line)
        station = tuple(number(row, axis, path, line) for axis in "xyz")
        opk = tuple(scale * number(row, a, path, line) for a in angles) if angles else None
        s = _sigmas(row, parts, ["x", "y", "z"], path, line)
        s += [scale * v for v in _sigmas(row, parts, ["o", "p", "k"], path, line)]
        eos[image] = PriorEo(image, station, opk, tuple(s))
    return eos
