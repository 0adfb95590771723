"""COLMAP's camera models and jaxba's: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and
OPENCV are "opencv" cameras, FULL_OPENCV an "opencv_full" one, OPENCV_FISHEYE a "fisheye" one
(the package's docstring says how: pixels, the one focal length, the default free set)."""

from collections.abc import Mapping

from ..._models._cameras._names import CAMERA_PARAMETER_NAMES
from ._model import COLMAP_CAMERA_MODELS, ColmapCamera

PIXEL_ORIGIN_SHIFT = -0.5  # COLMAP pixel (corner origin) -> jaxba/OpenCV pixel (centre origin)
JAXBA_PARAMETERS = {model: CAMERA_PARAMETER_NAMES[model]
                    for model in ("opencv", "opencv_full", "fisheye")}
_PIXEL_PARAMETERS = ("cx", "cy")  # shifted with the pixel origin


def camera_to_jaxba(camera: ColmapCamera) -> tuple[str, dict[str, float], tuple[str, ...]]:
    """(jaxba model, parameter values in jaxba's pixel convention, default free list: fx
    alone for COLMAP's one focal length f, whose fy the project ties to fx)."""
    model, names, free = COLMAP_CAMERA_MODELS[camera.model]
    colmap = dict(zip(names, camera.params))
    values = {name: 0.0 for name in JAXBA_PARAMETERS[model]}
    for name, value in colmap.items():
        if name == "f":
            values["fx"] = values["fy"] = value
        elif name in values:
            values[name] = value
    for name in _PIXEL_PARAMETERS:
        values[name] += PIXEL_ORIGIN_SHIFT
    jaxba_free = tuple("fx" if f == "f" else f for f in free)
    return model, values, jaxba_free


def camera_to_colmap(model: str, values: Mapping[str, float]) -> tuple[str, tuple[float, ...]]:
    """The smallest COLMAP model (and its parameters, COLMAP pixels) that holds a camera.

    `model` is "opencv", "opencv_full" or "fisheye", `values` its parameters in jaxba's pixel
    convention. Raises `ValueError` for other models, for a skewed camera and for thin-prism
    terms (COLMAP's pinhole models have neither).
    """
    if model not in JAXBA_PARAMETERS:
        raise ValueError(f"camera model {model!r} has no COLMAP equivalent "
                         f"({', '.join(JAXBA_PARAMETERS)})")
    v = {name: float(values.get(name, 0.0)) for name in JAXBA_PARAMETERS[model]}
    for name in _PIXEL_PARAMETERS:
        v[name] -= PIXEL_ORIGIN_SHIFT
    if model == "fisheye":
        colmap = "OPENCV_FISHEYE"
    else:
        for name in ("skew", "s1", "s2", "s3", "s4"):
            if v.get(name, 0.0) != 0:
                raise ValueError(f"an {model} camera with {name} = {v[name]} has no COLMAP "
                                 "equivalent")
        square = v["fx"] == v["fy"]
        if any(v.get(name, 0.0) != 0 for name in ("k3", "k4", "k5", "k6")):
            colmap = "FULL_OPENCV"
        elif v["p1"] != 0 or v["p2"] != 0 or not square and (v["k1"] != 0 or v["k2"] != 0):
            colmap = "OPENCV"
        elif not square:
            colmap = "PINHOLE"
        elif v["k2"] != 0:
            colmap = "RADIAL"
        elif v["k1"] != 0:
            colmap = "SIMPLE_RADIAL"
        else:
            colmap = "SIMPLE_PINHOLE"
    names = COLMAP_CAMERA_MODELS[colmap][1]
    v["f"] = v["fx"]
    return colmap, tuple(v.get(name, 0.0) for name in names)
