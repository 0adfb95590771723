"""The camera models a cameras.toml names (`model = "smac"`, ...)."""

from ._abstract import AbstractCamera
from ._bal import BalCamera
from ._fisheye import FisheyeCamera
from ._metrology import MetrologyCamera
from ._opencv import OpenCVCamera
from ._photomodeler import PhotoModelerCamera
from ._smac import SmacCamera

CAMERA_MODELS: dict[str, type[AbstractCamera]] = {
    "smac": SmacCamera, "opencv": OpenCVCamera, "photomodeler": PhotoModelerCamera,
    "bal": BalCamera, "fisheye": FisheyeCamera, "metrology": MetrologyCamera,
}
