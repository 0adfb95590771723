"""Read a project file and its tables (docs/project-files.md) into the project model's
records (`jaxba._project._spec`).

Plain Python, no jax. Every problem with the input raises `ProjectError` naming the file and,
where there is one, the line and the column or key. The project file itself (`[project]`,
`[files]`, `[adjustment]`) is read here; cameras.toml in `_cameras.py`, the text tables in
`_tables.py`, rigs.toml and the frames table in `_rigs.py`.
"""

import dataclasses
import os
import pathlib

from ..._files._paths import resolve
from ..._gc import paused_gc
from ..._project._errors import ProjectError
from ..._project._spec import AdjustmentSettings, InputFile, ProjectSpec
from ._cameras import read_cameras
from ._rigs import FRAME_COLUMNS, read_frames, read_rigs
from ._tables import (
    check_consistency,
    missing_points,
    read_distances,
    read_image_points,
    read_images,
    read_points,
)
from ._text_table import TextTable
from ._ties import expand_per_image
from ._toml import check_keys, load_toml, subtable, toml_float, toml_int, toml_value

IMAGE_UNITS = ("mm", "pixel")
IMAGE_UNIT_ALIASES = {"pixels": "pixel"}  # also accepted for [project] image_units

_PROJECT_TABLES = ("project", "files", "adjustment")
_PROJECT_KEYS = ("name", "image_units")
_REQUIRED_FILES = ("cameras", "images", "image_points", "points")
_OPTIONAL_FILES = ("distances", "rigs", "frames")
_POSITIVE_SETTINGS = frozenset({
    "sigma0", "image_sigma", "max_iterations", "object_unit_km", "snooping_alpha", "robust_scale",
})
_SETTING_CHOICES = {
    "robust": ("none", "huber", "cauchy"),
    "datum": ("control", "free", "dependent"),
    "solver": ("auto", "dense", "schur"),
    "stop": ("statistical", "cost"),
}
_NONNEGATIVE_SETTINGS = frozenset({"rtol", "atol"})


@dataclasses.dataclass(frozen=True)
class ProjectFile:
    """A project file read and checked, its tables not yet: `path` (resolved), its
    `file_name` as given (messages name it), the project's `name`, `image_units`,
    `settings` and `[files]` (`files`: key -> InputFile)."""

    path: pathlib.Path
    file_name: str
    name: str
    image_units: str
    settings: AdjustmentSettings
    files: dict[str, InputFile]

    @property
    def input_files(self) -> tuple[pathlib.Path, ...]:
        """The project file and the files of its `[files]` table (resolved), each once."""
        return tuple(dict.fromkeys([self.path, *(file.path for file in self.files.values())]))


def read_project(path: str | os.PathLike) -> ProjectSpec:
    """Read and validate a project file and every table it names.

    **Arguments:**

    - `path`: the project TOML file; the paths in its `[files]` table are relative to it.

    **Returns:** a `ProjectSpec`; its `input_files` lists every file read (resolved).

    **Raises:** `ProjectError` for any missing file, malformed entry or inconsistency.
    """
    return read_project_tables(read_project_file(path))


def read_project_file(path: str | os.PathLike) -> ProjectFile:
    """The project file alone: `read_project(path)` is `read_project_tables` of it. A batch
    checks its outputs against its `input_files` before the tables are read (in worker
    processes, which are handed it and do not parse the file again).

    **Raises:** `ProjectError` for a problem with the project file itself.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise ProjectError(f"{path}: no such project file")
    name = path.name
    document = load_toml(path, name)
    check_keys(document, _PROJECT_TABLES, f"{name}: top level")
    project = subtable(document, "project", name)
    adjustment = subtable(document, "adjustment", name)
    if "files" not in document:
        raise ProjectError(f"{name}: missing table [files]")
    base = path.parent.resolve()
    files = _read_files_table(subtable(document, "files", name), base, name)
    project_name, image_units = _read_project_table(project, name, path.stem)
    settings = _read_settings(adjustment, f"{name}: [adjustment]")
    return ProjectFile(_resolve_in(base, name), name, project_name, image_units, settings,
                       files)


def _resolve_in(directory: pathlib.Path, name: str) -> pathlib.Path:
    """`(directory / name).resolve()` for a resolved `directory`: where `name` is a plain
    file name, one `lstat` (is it a link?) instead of one per part of the path (`resolve`)."""
    folder = os.fspath(directory)
    return pathlib.Path(resolve(os.path.join(folder, name), {folder: folder}))


def read_project_tables(head: ProjectFile) -> ProjectSpec:
    """The project of the project file `head` (`read_project_file`) with every table it
    names read and validated (`read_project`)."""
    with paused_gc():  # the tables' rows are many small lists, none in a cycle
        return _read_tables(head)


def _read_tables(head: ProjectFile) -> ProjectSpec:
    files, image_units, name = head.files, head.image_units, head.file_name
    cameras = read_cameras(files["cameras"], image_units, name)
    images = read_images(files["images"], cameras, files["cameras"].name)
    cameras, images = expand_per_image(cameras, images, files["cameras"].name)
    points = read_points(files["points"])
    image_points = read_image_points(files["image_points"], images, files["images"].name)
    points.update(missing_points(image_points, points))
    distances = []
    if "distances" in files:
        distances = read_distances(files["distances"], points, files["points"].name)
    check_consistency(images, points, image_points, distances, files)
    rigs, frames = _read_rigs(files, cameras, images)

    return ProjectSpec(
        path=head.path,
        name=head.name,
        image_units=image_units,
        settings=head.settings,
        cameras=cameras,
        images=images,
        points=points,
        image_points=image_points,
        distances=distances,
        input_files=head.input_files,
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
    rigs = read_rigs(load_toml(files["rigs"].path, files["rigs"].name), files["rigs"].name,
                     cameras)
    frames = {}
    if "frames" in files:
        frames = read_frames(TextTable(files["frames"], FRAME_COLUMNS, 2).rows(), images, rigs)
    return rigs, frames


def _read_project_table(table: dict, where: str, default_name: str) -> tuple[str, str]:
    """`[project]`: the name (default: the file stem) and the image units."""
    check_keys(table, _PROJECT_KEYS, f"{where}: [project]")
    name = toml_value(table.get("name", default_name), str, f"{where}: [project] name",
                      "a string")
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


def _read_files_table(table: dict, base: pathlib.Path, where: str) -> dict[str, InputFile]:
    """`[files]`: resolve every path relative to the project file's resolved directory `base`
    and check it exists."""
    check_keys(table, _REQUIRED_FILES + _OPTIONAL_FILES, f"{where}: [files]")
    files = {}
    for key in _REQUIRED_FILES + _OPTIONAL_FILES:
        if key not in table:
            if key in _REQUIRED_FILES:
                raise ProjectError(
                    f"{where}: [files] {key}: missing; required keys: {', '.join(_REQUIRED_FILES)}"
                )
            continue
        value = toml_value(table[key], str, f"{where}: [files] {key}", "a string")
        resolved = _resolve_in(base, value)
        if not resolved.is_file():
            raise ProjectError(f"{where}: [files] {key}: no such file: {resolved}")
        files[key] = InputFile(resolved, value)
    return files


def _read_settings(table: dict, where: str) -> AdjustmentSettings:
    """`[adjustment]`: one key per `AdjustmentSettings` field, type-checked by the field's type."""
    fields = {field.name: field for field in dataclasses.fields(AdjustmentSettings)}
    check_keys(table, tuple(fields), where)
    values = {}
    for key, value in table.items():
        kind, key_where = fields[key].type, f"{where} {key}"
        kind = {"bool": bool, "int": int, "float": float, "str": str}.get(kind, kind)  # type: ignore
        if kind == tuple[str, ...]:
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ProjectError(f"{key_where}: expected a list of strings, got {value!r}")
            values[key] = tuple(value)
        elif kind is bool:
            values[key] = toml_value(value, bool, key_where, "true or false")
        elif kind is int:
            values[key] = toml_int(value, key_where, positive=key in _POSITIVE_SETTINGS)
        elif kind is float:
            values[key] = toml_float(
                value,
                key_where,
                positive=key in _POSITIVE_SETTINGS,
                nonnegative=key in _NONNEGATIVE_SETTINGS,
            )
        elif kind is str:
            values[key] = toml_value(value, str, key_where, "a string")
            choices = _SETTING_CHOICES.get(key)
            if choices is not None and values[key] not in choices:
                raise ProjectError(f"{key_where}: expected one of {choices}, got {values[key]!r}")
        else:
            raise TypeError(f"no reader for AdjustmentSettings.{key} of type {kind!r}")
    return AdjustmentSettings(**values)

