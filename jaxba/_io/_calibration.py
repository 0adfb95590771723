"""A camera's calibration from results.json (its "camera_models" entry), and `compare`."""

import json
import math
import os
import pathlib

import numpy as np

from .._models._cameras import CAMERA_MODELS, PixelGrid
from .._statistics._compare import Calibration, Comparison, compare_calibrations


def read_calibration(source: str | os.PathLike | dict, camera: str | None = None) -> Calibration:
    """The `Calibration` of `camera` (its ID; None: the only camera) in a results.json file
    (path) or its loaded dict. `ValueError` naming the file and what is missing."""
    name = "results" if isinstance(source, dict) else str(source)
    if isinstance(source, dict):
        tree = source
    else:
        try:
            tree = json.loads(pathlib.Path(source).read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ValueError(f"{name}: cannot read it as results.json ({error})") from None
    models = tree.get("camera_models") if isinstance(tree, dict) else None
    if not models:
        raise ValueError(f"{name}: no \"camera_models\" (results.json of jaxba adjust writes"
                         " them; re-run the adjustment with this version)")
    if camera is None:
        if len(models) != 1:
            raise ValueError(f"{name}: {len(models)} cameras {sorted(models)}; say which one")
        camera = next(iter(models))
    if camera not in models:
        raise ValueError(f"{name}: no camera {camera!r} (cameras: {sorted(models)})")
    entry = models[camera]
    model = entry["model"]
    if model not in CAMERA_MODELS:
        raise ValueError(f"{name}: camera {camera!r}: unknown model {model!r}")
    if entry.get("sensor") is None:
        raise ValueError(f"{name}: camera {camera!r} has no sensor (image size) to compare over"
                         " (give `sensor` in cameras.toml)")
    if list(entry["parameters"]) != list(CAMERA_MODELS[model].parameter_names):
        raise ValueError(f"{name}: camera {camera!r}: parameters {entry['parameters']} are not"
                         f" the {model!r} model's {list(CAMERA_MODELS[model].parameter_names)}")
    pixel_size = entry.get("pixel_size")
    grid = None if CAMERA_MODELS[model].image_units == "pixel" or pixel_size is None else \
        PixelGrid(tuple(float(v) for v in pixel_size), tuple(int(v) for v in entry["sensor"]))
    covariance = np.array(entry["covariance"], dtype=float)
    if not np.all(np.isfinite(covariance)):
        raise ValueError(f"{name}: camera {camera!r}: its covariance is not available")
    return Calibration(
        name=f"{name}:{camera}", camera=camera, model=model,
        parameters=np.asarray(entry["values"], dtype=float), covariance=covariance,
        constants=tuple(sorted((k, float(v)) for k, v in entry.get("constants", {}).items())),
        sensor=tuple(int(v) for v in entry["sensor"]), grid=grid)


def camera_pair(camera) -> tuple[str | None, str | None]:
    """"C1" -> (C1, C1), "C1:C2" or ("C1", "C2") -> (C1, C2), None -> (None, None)."""
    if camera is None:
        return None, None
    if isinstance(camera, str):
        parts = camera.split(":")
        if len(parts) > 2 or not all(parts):
            raise ValueError(f"camera {camera!r}: C1 or C1:C2")
        return parts[0], parts[-1]
    first, second = camera
    return first, second


def compare(
    a: str | os.PathLike | dict | Calibration,
    b: str | os.PathLike | dict | Calibration,
    *,
    camera: str | tuple[str, str] | None = None,
    distance: float = math.inf,
    fit: str = "rotation",
    pixels: np.ndarray | None = None,
) -> Comparison:
    """The projection difference of two calibrations of one camera and its χ² test
    (`jaxba._statistics._compare`).

    `a`, `b`: results.json files (paths or loaded dicts) or `Calibration`s; `camera`: the
    camera's ID in both ("C1"), one in each ("C1:C2" or a pair), or None where each file
    holds one camera; `distance`: object units along A's rays (inf: directions); `fit`:
    "rotation" (default) or "none"; `pixels`: the grid (pixels of the sensor), default 24
    columns over it.
    """
    first, second = camera_pair(camera)
    a = a if isinstance(a, Calibration) else read_calibration(a, first)
    b = b if isinstance(b, Calibration) else read_calibration(b, second)
    return compare_calibrations(a, b, distance=distance, fit=fit, pixels=pixels)
