"""The camera models a cameras.toml names (`model = "smac"`, ...)."""

import functools

from ..._programs import register_lookup
from ._abstract import AbstractCamera
from ._bal import BalCamera
from ._fisheye import FisheyeCamera
from ._flat_port import FlatPort
from ._metrology import MetrologyCamera
from ._names import REFRACTION_SEPARATOR, lens_model
from ._opencv import OpenCVCamera
from ._opencv_full import OpenCVFullCamera
from ._photomodeler import PhotoModelerCamera
from ._refracted import refracted_camera
from ._smac import SmacCamera
from ._user import load_camera_model

RAY_REFRACTION_MODELS = {"flat_port": FlatPort}
"""The ray refraction models a camera's `[ID.refraction]` table names."""


class _CameraModels(dict):
    """The built-in models by name; any other name is resolved when looked up (`camera_model`)
    and not listed."""

    def __missing__(self, name: str) -> type[AbstractCamera]:
        return _resolved(name)


_RESOLVED: dict[str, type[AbstractCamera]] = {}  # the names `_resolved` resolved so far


@functools.cache
def _resolved(name: str) -> type[AbstractCamera]:
    """A camera behind a ray refraction ("smac+flat_port") or a user model
    ("package.module:ClassName", or an entry point of the group "jaxba.cameras")."""
    lens = lens_model(name)
    if lens != name:
        refraction = RAY_REFRACTION_MODELS[name.removeprefix(lens + REFRACTION_SEPARATOR)]
        camera = refracted_camera(CAMERA_MODELS[lens], refraction, name)
    else:
        camera = load_camera_model(name)
    _RESOLVED[name] = camera
    return camera


CAMERA_MODELS: dict[str, type[AbstractCamera]] = _CameraModels({
    "smac": SmacCamera, "opencv": OpenCVCamera, "opencv_full": OpenCVFullCamera,
    "photomodeler": PhotoModelerCamera,
    "bal": BalCamera, "fisheye": FisheyeCamera, "metrology": MetrologyCamera,
})
"""Camera model name -> class: the built-in ones listed; `CAMERA_MODELS[name]` also finds a
user model ("package.module:ClassName" or an entry point of the group "jaxba.cameras") and a
camera behind a ray refraction ("smac+flat_port"), and raises `CameraModelError` (a
ValueError) for a name it cannot resolve."""

# Traces look cameras up by their model name: a stored program's key holds every model.
register_lookup(lambda: (*CAMERA_MODELS.values(), *_RESOLVED.values()))
