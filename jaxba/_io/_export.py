"""The calibrated cameras and rigs of a results.json in OpenCV's or COLMAP's conventions: what
`jaxba export` writes.

A camera with an exact equivalent in the target keeps its own values: an "opencv",
"opencv_full" or "fisheye" camera is OpenCV's camera (cv2's model; cv2.fisheye's for
"fisheye") and COLMAP's (`camera_to_colmap`), unless a parameter has no term there: skew
(`cv2.projectPoints` ignores K's skew, COLMAP has none) and, for COLMAP, the thin prism s1..s4.
Every other central camera, and those, is fitted: OpenCV's model over its sensor
(`fit_opencv`), whose largest and RMS misfit in pixels say how far the exported camera is
from the calibrated one anywhere on the sensor. A COLMAP export is a whole model: the cameras,
the images' poses and the points with the image points of observations.csv (in COLMAP's
pixels; observations removed by data snooping left out) and, with rigs, COLMAP's rigs and
frames (each camera's pose in its rig, each frame's pose).
"""

import dataclasses
from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from .._models._cameras import CAMERA_MODELS, PixelGrid
from .._models._cameras._names import (
    RAY_REFRACTION_PARAMETER_NAMES,
    REFRACTION_SEPARATOR,
    lens_model,
)
from ._camera_export import fit_opencv
from ._colmap import (
    PIXEL_ORIGIN_SHIFT,
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    ColmapPoint,
    camera_to_colmap,
    colmap_rigs,
    eop_to_colmap_pose,
    numeric_ids,
)
from ._opencv_yaml import opencv_camera_matrix
from ._stereo import essential_matrix, fundamental_matrix, stereo_extrinsics

TARGETS = {"opencv": "OpenCV", "colmap": "COLMAP"}
WARN_MISFIT_PX = 0.1  # a fitted camera further than this from the calibrated one is worth a word
_OPENCV_MODELS = ("opencv", "opencv_full", "fisheye")  # jaxba's models that are OpenCV's own
_NO_TERM = {  # target -> parameters of those models it has no term for
    "opencv": {"skew": "cv2.projectPoints ignores K's skew"},
    "colmap": {name: "COLMAP's models have no such term"
               for name in ("skew", "s1", "s2", "s3", "s4")},
}
_EOP = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


@dataclasses.dataclass(frozen=True)
class ResultsCamera:
    """One camera of a results.json: its `model` (a cameras.toml model name), the `values`
    and `constants` of its parameters by name, its `sensor` (columns, rows) and `pixel_size`
    (mm, x and y), None where its cameras.toml gave none."""

    id: str
    model: str
    values: dict[str, float]
    constants: dict[str, float]
    sensor: tuple[int, int] | None
    pixel_size: tuple[float, float] | None


@dataclasses.dataclass(frozen=True)
class ExportedCamera:
    """A camera in the target's conventions: `model` ("opencv", "opencv_full" or "fisheye")
    with `values` (pixels, OpenCV's convention: the centre of the top-left pixel is (0, 0))
    over `image_size` (width, height). `fitted`: None where these are the calibrated camera's
    own values, else why it has no exact equivalent; then the fit's largest and RMS misfit
    over the sensor (pixels)."""

    id: str
    source_model: str
    model: str
    values: dict[str, float]
    image_size: tuple[int, int]
    fitted: str | None
    max_misfit_px: float = 0.0
    rms_misfit_px: float = 0.0


@dataclasses.dataclass(frozen=True)
class StereoPair:
    """Camera `camera` of rig `rig` with the rig's `reference` as OpenCV's stereo pair
    (docs of `jaxba._io._stereo`): R (3, 3), T (3, 1) (object units), E, F (3, 3), and the
    `baseline` |b| (object units)."""

    rig: str
    reference: str
    camera: str
    r: np.ndarray
    t: np.ndarray
    e: np.ndarray
    f: np.ndarray
    baseline: float


def _value(entry, what: str) -> float:
    value = entry["value"]
    if value is None:
        raise ValueError(f"{what}: no value (null in results.json)")
    return float(value)


def results_cameras(results: Mapping) -> dict[str, ResultsCamera]:
    """The cameras of a results.json (parsed) by ID. Raises `ValueError` where it lacks
    "camera_models" (a results.json of an older jaxba) or a camera's values."""
    models = results.get("camera_models")
    if not isinstance(models, dict):
        raise ValueError('no "camera_models" (each camera\'s model and sensor): written by an '
                         "older jaxba; adjust the project again to export it")
    cameras = {}
    for cid, entries in results["cameras"].items():
        if cid not in models:
            raise ValueError(f'camera {cid!r} is not in "camera_models"')
        info, values, constants = models[cid], {}, {}
        for name, entry in entries.items():
            number = _value(entry, f"camera {cid!r} {name}")
            (constants if entry["status"] == "constant" else values)[name] = number
        sensor, pixel_size = info["sensor"], info["pixel_size"]
        cameras[cid] = ResultsCamera(
            cid, info["model"], values, constants,
            None if sensor is None else (int(sensor[0]), int(sensor[1])),
            None if pixel_size is None else (float(pixel_size[0]), float(pixel_size[1])))
    return cameras


def no_exact_equivalent(model: str, values: Mapping[str, float], target: str) -> str | None:
    """None where a `model` camera with `values` is exactly a camera of `target` ("opencv"
    or "colmap"), else why not, naming the model or the parameter without an equivalent."""
    if model not in _OPENCV_MODELS:
        return f"the {model} model has no {TARGETS[target]} equivalent"
    for name, why in _NO_TERM[target].items():
        if values.get(name, 0.0) != 0.0:
            return f"{name} = {values[name]:.6g} has no {TARGETS[target]} equivalent ({why})"
    return None


def export_camera(camera: ResultsCamera, target: str, *, coefficients: int = 5,
                  samples: int = 41, exact: bool = False) -> ExportedCamera:
    """`camera` in `target`'s conventions: its own values where it has an exact equivalent
    (`no_exact_equivalent`), else (unless `exact`) OpenCV's model with `coefficients`
    distortion terms fitted over the sensor from `samples` grid points along its longer side
    (`fit_opencv`).

    Raises `ValueError` naming the camera where it has no sensor size, a mm camera no pixel
    size, `exact` and no exact equivalent (naming the parameter or model), or no fit is
    possible: a camera behind a flat port (not central), a bal camera (centred image frame,
    no principal point), a distortion that folds the image over."""
    where = f"camera {camera.id!r}"
    lens = lens_model(camera.model)
    if lens != camera.model:
        refraction = camera.model.removeprefix(lens + REFRACTION_SEPARATOR)
        names = ", ".join(RAY_REFRACTION_PARAMETER_NAMES[refraction])
        raise ValueError(f"{where}: its {refraction} refraction ({names}) has no "
                         f"{TARGETS[target]} equivalent: the camera behind it is not central")
    if camera.model == "bal":
        raise ValueError(f"{where}: the bal model has no {TARGETS[target]} equivalent: its"
                         " image frame is centred with y up and its principal point unknown")
    if camera.sensor is None:
        raise ValueError(f"{where}: its cameras.toml gives no sensor (columns, rows); "
                         f"{TARGETS[target]} needs the image size")
    obstacle = no_exact_equivalent(camera.model, camera.values, target)
    if obstacle is None:
        return ExportedCamera(camera.id, camera.model, camera.model, dict(camera.values),
                              camera.sensor, None)
    if exact:
        raise ValueError(f"{where}: {obstacle}; only an exact equivalent was asked for")
    try:
        model = CAMERA_MODELS[camera.model]
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    instance = model.from_parameters(
        jnp.array([camera.values[name] for name in model.parameter_names]), **camera.constants)
    grid = None
    if instance.image_units == "mm":
        if camera.pixel_size is None:
            raise ValueError(f"{where}: a {camera.model} camera works in mm and its cameras.toml"
                             " gives no pixel_size: its pixels are unknown")
        grid = PixelGrid(camera.pixel_size, camera.sensor)
    try:
        fit = fit_opencv(instance, camera.sensor, grid, coefficients=coefficients,
                         samples=samples)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    return ExportedCamera(camera.id, camera.model, fit.model, fit.values, fit.image_size,
                          obstacle, fit.max_misfit_px, fit.rms_misfit_px)


def results_rigs(results: Mapping) -> dict[str, tuple[str, dict[str, Mapping]]]:
    """results.json "rigs" as rig -> (its reference camera, {camera: its entries}); {}
    without rigs. Raises `ValueError` for a rig that names no reference camera."""
    rigs = {}
    for rig, table in (results.get("rigs") or {}).items():
        reference = table.get("reference")
        if not isinstance(reference, str):
            raise ValueError(f"rig {rig!r}: names no reference camera (\"reference\")")
        rigs[rig] = (reference, {camera: entry for camera, entry in table.items()
                                 if camera != reference and isinstance(entry, dict)})
    return rigs


def stereo_pairs(results: Mapping, exported: Mapping[str, ExportedCamera]) -> list[StereoPair]:
    """Every non-reference camera of every rig of a results.json with its rig's reference
    camera, where both are `exported` (results.json "rigs": rig -> "reference", the camera
    whose frame is the rig frame, and camera -> X0, Y0, Z0, omega, phi, kappa); [] without
    rigs. F is that of the exported cameras' K."""
    pairs = []
    for rig, (reference, entries) in results_rigs(results).items():
        for camera, entry in entries.items():
            if camera not in exported or reference not in exported:
                continue
            where = f"rig {rig!r} camera {camera!r}"
            pose = [_value(entry[name], f"{where} {name}") for name in _EOP]
            r, t = stereo_extrinsics(pose[:3], pose[3:])
            e = essential_matrix(r, t)
            k1, k2 = (opencv_camera_matrix(exported[c].model, exported[c].values)[0]
                      for c in (reference, camera))
            pairs.append(StereoPair(rig, reference, camera, r, t, e,
                                    fundamental_matrix(e, k1, k2),
                                    float(np.linalg.norm(pose[:3]))))
    return pairs


def colmap_model(results: Mapping, observations: Mapping[str, np.ndarray],
                 cameras: Mapping[str, ResultsCamera],
                 exported: Mapping[str, ExportedCamera]) -> ColmapModel:
    """The COLMAP model of the `exported` cameras: their images (poses of results.json, NAME
    the image ID) and the points they observe (results.json's coordinates), with the image
    points of `observations` (observations.csv's columns, `read_observations`) not removed
    by data snooping, converted to COLMAP's pixels (mm through the camera's pixel size).
    Numeric camera and point IDs are kept where they can be (`project_to_colmap`). With
    rigs, COLMAP's rigs and frames too (`colmap_rigs`: results.json's "rigs", "frames" and
    "image_frames")."""
    camera_numbers = numeric_ids(list(exported))
    colmap_cameras = {}
    for cid, camera in exported.items():
        model, params = camera_to_colmap(camera.model, camera.values)
        number = camera_numbers[cid]
        colmap_cameras[number] = ColmapCamera(number, model, *camera.image_size, params)

    image_cameras = results["image_cameras"]
    image_ids = [iid for iid in results["images"] if image_cameras[iid] in exported]
    image_numbers = {iid: k for k, iid in enumerate(image_ids, start=1)}
    used = ((observations["type"] == "image_points") & ~observations["removed"]
            & np.isin(observations["image"], image_ids))
    images, points = observations["image"][used], observations["point"][used]
    xy = np.column_stack([observations["x"][used], observations["y"][used]])
    for cid in exported:
        rows = observations["camera"][used] == cid
        camera = cameras[cid]
        if rows.any() and CAMERA_MODELS[camera.model].image_units == "mm":
            grid = PixelGrid(camera.pixel_size, camera.sensor)
            xy[rows] = np.asarray(grid.image_to_pixel(jnp.asarray(xy[rows])))
    xy -= PIXEL_ORIGIN_SHIFT

    observed = set(points.tolist())
    point_ids = [pid for pid in results["points"] if pid in observed]
    point_numbers = numeric_ids(point_ids)
    points2d: dict[str, list] = {iid: [] for iid in image_ids}
    tracks: dict[str, list] = {pid: [] for pid in point_ids}
    for iid, pid, (x, y) in zip(images.tolist(), points.tolist(), xy.tolist()):
        entries = points2d[iid]
        tracks[pid].append((image_numbers[iid], len(entries)))
        entries.append((x, y, point_numbers[pid]))

    poses = {iid: _pose(results["images"][iid], f"image {iid!r}") for iid in image_ids}
    colmap_images = {}
    for iid in image_ids:
        q, t = eop_to_colmap_pose(poses[iid])
        number = image_numbers[iid]
        colmap_images[number] = ColmapImage(number, tuple(q), tuple(t),
                                            camera_numbers[image_cameras[iid]], iid,
                                            tuple(points2d[iid]))
    colmap_points = {}
    for pid in point_ids:
        xyz = tuple(_value(results["points"][pid][name], f"point {pid!r} {name}")
                    for name in ("X", "Y", "Z"))
        number = point_numbers[pid]
        colmap_points[number] = ColmapPoint(number, xyz, (0, 0, 0), -1.0, tuple(tracks[pid]))
    if not results_rigs(results):
        return ColmapModel(colmap_cameras, colmap_images, colmap_points)
    rigs, frames = _colmap_rigs(results, poses, camera_numbers, image_numbers)
    return ColmapModel(colmap_cameras, colmap_images, colmap_points, rigs, frames)


def _pose(entries: Mapping, what: str) -> np.ndarray:
    """(6,) X0, Y0, Z0, omega, phi, kappa (radians) of results.json's entries (degrees)."""
    pose = np.array([_value(entries[name], f"{what} {name}") for name in _EOP])
    return np.r_[pose[:3], np.radians(pose[3:])]


def _colmap_rigs(results: Mapping, poses: Mapping[str, np.ndarray],
                 camera_numbers: Mapping[str, int], image_numbers: Mapping[str, int]):
    """COLMAP's rigs and frames (`colmap_rigs`) of results.json's "rigs", "frames" and
    "image_frames" for the exported images `poses` (radians)."""
    image_frames = results.get("image_frames")
    if not isinstance(image_frames, dict):
        raise ValueError('no "image_frames" (each image\'s frame): written by an older jaxba; '
                         "adjust the project again to export its rigs")
    rigs = {rig: (reference, {camera: _pose(entry, f"rig {rig!r} camera {camera!r}")
                              for camera, entry in entries.items()})
            for rig, (reference, entries) in results_rigs(results).items()}
    image_cameras = results["image_cameras"]
    images = {iid: (image_cameras[iid], image_frames.get(iid, iid), pose)
              for iid, pose in poses.items()}
    frames = {frame: _pose(results["frames"][frame], f"frame {frame!r}")
              for frame in {frame for _, frame, _ in images.values()}}
    return colmap_rigs(rigs, images, frames, camera_numbers, image_numbers)
