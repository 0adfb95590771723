"""cameras.toml (docs/project-files.md): one table per camera ID, read into `CameraSpec`s.

A camera table gives its model (built-in or a user model), parameter values, the `free` list,
the prior σ `[ID.sigma]`, the pixel size and sensor, the model's constants, the ray refraction
`[ID.refraction]` (`_port.py`), the platform mount `[ID.mount]` (`_rigs.py`) and the ties
(`_ties.py`). Plain Python: jax is imported only for a user model.
"""

from typing import Any

from ..._models._cameras._names import (
    CAMERA_CONSTANT_NAMES,
    CAMERA_PARAMETER_NAMES,
    PIXEL_MODELS,
    PRINCIPAL_DISTANCES,
    lens_model,
)
from ..._project._errors import ProjectError
from ..._project._spec import CameraSpec, InputFile
from ._content import once
from ._port import read_refraction
from ._rigs import read_platform_mount
from ._ties import TIE_KEYS, read_camera_ties, resolve_ties
from ._toml import (
    check_keys,
    check_not_weighted,
    name_list,
    parse_toml,
    prior_table,
    read_bytes,
    toml_float,
    toml_int,
    toml_pair,
)

DEFAULT_CAMERA_MODEL = "smac"
_CAMERA_KEYS = ("model", "free", "sigma", "pixel_size", "sensor", "refraction", "mount",
                *TIE_KEYS)


def read_cameras(file: InputFile, image_units: str, project: str) -> dict[str, CameraSpec]:
    """cameras.toml: one table per camera id (a text read before with the same arguments:
    its cameras again, `once`; not for a user model, whose names may change)."""
    data = read_bytes(file.path, file.name)
    return dict(once(
        ("cameras", data, file.name, image_units, project), data,
        lambda: _read_cameras(parse_toml(data, file.name), file.name, image_units, project),
        lambda cameras: all(c.model in CAMERA_PARAMETER_NAMES for c in cameras.values())))


def _read_cameras(document: dict, file: str, image_units: str, project: str
                  ) -> dict[str, CameraSpec]:
    """`read_cameras` of the parsed document of `file`."""
    cameras = {}
    for camera_id, table in document.items():
        if not isinstance(table, dict):
            raise ProjectError(
                f"{file}: {camera_id}: expected a table [{camera_id}] per camera, "
                f"got {table!r}"
            )
        camera = _read_camera(camera_id, table, file)
        if image_units == "pixel":
            # A pixel model computes pixels itself: it needs no pixel size.
            needed = ("sensor",) if camera.model in PIXEL_MODELS else ("pixel_size", "sensor")
            missing = [key for key in needed if table.get(key) is None]
            if missing:
                raise ProjectError(
                    f"{file}: [{camera_id}] {missing[0]}: missing; {project} has "
                    f'image_units = "pixel", so model {camera.model!r} needs '
                    + " and ".join(needed)
                )
        cameras[camera_id] = camera
    return resolve_ties(cameras, document, file)


def _read_camera(camera_id: str, table: dict, file: str) -> CameraSpec:
    """One camera table: model, parameter values, free list, `[ID.sigma]`, pixel size, sensor,
    and the ray refraction `[ID.refraction]`, whose parameters join the camera's."""
    where = f"{file}: [{camera_id}]"
    model = table.get("model", DEFAULT_CAMERA_MODEL)
    names, constant_names = _model_names(model, where)
    constants = _read_constants(table, model, names, constant_names, where)
    check_keys(table, _CAMERA_KEYS + names + tuple(constants), where)
    values = {name: toml_float(table.get(name, 0.0), f"{where} {name}") for name in names}
    for name in PRINCIPAL_DISTANCES.get(model, ()):
        if values[name] <= 0:
            raise ProjectError(
                f"{where} {name}: the principal distance (focal length) of model {model!r}"
                f" must be > 0, got {table.get(name, 0.0)!r}"
                + ("" if name in table else " (not given: it defaults to 0)")
            )

    free = name_list(table.get("free", []), f"{where} free")
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
    sigma_table = prior_table(table.get("sigma", {}), sigma_where)
    for name in constants:
        if name in sigma_table:
            raise ProjectError(f"{sigma_where} {name}: {name!r} is a constant of model "
                               f"{model!r}, not an unknown; it has no prior σ")
    check_keys(sigma_table, names, sigma_where)
    sigma = {
        name: toml_float(value, f"{sigma_where} {name}", positive=True)
        for name, value in sigma_table.items()
    }
    for name in free:
        check_not_weighted(name, sigma, sigma_where)

    refraction = None
    if "refraction" in table:
        refraction, port = read_refraction(table["refraction"], f"{file}: [{camera_id}")
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
        pixel_size=toml_pair(table.get("pixel_size"), f"{where} pixel_size", toml_float),
        sensor=toml_pair(table.get("sensor"), f"{where} sensor", toml_int),
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
    return {name: toml_float(table[name], f"{where} {name}", nonnegative=True) for name in own}
