"""The ray refraction of a camera in cameras.toml, `[ID.refraction]` (docs/project-files.md):
a flat port, whose parameters join the camera's; the port normal is given as one 3-vector and
joins them as (normal_x, normal_y) of the unit normal turned towards the object.

The indices are > 0, the distance and thickness ≥ 0; n_air is 1 unless given, the normal the
optical axis.
"""

import dataclasses
from typing import Any

import numpy as np

from ..._models._cameras._names import RAY_REFRACTION_PARAMETER_NAMES
from ..._project._errors import ProjectError
from ._toml import check_keys, check_not_weighted, name_list, prior_table, toml_float

_PORT_KEYS = ("model", "distance", "thickness", "n_air", "n_glass", "n_medium", "normal",
             "free", "sigma")
_PORT_NORMAL = ("normal_x", "normal_y")
_PORT_DEFAULTS = {"n_air": 1.0, "normal": [0.0, 0.0, -1.0]}
_PORT_INDICES = ("n_air", "n_glass", "n_medium")


@dataclasses.dataclass(frozen=True)
class Port:
    """The parameters of a camera's ray refraction, as they join the camera's."""

    values: dict[str, float]
    free: list[str]
    sigma: dict[str, float]


def read_refraction(table: Any, camera: str) -> tuple[str, Port]:
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
    check_keys(table, _PORT_KEYS, where)
    given = {**_PORT_DEFAULTS, **table}
    values = {}
    for name in ("distance", "thickness", *_PORT_INDICES):
        if name not in given:
            raise ProjectError(f"{where} {name}: missing; a flat port needs distance, thickness,"
                               " n_glass and n_medium (n_air is 1 and the normal the optical"
                               " axis unless given)")
        values[name] = toml_float(given[name], f"{where} {name}",
                                  positive=name in _PORT_INDICES, nonnegative=True)
    values.update(zip(_PORT_NORMAL, _port_normal(given["normal"], f"{where} normal")))
    free = name_list(table.get("free", []), f"{where} free")
    sigma_table = prior_table(table.get("sigma", {}), sigma_where)
    allowed = _PORT_KEYS[1:-2]
    for name in free:
        if name not in allowed:
            raise ProjectError(f"{where} free: unknown parameter {name!r}; allowed: "
                               f"{', '.join(allowed)}")
        check_not_weighted(name, sigma_table, sigma_where)
    check_keys(sigma_table, allowed, sigma_where)
    sigma = {name: toml_float(value, f"{sigma_where} {name}", positive=True)
             for name, value in sigma_table.items()}

    def unknowns(name: str) -> tuple[str, ...]:
        return _PORT_NORMAL if name == "normal" else (name,)

    return model, Port(
        values, [n for name in free for n in unknowns(name)],
        {n: value for name, value in sigma.items() for n in unknowns(name)})


def _port_normal(value: Any, where: str) -> tuple[float, float]:
    """(x, y) of the unit port normal given as a 3-vector (any length, either sense), turned
    towards the object (z < 0); a normal across the optical axis (z = 0) is refused."""
    if not isinstance(value, list) or len(value) != 3:
        raise ProjectError(f"{where}: expected a list of three numbers, got {value!r}")
    normal = np.array([toml_float(v, where) for v in value])
    length = float(np.linalg.norm(normal))
    if normal[2] == 0:
        raise ProjectError(f"{where}: {value!r} is not a port normal: it must not be across the"
                           " optical axis (z ≠ 0)")
    normal = -np.sign(normal[2]) * normal / length
    return float(normal[0]), float(normal[1])

