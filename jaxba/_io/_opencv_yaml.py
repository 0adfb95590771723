"""A camera as an OpenCV YAML file (cv::FileStorage): camera matrix and distortion.

The file is what OpenCV's calibration sample writes and `cv2.FileStorage(path,
cv2.FILE_STORAGE_READ)` reads back:

    %YAML:1.0
    ---
    camera_model: "opencv"
    image_width: 640
    image_height: 480
    camera_matrix: !!opencv-matrix          # [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]
       rows: 3
       cols: 3
       dt: d
       data: [ ... ]
    distortion_coefficients: !!opencv-matrix
       rows: 1                              # "opencv": 1 x 5, (k1, k2, p1, p2, k3)
                                            # "opencv_full": 1 x 12, (..., k4, k5, k6, s1..s4)
       cols: 5                              # "fisheye": 4 x 1, (k1, k2, k3, k4), cv2.fisheye's D
       dt: d
       data: [ ... ]

jaxba's "opencv" and "fisheye" models use OpenCV's pixel convention (the centre of the
top-left pixel is (0, 0)) and OpenCV's formulas, so the values are written unchanged; the
skew sits in camera_matrix[0, 1] (OpenCV's `calibrateCamera` keeps it 0, `projectPoints`
ignores it). Numbers are written with Python's shortest round-trip repr, so they read back
exactly. Plain Python; nothing here calls jax.
"""

import json
import os
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

_DISTORTION = {"opencv": (("k1", "k2", "p1", "p2", "k3"), (1, 5)),
               "opencv_full": (("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2",
                                "s3", "s4"), (1, 12)),
               "fisheye": (("k1", "k2", "k3", "k4"), (4, 1))}


def _matrix(name: str, values, shape: tuple[int, int]) -> list[str]:
    data = ", ".join(repr(float(v)) for v in values)
    return [f"{name}: !!opencv-matrix", f"   rows: {shape[0]}", f"   cols: {shape[1]}",
            "   dt: d", f"   data: [ {data} ]"]


def opencv_camera_matrix(model: str, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(K 3x3, distortion coefficients) of an "opencv", "opencv_full" or "fisheye" camera,
    OpenCV's order."""
    if model not in _DISTORTION:
        raise ValueError(f"camera model {model!r}: only {', '.join(map(repr, _DISTORTION))} "
                         "write OpenCV YAML")
    value = lambda name: float(values.get(name, 0.0))  # noqa: E731
    k = np.array([[value("fx"), value("skew"), value("cx")], [0.0, value("fy"), value("cy")],
                  [0.0, 0.0, 1.0]])
    names, shape = _DISTORTION[model]
    return k, np.array([value(n) for n in names]).reshape(shape)


def opencv_yaml_text(model: str, values: Mapping[str, float], image_size: tuple[int, int],
                     extra: Mapping[str, float] | None = None) -> str:
    """One camera as OpenCV YAML text (module docstring); arguments as `write_opencv_yaml`,
    then the numbers `extra` by name (keys a reader of the file may ignore)."""
    k, distortion = opencv_camera_matrix(model, values)
    lines = ["%YAML:1.0", "---", f'camera_model: "{model}"',
             f"image_width: {int(image_size[0])}", f"image_height: {int(image_size[1])}",
             *_matrix("camera_matrix", k.ravel(), (3, 3)),
             *_matrix("distortion_coefficients", distortion.ravel(), distortion.shape),
             *(f"{name}: {float(value)!r}" for name, value in (extra or {}).items())]
    return "\n".join(lines) + "\n"


def stereo_yaml_text(cameras: Sequence[tuple[str, str, Mapping[str, float], tuple[int, int]]],
                     matrices: Mapping[str, np.ndarray], extra: Mapping[str, float]) -> str:
    """A camera pair as OpenCV's stereo YAML: per camera i = 1, 2 of `cameras` (name, model,
    values, image size) `camera_i` (its name), `camera_model_i`, `image_width_i`,
    `image_height_i`, `Ki` (3 x 3) and `Di` (its distortion coefficients); then `matrices`
    by name (R, T, E, F as `cv2.stereoCalibrate` returns them) and the numbers `extra`."""
    lines = ["%YAML:1.0", "---"]
    for i, (name, model, values, image_size) in enumerate(cameras, start=1):
        k, distortion = opencv_camera_matrix(model, values)
        lines += [f"camera_{i}: {json.dumps(name)}", f'camera_model_{i}: "{model}"',
                  f"image_width_{i}: {int(image_size[0])}",
                  f"image_height_{i}: {int(image_size[1])}",
                  *_matrix(f"K{i}", k.ravel(), (3, 3)),
                  *_matrix(f"D{i}", distortion.ravel(), distortion.shape)]
    for name, matrix in matrices.items():
        matrix = np.atleast_2d(matrix)
        lines += _matrix(name, matrix.ravel(), matrix.shape)
    lines += [f"{name}: {float(value)!r}" for name, value in extra.items()]
    return "\n".join(lines) + "\n"


def write_opencv_yaml(
    path: str | os.PathLike,
    model: str,
    values: Mapping[str, float],
    image_size: tuple[int, int],
) -> pathlib.Path:
    """Write one camera as OpenCV YAML (module docstring).

    **Arguments:**

    - `path`: the file to write (`.yml` / `.yaml`).
    - `model`: "opencv", "opencv_full" or "fisheye".
    - `values`: the model's parameters by name (pixels; missing ones 0).
    - `image_size`: (width, height) in pixels.
    """
    path = pathlib.Path(path)
    path.write_text(opencv_yaml_text(model, values, image_size))
    return path


def write_project_camera_yaml(project, camera_id: str, path: str | os.PathLike,
                              parameters=None) -> pathlib.Path:
    """Write camera `camera_id` of a `Project` with `parameters` (default: the starting values,
    e.g. `adjust_project(project).parameters` for the adjusted ones) as OpenCV YAML."""
    from .._models._cameras import CAMERA_MODELS  # late: keeps importing this module free of jax

    parameters = project.problem.initial if parameters is None else parameters
    if camera_id not in project.camera_rows:
        raise ValueError(f"{project.spec.name}: no camera {camera_id!r} used by an image")
    model, row = project.camera_rows[camera_id]
    names = CAMERA_MODELS[model].parameter_names
    values = dict(zip(names, np.asarray(parameters.cameras[model][row], dtype=float)))
    sensor = project.spec.cameras[camera_id].sensor
    if sensor is None:
        raise ValueError(f"camera {camera_id!r}: no sensor size (columns, rows) in cameras.toml")
    return write_opencv_yaml(path, model, values, sensor)
