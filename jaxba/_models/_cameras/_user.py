"""Camera models from outside jaxba (docs/models.md "User models"): `"package.module:ClassName"`,
or a name that an installed package declares in the entry-point group `jaxba.cameras`."""

import importlib
import importlib.metadata
import inspect

import jax.numpy as jnp

from ._abstract import AbstractCamera

ENTRY_POINT_GROUP = "jaxba.cameras"
IMAGE_UNITS = ("mm", "pixel")


class CameraModelError(ValueError):
    """A camera model name that names no usable model; the message says why."""


def load_camera_model(name: str) -> type[AbstractCamera]:
    """The class that `name` names: "package.module:ClassName" (imported) or an entry point
    of `ENTRY_POINT_GROUP`, checked to be a usable `AbstractCamera` subclass.

    Raises `CameraModelError` when it cannot be loaded or is not usable."""
    model = _imported(name) if ":" in name else _entry_point(name)
    _check_model(model, name)
    return model


def _imported(name: str):
    module_name, _, attribute = name.partition(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # an import runs the user's code: any error is theirs
        raise CameraModelError(
            f"camera model {name!r}: cannot import module {module_name!r}"
            f" ({type(error).__name__}: {error}); is it on sys.path / PYTHONPATH?") from error
    target = module
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise CameraModelError(
                f"camera model {name!r}: module {module_name!r} has no {attribute!r}")
        target = getattr(target, part)
    return target


def _entry_point(name: str):
    found = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    matches = [entry for entry in found if entry.name == name]
    if not matches:
        from ._names import CAMERA_PARAMETER_NAMES

        installed = sorted({entry.name for entry in found})
        raise CameraModelError(
            f"unknown camera model {name!r}; known models: {', '.join(CAMERA_PARAMETER_NAMES)}"
            f"; installed user models (entry points {ENTRY_POINT_GROUP!r}):"
            f" {', '.join(installed) or 'none'}; or a class as \"package.module:ClassName\"")
    if len({entry.value for entry in matches}) > 1:
        raise CameraModelError(
            f"camera model {name!r}: installed twice in {ENTRY_POINT_GROUP!r}, as "
            + " and ".join(repr(entry.value) for entry in matches))
    try:
        return matches[0].load()
    except Exception as error:  # loading runs the user's code: any error is theirs
        raise CameraModelError(
            f"camera model {name!r}: cannot load its entry point {matches[0].value!r}"
            f" ({type(error).__name__}: {error})") from error


def _check_model(model, name: str) -> None:
    """Refuse what is not a concrete `AbstractCamera` with named parameters that round-trip
    through `from_parameters` and `parameters`."""
    where = f"camera model {name!r}"
    if not (inspect.isclass(model) and issubclass(model, AbstractCamera)):
        raise CameraModelError(f"{where}: {model!r} is not a subclass of jaxba.AbstractCamera")
    if inspect.isabstract(model):
        missing = ", ".join(sorted(model.__abstractmethods__))
        raise CameraModelError(f"{where}: {model.__name__} does not implement {missing}")
    names = getattr(model, "parameter_names", None)
    if (not isinstance(names, tuple) or not all(isinstance(n, str) for n in names)
            or len(set(names)) != len(names)):
        raise CameraModelError(
            f"{where}: parameter_names must be a tuple of distinct strings, got {names!r}")
    if getattr(model, "image_units", None) not in IMAGE_UNITS:
        raise CameraModelError(f"{where}: image_units must be one of {IMAGE_UNITS}, got"
                               f" {getattr(model, 'image_units', None)!r}")
    constants = dict.fromkeys(model.constant_names, 1.0)
    try:
        count = jnp.shape(model.from_parameters(jnp.ones(len(names)), **constants).parameters())
    except Exception as error:  # the user's constructor: any error is theirs
        raise CameraModelError(
            f"{where}: {model.__name__}.from_parameters(values of {', '.join(names)}) fails"
            f" ({type(error).__name__}: {error}): its parameter_names must match its"
            " fields (or override from_parameters and parameters)") from error
    if count != (len(names),):
        raise CameraModelError(
            f"{where}: parameters() has shape {count}, expected ({len(names)},), one value per"
            " name in parameter_names")
