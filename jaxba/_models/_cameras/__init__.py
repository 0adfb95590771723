"""Camera, distortion and refraction models; `CAMERA_MODELS` names them for project files.

`CAMERA_PARAMETER_NAMES` needs no jax; the models are imported when first used.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._abstract": (
        "AbstractCamera", "AbstractDistortion", "AbstractRayRefraction", "AbstractRefraction",
    ),
    "._affine": ("Affine",),
    "._bal": ("BalCamera",),
    "._decentering": ("DecenteringSmac",),
    "._fisheye": ("FisheyeCamera",),
    "._flat_port": ("FlatPort",),
    "._metrology": ("MetrologyCamera", "metrology_to_smac", "smac_to_metrology"),
    "._names": ("CAMERA_CONSTANT_NAMES", "CAMERA_PARAMETER_NAMES"),
    "._opencv": ("OpenCVCamera",),
    "._opencv_full": ("OpenCVFullCamera",),
    "._photomodeler": ("PhotoModelerCamera",),
    "._pixel": ("PixelGrid",),
    "._radial": ("RadialSmac",),
    "._refraction": ("AtmosphericRefraction", "NoRefraction"),
    "._refracted": ("RefractedCamera", "refracted_camera"),
    "._registry": ("CAMERA_MODELS", "RAY_REFRACTION_MODELS"),
    "._smac": ("SmacCamera",),
    "._user": ("CameraModelError",),
})
