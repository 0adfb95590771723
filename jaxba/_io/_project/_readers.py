"""Read a project file and its tables (docs/project-files.md) into the records of `_spec.py`.

Plain Python, no jax. Every problem with the input raises `ProjectError` naming the file and,
where there is one, the line and the column or key. Values are not converted: angles stay in
decimal degrees and image coordinates (and their σ) in the project's `image_units`.

A σ read from a text table is `None` (free / no observation), `0.0` (fixed) or a positive
number (weighted). Image points have no fixed state: their σ pair is `None` (use the project's
`image_sigma`) or two positive numbers.

Missing approximations are read as such (`_spec.py`): `-` in all six EOP columns of an image
(`ImageSpec.eop` None; its σ columns must then be `-`), and a point measured in the image
points but absent from the points table (a tie point, `PointSpec.xyz` None, appended to the
points in the order of first measurement).
"""

import collections
import dataclasses
import math
import os
import pathlib
import tomllib
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from ..._gc import paused_gc
from ..._models._cameras._names import (
    CAMERA_CONSTANT_NAMES,
    CAMERA_PARAMETER_NAMES,
    PIXEL_MODELS,
    PRINCIPAL_DISTANCES,
    RAY_REFRACTION_PARAMETER_NAMES,
    lens_model,
)
from ._errors import ProjectError
from ._rigs import read_frames, read_platform_mount, read_rigs
from ._spec import (
    AdjustmentSettings,
    CameraSpec,
    DistanceSpec,
    ImagePointSpec,
    ImagePointTable,
    ImageSpec,
    PointSpec,
    ProjectSpec,
)
from ._ties import TIE_KEYS, expand_per_image, read_camera_ties, resolve_ties

IMAGE_UNITS = ("mm", "pixel")
IMAGE_UNIT_ALIASES = {"pixels": "pixel"}  # also accepted for [project] image_units
DEFAULT_CAMERA_MODEL = "smac"

_PROJECT_TABLES = ("project", "files", "adjustment")
_PROJECT_KEYS = ("name", "image_units")
_REQUIRED_FILES = ("cameras", "images", "image_points", "points")
_OPTIONAL_FILES = ("distances", "rigs", "frames")
_CAMERA_KEYS = ("model", "free", "sigma", "pixel_size", "sensor", "refraction", "mount",
                *TIE_KEYS)
# `[ID.refraction]` of a flat port: its parameters, but the port normal as one 3-vector; the
# indices > 0, distance and thickness ≥ 0; n_air 1 unless given, the normal the optical axis.
_PORT_KEYS = ("model", "distance", "thickness", "n_air", "n_glass", "n_medium", "normal",
              "free", "sigma")
_PORT_NORMAL = ("normal_x", "normal_y")
_PORT_DEFAULTS = {"n_air": 1.0, "normal": [0.0, 0.0, -1.0]}
_PORT_INDICES = ("n_air", "n_glass", "n_medium")
_POSITIVE_SETTINGS = frozenset({
    "sigma0", "image_sigma", "max_iterations", "object_unit_km", "snooping_alpha", "robust_scale",
})
_SETTING_CHOICES = {
    "robust": ("none", "huber", "cauchy"),
    "datum": ("control", "free", "dependent"),
    "solver": ("auto", "dense", "schur"),
}
_NONNEGATIVE_SETTINGS = frozenset({"rtol", "atol"})
# The largest magnitude of a number in a text table (coordinates, angles, image points,
# distances): anything larger is a typo or a unit mistake, and would overflow the model
# (a squared 1e200 is inf) instead of being reported where it was written.
MAX_MAGNITUDE = 1e12

_IMAGE_COLUMNS = (
    *("image_id", "camera_id", "X0", "Y0", "Z0", "omega", "phi", "kappa"),
    *("sX0", "sY0", "sZ0", "somega", "sphi", "skappa"),
)
_POINT_COLUMNS = ("point_id", "X", "Y", "Z", "sX", "sY", "sZ")
_IMAGE_POINT_COLUMNS = ("image_id", "point_id", "x", "y", "sx", "sy")
_DISTANCE_COLUMNS = ("point_a", "point_b", "distance", "sigma")
_FRAME_COLUMNS = ("image_id", "frame_id")


def read_project(path: str | os.PathLike) -> ProjectSpec:
    """Read and validate a project file and every table it names.

    **Arguments:**

    - `path`: the project TOML file; the paths in its `[files]` table are relative to it.

    **Returns:** a `ProjectSpec`; its `input_files` lists every file read (resolved).

    **Raises:** `ProjectError` for any missing file, malformed entry or inconsistency.
    """
    with paused_gc():  # the tables' rows are many small lists, none in a cycle
        return _read_project(pathlib.Path(path))


def _read_project(path: pathlib.Path) -> ProjectSpec:
    """`read_project`."""
    if not path.is_file():
        raise ProjectError(f"{path}: no such project file")
    name = path.name
    document = _load_toml(path, name)
    _check_keys(document, _PROJECT_TABLES, f"{name}: top level")
    project = _subtable(document, "project", name)
    adjustment = _subtable(document, "adjustment", name)
    if "files" not in document:
        raise ProjectError(f"{name}: missing table [files]")
    files = _read_files_table(_subtable(document, "files", name), path.parent, name)

    project_name, image_units = _read_project_table(project, name, path.stem)
    settings = _read_settings(adjustment, f"{name}: [adjustment]")
    cameras = _read_cameras(files["cameras"], image_units, name)
    images = _read_images(files["images"], cameras, files["cameras"].name)
    cameras, images = expand_per_image(cameras, images, files["cameras"].name)
    points = _read_points(files["points"])
    image_points = _read_image_points(files["image_points"], images, files)
    points.update(_missing_points(image_points, points))
    distances = []
    if "distances" in files:
        distances = _read_distances(files["distances"], points, files["points"].name)
    _check_consistency(images, points, image_points, distances, files)
    rigs, frames = _read_rigs(files, cameras, images)

    inputs = dict.fromkeys([path.resolve(), *(file.path for file in files.values())])
    return ProjectSpec(
        path=path.resolve(),
        name=project_name,
        image_units=image_units,
        settings=settings,
        cameras=cameras,
        images=images,
        points=points,
        image_points=image_points,
        distances=distances,
        input_files=tuple(inputs),
        files={key: file.path for key, file in files.items()},
        file_names={key: file.name for key, file in files.items()},
        rigs=rigs,
        frames=frames,
    )


def _read_rigs(files: dict, cameras, images) -> tuple[dict, dict[str, str]]:
    """rigs.toml and the frames table (`_rigs.py`), each optional, the frames only with rigs."""
    if "frames" in files and "rigs" not in files:
        raise ProjectError(f"{files['frames'].name}: frames need rigs (the [files] table has "
                           "no rigs)")
    if "rigs" not in files:
        return {}, {}
    rigs = read_rigs(_load_toml(files["rigs"].path, files["rigs"].name), files["rigs"].name,
                     cameras)
    frames = {}
    if "frames" in files:
        frames = read_frames(_rows(files["frames"], _FRAME_COLUMNS, 2), images, rigs)
    return rigs, frames


# --- the project file -------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _File:
    """A table file: its resolved path and the name used in messages (as written in [files])."""

    path: pathlib.Path
    name: str


def _read_project_table(table: dict, where: str, default_name: str) -> tuple[str, str]:
    """`[project]`: the name (default: the file stem) and the image units."""
    _check_keys(table, _PROJECT_KEYS, f"{where}: [project]")
    name = _toml_str(table.get("name", default_name), f"{where}: [project] name")
    if not name.strip() or "/" in name or "\\" in name:
        raise ProjectError(
            f"{where}: [project] name: expected a file name without '/' or '\\', got {name!r}"
        )
    units = table.get("image_units", "mm")
    units = IMAGE_UNIT_ALIASES.get(units, units)
    if units not in IMAGE_UNITS:
        raise ProjectError(
            f"{where}: [project] image_units: expected one of "
            f"{', '.join(map(repr, IMAGE_UNITS))}, got {units!r}"
        )
    return name, units


def _read_files_table(table: dict, base: pathlib.Path, where: str) -> dict[str, _File]:
    """`[files]`: resolve every path relative to the project file and check it exists."""
    _check_keys(table, _REQUIRED_FILES + _OPTIONAL_FILES, f"{where}: [files]")
    files = {}
    for key in _REQUIRED_FILES + _OPTIONAL_FILES:
        if key not in table:
            if key in _REQUIRED_FILES:
                raise ProjectError(
                    f"{where}: [files] {key}: missing; required keys: {', '.join(_REQUIRED_FILES)}"
                )
            continue
        value = _toml_str(table[key], f"{where}: [files] {key}")
        resolved = (base / value).resolve()
        if not resolved.is_file():
            raise ProjectError(f"{where}: [files] {key}: no such file: {resolved}")
        files[key] = _File(resolved, value)
    return files


def _read_settings(table: dict, where: str) -> AdjustmentSettings:
    """`[adjustment]`: one key per `AdjustmentSettings` field, type-checked by the field's type."""
    fields = {field.name: field for field in dataclasses.fields(AdjustmentSettings)}
    _check_keys(table, tuple(fields), where)
    values = {}
    for key, value in table.items():
        kind, key_where = fields[key].type, f"{where} {key}"
        kind = {"bool": bool, "int": int, "float": float, "str": str}.get(kind, kind)  # type: ignore
        if kind == tuple[str, ...]:
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ProjectError(f"{key_where}: expected a list of strings, got {value!r}")
            values[key] = tuple(value)
        elif kind is bool:
            values[key] = _toml_bool(value, key_where)
        elif kind is int:
            values[key] = _toml_int(value, key_where, positive=key in _POSITIVE_SETTINGS)
        elif kind is float:
            values[key] = _toml_float(
                value,
                key_where,
                positive=key in _POSITIVE_SETTINGS,
                nonnegative=key in _NONNEGATIVE_SETTINGS,
            )
        elif kind is str:
            values[key] = _toml_str(value, key_where)
            choices = _SETTING_CHOICES.get(key)
            if choices is not None and values[key] not in choices:
                raise ProjectError(f"{key_where}: expected one of {choices}, got {values[key]!r}")
        else:
            raise TypeError(f"no reader for AdjustmentSettings.{key} of type {kind!r}")
    return AdjustmentSettings(**values)


# --- cameras.toml -----------------------------------------------------------------------


def _read_cameras(file: _File, image_units: str, project: str) -> dict[str, CameraSpec]:
    """cameras.toml: one table per camera id."""
    document = _load_toml(file.path, file.name)
    cameras = {}
    for camera_id, table in document.items():
        if not isinstance(table, dict):
            raise ProjectError(
                f"{file.name}: {camera_id}: expected a table [{camera_id}] per camera, "
                f"got {table!r}"
            )
        camera = _read_camera(camera_id, table, file.name)
        if image_units == "pixel":
            # A pixel model computes pixels itself: it needs no pixel size.
            needed = ("sensor",) if camera.model in PIXEL_MODELS else ("pixel_size", "sensor")
            missing = [key for key in needed if table.get(key) is None]
            if missing:
                raise ProjectError(
                    f"{file.name}: [{camera_id}] {missing[0]}: missing; {project} has "
                    f'image_units = "pixel", so model {camera.model!r} needs '
                    + " and ".join(needed)
                )
        cameras[camera_id] = camera
    return resolve_ties(cameras, document, file.name)


def _read_camera(camera_id: str, table: dict, file: str) -> CameraSpec:
    """One camera table: model, parameter values, free list, `[ID.sigma]`, pixel size, sensor,
    and the ray refraction `[ID.refraction]`, whose parameters join the camera's."""
    where = f"{file}: [{camera_id}]"
    model = table.get("model", DEFAULT_CAMERA_MODEL)
    names, constant_names = _model_names(model, where)
    constants = _read_constants(table, model, names, constant_names, where)
    _check_keys(table, _CAMERA_KEYS + names + tuple(constants), where)
    values = {name: _toml_float(table.get(name, 0.0), f"{where} {name}") for name in names}
    for name in PRINCIPAL_DISTANCES.get(model, ()):
        if values[name] <= 0:
            raise ProjectError(
                f"{where} {name}: the principal distance (focal length) of model {model!r}"
                f" must be > 0, got {table.get(name, 0.0)!r}"
                + ("" if name in table else " (not given: it defaults to 0)")
            )

    free = table.get("free", [])
    if not isinstance(free, list) or not all(isinstance(name, str) for name in free):
        raise ProjectError(f"{where} free: expected a list of parameter names, got {free!r}")
    for name in free:
        if name in constants:
            raise ProjectError(f"{where} free: {name!r} is a constant of model {model!r}, "
                               "not an unknown; it cannot be free")
        if name not in names:
            raise ProjectError(
                f"{where} free: unknown parameter {name!r} for model {model!r}; "
                f"allowed: {', '.join(names)}"
            )

    sigma_where = f"{file}: [{camera_id}.sigma]"
    sigma_table = table.get("sigma", {})
    if not isinstance(sigma_table, dict):
        raise ProjectError(f"{sigma_where}: expected a table of prior σ, got {sigma_table!r}")
    for name in constants:
        if name in sigma_table:
            raise ProjectError(f"{sigma_where} {name}: {name!r} is a constant of model "
                               f"{model!r}, not an unknown; it has no prior σ")
    _check_keys(sigma_table, names, sigma_where)
    sigma = {
        name: _toml_float(value, f"{sigma_where} {name}", positive=True)
        for name, value in sigma_table.items()
    }
    for name in free:
        if name in sigma:
            raise ProjectError(
                f"{sigma_where} {name}: {name!r} is also in free; a parameter is either "
                "free or weighted, not both"
            )

    refraction = None
    if "refraction" in table:
        refraction, port = _read_refraction(table["refraction"], f"{file}: [{camera_id}")
        clash = sorted(set(port.values) & set(names))
        if clash:
            raise ProjectError(f"{where} refraction: model {model!r} has a parameter {clash[0]!r}"
                               f" as the {refraction} refraction has: one of them must be renamed")
        values.update(port.values)
        free = [*free, *port.free]
        sigma.update(port.sigma)

    ties, per_image = read_camera_ties(table, camera_id, where)
    return CameraSpec(
        id=camera_id,
        ties=ties,
        per_image=per_image,
        model=model,
        values=values,
        free=frozenset(free),
        sigma=sigma,
        refraction=refraction,
        pixel_size=_toml_pair(table.get("pixel_size"), f"{where} pixel_size", _toml_float),
        sensor=_toml_pair(table.get("sensor"), f"{where} sensor", _toml_int),
        constants=constants,
        mount=(read_platform_mount(camera_id, table["mount"], f"{file}: [{camera_id}.mount]")
               if "mount" in table else None),
    )


def _model_names(model: Any, where: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The parameter and constant names of the camera model `model`: a built-in one (no jax
    loaded), or a user model ("package.module:ClassName", an entry point of "jaxba.cameras"),
    imported and checked here."""
    if not isinstance(model, str):
        raise ProjectError(f"{where} model: expected a string, got {model!r}")
    if model in CAMERA_PARAMETER_NAMES:
        return CAMERA_PARAMETER_NAMES[model], CAMERA_CONSTANT_NAMES.get(model, ())
    if lens_model(model) != model:
        raise ProjectError(
            f"{where} model: {model!r}: give the camera model alone, model ="
            f' "{lens_model(model)}", and the refraction in a table [ID.refraction]')
    from ..._models._cameras._registry import CAMERA_MODELS  # a user model: jax needed
    from ..._models._cameras._user import CameraModelError

    try:
        camera = CAMERA_MODELS[model]
    except CameraModelError as error:
        raise ProjectError(f"{where} model: {error}") from error
    reserved = sorted(set(_CAMERA_KEYS) & {*camera.parameter_names, *camera.constant_names})
    if reserved:
        raise ProjectError(f"{where} model: {model!r} names a parameter {reserved[0]!r}, a key"
                           " that cameras.toml uses for something else: rename it")
    return camera.parameter_names, camera.constant_names


@dataclasses.dataclass(frozen=True)
class _Port:
    """The parameters of a camera's ray refraction, as they join the camera's."""

    values: dict[str, float]
    free: list[str]
    sigma: dict[str, float]


def _read_refraction(table: Any, camera: str) -> tuple[str, _Port]:
    """`[ID.refraction]` of `camera` ("cameras.toml: [ID"): the ray refraction model (only
    "flat_port") and its parameters, the normal as (normal_x, normal_y) of the unit normal
    turned towards the object (z < 0)."""
    where, sigma_where = f"{camera}.refraction]", f"{camera}.refraction.sigma]"
    if not isinstance(table, dict):
        raise ProjectError(f"{where}: expected a table of the refraction model, got {table!r}")
    model = table.get("model")
    if model not in RAY_REFRACTION_PARAMETER_NAMES:
        raise ProjectError(f"{where} model: expected one of "
                           f"{', '.join(map(repr, RAY_REFRACTION_PARAMETER_NAMES))}, got {model!r}")
    _check_keys(table, _PORT_KEYS, where)
    given = {**_PORT_DEFAULTS, **table}
    values = {}
    for name in ("distance", "thickness", *_PORT_INDICES):
        if name not in given:
            raise ProjectError(f"{where} {name}: missing; a flat port needs distance, thickness,"
                               " n_glass and n_medium (n_air is 1 and the normal the optical"
                               " axis unless given)")
        values[name] = _toml_float(given[name], f"{where} {name}",
                                   positive=name in _PORT_INDICES, nonnegative=True)
    values.update(zip(_PORT_NORMAL, _port_normal(given["normal"], f"{where} normal")))
    free = table.get("free", [])
    if not isinstance(free, list) or not all(isinstance(name, str) for name in free):
        raise ProjectError(f"{where} free: expected a list of parameter names, got {free!r}")
    sigma_table = table.get("sigma", {})
    if not isinstance(sigma_table, dict):
        raise ProjectError(f"{sigma_where}: expected a table of prior σ, got {sigma_table!r}")
    allowed = _PORT_KEYS[1:-2]
    for name in free:
        if name not in allowed:
            raise ProjectError(f"{where} free: unknown parameter {name!r}; allowed: "
                               f"{', '.join(allowed)}")
        if name in sigma_table:
            raise ProjectError(f"{sigma_where} {name}: {name!r} is also in free; a parameter is"
                               " either free or weighted, not both")
    _check_keys(sigma_table, allowed, sigma_where)
    sigma = {name: _toml_float(value, f"{sigma_where} {name}", positive=True)
             for name, value in sigma_table.items()}

    def unknowns(name: str) -> tuple[str, ...]:
        return _PORT_NORMAL if name == "normal" else (name,)

    return model, _Port(
        values, [n for name in free for n in unknowns(name)],
        {n: value for name, value in sigma.items() for n in unknowns(name)})


def _port_normal(value: Any, where: str) -> tuple[float, float]:
    """(x, y) of the unit port normal given as a 3-vector (any length, either sense), turned
    towards the object (z < 0); a normal across the optical axis (z = 0) is refused."""
    if not isinstance(value, list) or len(value) != 3:
        raise ProjectError(f"{where}: expected a list of three numbers, got {value!r}")
    normal = np.array([_toml_float(v, where) for v in value])
    length = float(np.linalg.norm(normal))
    if normal[2] == 0:
        raise ProjectError(f"{where}: {value!r} is not a port normal: it must not be across the"
                           " optical axis (z ≠ 0)")
    normal = -np.sign(normal[2]) * normal / length
    return float(normal[0]), float(normal[1])


def _read_constants(
    table: dict, model: str, names: tuple[str, ...], own: tuple[str, ...], where: str
) -> dict[str, float]:
    """The model's constants `own` (each required, ≥ 0); a constant of another built-in model
    (CAMERA_CONSTANT_NAMES) that is not one of the model's parameters `names` is refused by
    name."""
    for other, constants in CAMERA_CONSTANT_NAMES.items():
        for name in constants:
            if name in table and name not in own and name not in names:
                raise ProjectError(
                    f"{where} {name}: {name} is a constant of model {other!r}; model "
                    f'{model!r} has no {name} (remove it, or set model = "{other}")'
                )
    for name in own:
        if name not in table:
            raise ProjectError(
                f"{where} {name}: missing; model {model!r} needs its constant {name} "
                "(a value of the camera that is not estimated)"
            )
    return {name: _toml_float(table[name], f"{where} {name}", nonnegative=True) for name in own}


# --- text tables ------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Row:
    """One data line of a text table, with number parsing that names file, line and column."""

    file: str
    line: int
    tokens: tuple[str, ...]
    columns: tuple[str, ...]

    def error(self, message: str, column: int | None = None) -> ProjectError:
        """A `ProjectError` located at this line (and column)."""
        field = "" if column is None else f"column {self.columns[column]}: "
        return ProjectError(f"{self.file}:{self.line}: {field}{message}")

    def number(self, column: int, *, positive: bool = False) -> float:
        """A finite number of magnitude at most `MAX_MAGNITUDE` (> 0 with `positive`)."""
        token = self.tokens[column]
        value = _parse_float(token)
        if value is None or (positive and value <= 0):
            expected = "a number > 0" if positive else "a number"
            raise self.error(f"expected {expected}, got {token!r}", column)
        if abs(value) > MAX_MAGNITUDE:
            raise self.error(
                f"{token} is out of range: numbers must be at most 1e12 in"
                " magnitude (a typo or a unit mistake?)", column)
        return value

    def sigma(self, column: int, *, fixed: bool = True) -> float | None:
        """A σ: `-` or an absent column -> None, `0` -> 0.0 (only if `fixed`), or a number > 0."""
        if column >= len(self.tokens) or self.tokens[column] == "-":
            return None
        token = self.tokens[column]
        value = _parse_float(token)
        if value is None or value < 0 or (value == 0 and not fixed):
            expected = "a number, '0' or '-'" if fixed else "a number > 0 or '-'"
            raise self.error(f"expected {expected}, got {token!r}", column)
        return value


def _parse_float(token: str) -> float | None:
    """The finite float a token spells, or None."""
    try:
        value = float(token)
    except ValueError:
        return None
    return value if abs(value) < float("inf") else None  # rejects nan and ±inf


def _lines(file: _File) -> list[str]:
    """The lines of a text table (BOM dropped, any line ending)."""
    try:
        with file.path.open(encoding="utf-8-sig") as stream:
            return stream.read().split("\n")
    except (OSError, UnicodeDecodeError) as error:
        raise ProjectError(f"{file.name}: cannot read {file.path}: {error}") from None


def _token_columns(
    file: _File, columns: tuple[str, ...], n_required: int
) -> tuple[list[tuple[str, ...]], np.ndarray] | None:
    """The fast path of `_rows`: the data lines' tokens as columns (rows with only the
    `n_required` columns padded with "-", no σ), and their line numbers; None when a line has
    another number of columns (`_rows` then says where)."""
    lines = _lines(file)
    for k in [k for k, line in enumerate(lines) if "#" in line]:
        lines[k] = lines[k].split("#", 1)[0]
    tokens = list(map(str.split, lines))
    sizes = np.fromiter(map(len, tokens), dtype=int, count=len(tokens))
    numbers = np.flatnonzero(sizes) + 1
    rows = list(filter(None, tokens))
    sizes = set(np.unique(sizes[sizes > 0]).tolist())
    if not sizes <= {n_required, len(columns)}:
        return None
    if sizes == {n_required}:  # no optional column anywhere: all "-"
        table = list(zip(*rows)) + [("-",) * len(rows)] * (len(columns) - n_required)
    else:
        padding = ["-"] * (len(columns) - n_required)
        table = list(zip(*(row if len(row) == len(columns) else row + padding for row in rows)))
    return table or [()] * len(columns), numbers


def _numbers(tokens: tuple[str, ...]) -> np.ndarray | None:
    """Finite numbers of magnitude at most `MAX_MAGNITUDE` (`_Row.number`), or None."""
    try:
        values = np.array(list(map(float, tokens)), dtype=float)
    except ValueError:
        return None
    return values if np.all(np.abs(values) <= MAX_MAGNITUDE) else None  # NaN fails too


def _sigmas(tokens: tuple[str, ...], *, fixed: bool = True) -> np.ndarray | None:
    """σ as `_Row.sigma` reads them, NaN for "-" (None), or None if one is not valid."""
    if tokens.count("-") == len(tokens):
        return np.full(len(tokens), math.nan)
    try:
        values = np.array([math.nan if t == "-" else float(t) for t in tokens], dtype=float)
    except ValueError:
        return None
    given = np.array([t != "-" for t in tokens], dtype=bool)
    valid = np.isfinite(values) & ((values >= 0) if fixed else (values > 0))
    return values if np.all(valid | ~given) else None


def _rows(file: _File, columns: tuple[str, ...], n_required: int) -> Iterator[_Row]:
    """The data lines of a whitespace-separated table: comments (`#`) and blank lines skipped.

    A line has either `n_required` columns or all `columns`.
    """
    counts = sorted({n_required, len(columns)})
    layout = " ".join(columns[:n_required])
    if n_required < len(columns):
        layout += " [" + " ".join(columns[n_required:]) + "]"
    for number, text in enumerate(_lines(file), start=1):
        tokens = tuple(text.split("#", 1)[0].split())
        if not tokens:
            continue
        if len(tokens) not in counts:
            raise ProjectError(
                f"{file.name}:{number}: expected {' or '.join(map(str, counts))} columns "
                f"({layout}), got {len(tokens)}"
            )
        yield _Row(file.name, number, tokens, columns)


def _add_unique(records: dict, key: Any, record: Any, row: _Row, what: str) -> None:
    """Insert a record, refusing a duplicate key with both line numbers."""
    if key in records:
        raise row.error(f"duplicate {what} (first on line {records[key].line})")
    records[key] = record


def _read_images(
    file: _File, cameras: Mapping[str, CameraSpec], cameras_file: str
) -> dict[str, ImageSpec]:
    """images: `image_id camera_id X0 Y0 Z0 omega phi kappa [sX0 sY0 sZ0 somega sphi skappa]`."""
    images: dict[str, ImageSpec] = {}
    for row in _rows(file, _IMAGE_COLUMNS, 8):
        image_id, camera_id = row.tokens[:2]
        if camera_id not in cameras:
            raise row.error(
                f"unknown camera {camera_id!r} (not in {cameras_file}; "
                f"known: {', '.join(cameras) or 'none'})",
                1,
            )
        eop_sigma = tuple(row.sigma(column) for column in range(8, 14))
        eop = _read_eop(row, eop_sigma)
        image = ImageSpec(image_id, camera_id, eop, eop_sigma, row.line)
        _add_unique(images, image_id, image, row, f"image {image_id!r}")
    if not images:
        raise ProjectError(f"{file.name}: no images")
    return images


def _read_eop(row: _Row, eop_sigma: tuple[float | None, ...]) -> tuple[float, ...] | None:
    """X0 .. kappa of an images row: six numbers, or None for `-` in all six (no
    approximation), which needs `-` (or no) σ columns."""
    tokens = row.tokens[2:8]
    if "-" not in tokens:
        return tuple(row.number(column) for column in range(2, 8))
    if tokens.count("-") != len(tokens):
        odd = next(k for k, token in enumerate(tokens) if (token == "-") != (tokens[0] == "-"))
        column = 2 + odd  # the first column that breaks X0's pattern
        raise row.error(
            "'-' (no approximation) must stand in all six EOP columns X0 .. kappa or in none;"
            " give the six values, or '-' in all six to have them computed", column)
    for k, sigma in enumerate(eop_sigma):
        if sigma is not None:
            state = "fixed" if sigma == 0 else "weighted"
            raise row.error(
                f"the EOPs are '-' (no approximation), but this column makes "
                f"{_IMAGE_COLUMNS[2 + k]} {state}: a fixed or weighted EOP needs its value",
                8 + k)
    return None


def _read_points(file: _File) -> dict[str, PointSpec]:
    """points: `point_id X Y Z [sX sY sZ]`; without σ columns the point is a tie point."""
    points = _read_points_fast(file)
    return points if points is not None else _read_points_by_row(file)


def _read_points_fast(file: _File) -> dict[str, PointSpec] | None:
    """`_read_points` column by column; None where a row needs `_read_points_by_row` (which
    names the problem)."""
    table = _token_columns(file, _POINT_COLUMNS, 4)
    if table is None:
        return None
    (ids, *columns), lines = table
    xyz = [_numbers(column) for column in columns[:3]]
    sigma = [_sigmas(column) for column in columns[3:]]
    if any(c is None for c in xyz + sigma) or len(set(ids)) != len(ids):
        return None
    sigma_lists = [[None if math.isnan(s) else s for s in column.tolist()] for column in sigma]
    return {
        point_id: PointSpec(point_id, xyz_k, sigma_k, line)
        for point_id, xyz_k, sigma_k, line in zip(
            ids, zip(*(c.tolist() for c in xyz)), zip(*sigma_lists), lines.tolist())
    }


def _read_points_by_row(file: _File) -> dict[str, PointSpec]:
    points: dict[str, PointSpec] = {}
    for row in _rows(file, _POINT_COLUMNS, 4):
        point_id = row.tokens[0]
        xyz = tuple(row.number(column) for column in range(1, 4))
        sigma = tuple(row.sigma(column) for column in range(4, 7))
        point = PointSpec(point_id, xyz, sigma, row.line)
        _add_unique(points, point_id, point, row, f"point {point_id!r}")
    return points


def _read_image_points(
    file: _File, images: Mapping[str, ImageSpec], files: Mapping[str, _File]
) -> ImagePointTable:
    """image points: `image_id point_id x y [sx sy]`, σ both given (> 0) or both `-`/absent.
    A point need not be in the points table (`_missing_points`)."""
    table = _read_image_points_fast(file, images)
    if table is not None:
        return table
    return ImagePointTable.from_records(_read_image_points_by_row(file, images, files))


def _missing_points(
    image_points: ImagePointTable, points: Mapping[str, PointSpec]
) -> dict[str, PointSpec]:
    """The measured points absent from the points table: tie points without approximation
    (`xyz` None, free), each at the line of its first measurement, in that order."""
    missing = set(image_points.point) - points.keys()
    first: dict[str, int] = {}
    if missing:
        for point_id, line in zip(image_points.point, image_points.line.tolist()):
            if point_id in missing and point_id not in first:
                first[point_id] = line
    return {point_id: PointSpec(point_id, None, (None, None, None), line)
            for point_id, line in first.items()}


def _read_image_points_fast(
    file: _File, images: Mapping[str, ImageSpec]
) -> ImagePointTable | None:
    """`_read_image_points` column by column; None where a row needs
    `_read_image_points_by_row` (which names the problem)."""
    table = _token_columns(file, _IMAGE_POINT_COLUMNS, 4)
    if table is None:
        return None
    (image, point, *columns), lines = table
    xy = [_numbers(column) for column in columns[:2]]
    sigma = [_sigmas(column, fixed=False) for column in columns[2:]]
    if any(c is None for c in xy + sigma):
        return None
    if np.any(np.isnan(sigma[0]) != np.isnan(sigma[1])):
        return None
    if not set(image) <= images.keys():
        return None
    if len(set(zip(image, point))) != len(image):
        return None
    return ImagePointTable(list(image), list(point), np.column_stack(xy).reshape(-1, 2),
                           np.column_stack(sigma).reshape(-1, 2), lines)


def _read_image_points_by_row(
    file: _File, images: Mapping[str, ImageSpec], files: Mapping[str, _File]
) -> list[ImagePointSpec]:
    observations: list[ImagePointSpec] = []
    first_line: dict[tuple[str, str], ImagePointSpec] = {}
    for row in _rows(file, _IMAGE_POINT_COLUMNS, 4):
        image_id, point_id = row.tokens[:2]
        xy = (row.number(2), row.number(3))
        sx, sy = row.sigma(4, fixed=False), row.sigma(5, fixed=False)
        if (sx is None) != (sy is None):
            raise row.error("give both sx and sy, or '-' for both", 4 if sx is None else 5)
        if image_id not in images:
            raise row.error(f"unknown image {image_id!r} (not in {files['images'].name})", 0)
        observation = ImagePointSpec(
            image_id, point_id, xy, None if sx is None else (sx, sy), row.line
        )
        what = f"measurement of point {point_id!r} in image {image_id!r}"
        _add_unique(first_line, (image_id, point_id), observation, row, what)
        observations.append(observation)
    return observations


def _read_distances(
    file: _File, points: Mapping[str, PointSpec], points_file: str
) -> list[DistanceSpec]:
    """distances: `point_a point_b distance sigma`, both > 0, two different known points."""
    distances = []
    for row in _rows(file, _DISTANCE_COLUMNS, 4):
        a, b = row.tokens[:2]
        distance = row.number(2, positive=True)
        sigma = row.number(3, positive=True)
        for column, point_id in ((0, a), (1, b)):
            if point_id not in points:
                raise row.error(f"unknown point {point_id!r} (not in {points_file})", column)
        if a == b:
            raise row.error(f"a distance needs two different points, got {a!r} twice", 1)
        distances.append(DistanceSpec(a, b, distance, sigma, row.line))
    return distances


def _check_consistency(
    images: Mapping[str, ImageSpec],
    points: Mapping[str, PointSpec],
    image_points: ImagePointTable,
    distances: list[DistanceSpec],
    files: Mapping[str, _File],
) -> None:
    """Every image is measured; every used point with a free coordinate is in ≥ 2 images.

    A point used by nothing is allowed (and kept); so is a camera used by no image.
    """
    counts = collections.Counter(image_points.point)
    measured = set(image_points.image)
    for image in images.values():
        if image.id not in measured:
            raise ProjectError(
                f"{files['images'].name}:{image.line}: image {image.id!r} has no measurements "
                f"in {files['image_points'].name}"
            )

    first_distance: dict[str, DistanceSpec] = {}
    for distance in distances:
        first_distance.setdefault(distance.a, distance)
        first_distance.setdefault(distance.b, distance)
    for point in points.values():
        seen = counts.get(point.id, 0)
        if seen >= 2 or None not in point.sigma:
            continue
        where = f"{files['points'].name}:{point.line}"
        if seen:
            image = image_points.image[image_points.point.index(point.id)]
            if point.xyz is None:
                raise ProjectError(
                    f"{files['image_points'].name}:{point.line}: point {point.id!r} is "
                    f"measured in only 1 image ({image}) and is not in "
                    f"{files['points'].name}: a tie point needs 2 images or more"
                )
            raise ProjectError(
                f"{where}: point {point.id!r} is measured in only 1 image ({image}) "
                "but has free coordinates"
            )
        if point.id in first_distance:
            raise ProjectError(
                f"{where}: point {point.id!r} is measured in no image but has free "
                f"coordinates; it is used by {files['distances'].name}:"
                f"{first_distance[point.id].line}"
            )


# --- TOML helpers -----------------------------------------------------------------------


def _load_toml(path: pathlib.Path, name: str) -> dict:
    """Parse a TOML file, turning syntax errors into `ProjectError`."""
    try:
        with path.open("rb") as stream:
            return tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise ProjectError(f"{name}: invalid TOML: {error}") from None
    except UnicodeDecodeError as error:
        line = error.object[: error.start].count(b"\n") + 1
        raise ProjectError(
            f"{name}:{line}: not UTF-8 text (byte 0x{error.object[error.start]:02x}); save"
            " the file as UTF-8"
        ) from None
    except OSError as error:
        raise ProjectError(f"{name}: cannot read {path}: {error}") from None


def _subtable(document: dict, key: str, where: str) -> dict:
    """An optional `[key]` table (empty if absent)."""
    table = document.get(key, {})
    if not isinstance(table, dict):
        raise ProjectError(f"{where}: {key}: expected a table [{key}], got {table!r}")
    return table


def _check_keys(table: Mapping, allowed: tuple[str, ...], where: str) -> None:
    """Refuse keys that are not in `allowed` (typo protection), listing the allowed ones."""
    for key in table:
        if key not in allowed:
            raise ProjectError(f"{where}: unknown key {key!r}; allowed keys: {', '.join(allowed)}")


def _toml_float(
    value: Any, where: str, *, positive: bool = False, nonnegative: bool = False
) -> float:
    """A finite TOML number (int or float, not bool), optionally > 0 or ≥ 0."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and abs(value) < float("inf")
    ok = ok and not (positive and value <= 0) and not (nonnegative and value < 0)
    if not ok:
        expected = "a number > 0" if positive else "a number ≥ 0" if nonnegative else "a number"
        raise ProjectError(f"{where}: expected {expected}, got {value!r}")
    return float(value)


def _toml_int(value: Any, where: str, *, positive: bool = True) -> int:
    """A TOML integer (not bool), by default > 0."""
    if not isinstance(value, int) or isinstance(value, bool) or (positive and value <= 0):
        expected = "an integer > 0" if positive else "an integer"
        raise ProjectError(f"{where}: expected {expected}, got {value!r}")
    return value


def _toml_bool(value: Any, where: str) -> bool:
    """A TOML boolean."""
    if not isinstance(value, bool):
        raise ProjectError(f"{where}: expected true or false, got {value!r}")
    return value


def _toml_str(value: Any, where: str) -> str:
    """A TOML string."""
    if not isinstance(value, str):
        raise ProjectError(f"{where}: expected a string, got {value!r}")
    return value


def _toml_pair(value: Any, where: str, parse: Any) -> tuple | None:
    """An optional `[a, b]` of positive numbers, each read with `parse`."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 2:
        raise ProjectError(f"{where}: expected a list of two values, got {value!r}")
    return tuple(parse(item, where, positive=True) for item in value)
