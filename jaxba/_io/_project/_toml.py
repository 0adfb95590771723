"""TOML documents of a project (the project file, cameras.toml, rigs.toml) and their values,
each checked where it is read: a `ProjectError` names the file and the table and key (`where`).
"""

import pathlib
import tomllib
from collections.abc import Container, Mapping
from typing import Any

from ..._project._errors import ProjectError


def load_toml(path: pathlib.Path, name: str) -> dict:
    """Parse the TOML file `path` (`name` in messages), turning syntax errors into
    `ProjectError`."""
    return parse_toml(read_bytes(path, name), name)


def read_bytes(path: pathlib.Path, name: str) -> bytes:
    """The content of the file `path` (`name` in messages)."""
    try:
        return path.read_bytes()
    except OSError as error:
        raise ProjectError(f"{name}: cannot read {path}: {error}") from None


def parse_toml(data: bytes, name: str) -> dict:
    """The TOML document `data`, the content of the file `name` (in messages)."""
    try:
        return tomllib.loads(data.decode())
    except tomllib.TOMLDecodeError as error:
        raise ProjectError(f"{name}: invalid TOML: {error}") from None
    except UnicodeDecodeError as error:
        line = error.object[: error.start].count(b"\n") + 1
        raise ProjectError(
            f"{name}:{line}: not UTF-8 text (byte 0x{error.object[error.start]:02x}); save"
            " the file as UTF-8"
        ) from None


def subtable(document: dict, key: str, where: str) -> dict:
    """An optional `[key]` table (empty if absent)."""
    table = document.get(key, {})
    if not isinstance(table, dict):
        raise ProjectError(f"{where}: {key}: expected a table [{key}], got {table!r}")
    return table


def check_keys(table: Mapping, allowed: tuple[str, ...], where: str) -> None:
    """Refuse keys that are not in `allowed` (typo protection), listing the allowed ones."""
    for key in table:
        if key not in allowed:
            raise ProjectError(f"{where}: unknown key {key!r}; allowed keys: {', '.join(allowed)}")


def toml_float(
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


def toml_int(value: Any, where: str, *, positive: bool = True) -> int:
    """A TOML integer (not bool), by default > 0."""
    if not isinstance(value, int) or isinstance(value, bool) or (positive and value <= 0):
        expected = "an integer > 0" if positive else "an integer"
        raise ProjectError(f"{where}: expected {expected}, got {value!r}")
    return value


def toml_value(value: Any, kind: type, where: str, expected: str) -> Any:
    """A TOML value of type `kind` (a string, a boolean, a table), described as `expected`."""
    if not isinstance(value, kind):
        raise ProjectError(f"{where}: expected {expected}, got {value!r}")
    return value


def toml_pair(value: Any, where: str, parse: Any) -> tuple | None:
    """An optional `[a, b]` of positive numbers, each read with `parse`."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 2:
        raise ProjectError(f"{where}: expected a list of two values, got {value!r}")
    return tuple(parse(item, where, positive=True) for item in value)


def name_list(value: Any, where: str) -> list[str]:
    """A `free` list: parameter names."""
    if not isinstance(value, list) or not all(isinstance(name, str) for name in value):
        raise ProjectError(f"{where}: expected a list of parameter names, got {value!r}")
    return value


def prior_table(value: Any, where: str) -> dict:
    """A `[... .sigma]` table: prior σ by parameter name (the values not yet checked)."""
    return toml_value(value, dict, where, "a table of prior σ")


def check_not_weighted(name: str, other: Container[str], where: str) -> None:
    """`name`, in a `free` list or a prior σ table (`where`), is not in the other one,
    `other`: a parameter is free or weighted."""
    if name in other:
        raise ProjectError(f"{where} {name}: {name!r} is also in free; a parameter is either"
                           " free or weighted, not both")
