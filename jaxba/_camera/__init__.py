"""Camera, distortion and refraction models; `CAMERA_MODELS` names them for project files."""

from ._abstract import AbstractCamera, AbstractDistortion, AbstractRefraction
from ._affine import Affine
from ._bal import BalCamera
from ._decentering import DecenteringSmac
from ._fisheye import FisheyeCamera
from ._opencv import OpenCVCamera
from ._photomodeler import PhotoModelerCamera
from ._pixel import PixelGrid
from ._radial import RadialSmac
from ._refraction import AtmosphericRefraction, NoRefraction
from ._smac import SmacCamera

CAMERA_MODELS: dict[str, type[AbstractCamera]] = {
    "smac": SmacCamera, "opencv": OpenCVCamera, "photomodeler": PhotoModelerCamera,
    "bal": BalCamera, "fisheye": FisheyeCamera,
}

__all__ = [
    "CAMERA_MODELS", "AbstractCamera", "AbstractDistortion", "AbstractRefraction", "Affine",
    "AtmosphericRefraction", "BalCamera", "DecenteringSmac", "FisheyeCamera", "NoRefraction",
    "OpenCVCamera", "PhotoModelerCamera", "PixelGrid", "RadialSmac", "SmacCamera",
]
