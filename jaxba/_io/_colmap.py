"""COLMAP text models (cameras.txt, images.txt, points3D.txt) to and from jaxba projects.

COLMAP's formats (colmap.github.io/format.html, "Text format"):

- cameras.txt: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`;
- images.txt: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then
  `POINTS2D[] as (X, Y, POINT3D_ID)` (POINT3D_ID -1: not triangulated);
- points3D.txt: `POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)`.

Conventions, and how they map onto jaxba's (docs/conventions.md):

- **Poses.** (q, t) maps world to camera, x_cam = R(q) X + t, in COLMAP's camera frame: x
  right, y down, looking along +z (OpenCV's). jaxba's photogrammetric frame is
  diag(1, -1, -1) of it, so M = diag(1, -1, -1) R(q), X0 = -R(q)ᵀ t, and (omega, phi, kappa)
  are M's angles. q = (qw, qx, qy, qz) is a Hamilton unit quaternion.
- **Pixels.** COLMAP's pixel origin is the top-left *corner* of the image: the centre of the
  top-left pixel is (0.5, 0.5). jaxba's pixel-unit models ("opencv", "fisheye") use OpenCV's
  convention, the centre of the top-left pixel at (0, 0). Both conventions enter the
  projection only through the principal point (u = fx x'' + cx), so the conversion is one
  shift of every pixel coordinate, image points *and* principal point:
  u_jaxba = u_colmap - 0.5, cx_jaxba = cx_colmap - 0.5 (and v, cy alike); export adds 0.5.
- **Cameras.** SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV become "opencv"
  cameras, FULL_OPENCV an "opencv_full" one, OPENCV_FISHEYE a "fisheye" one; the terms the
  COLMAP model lacks are fixed at 0 (skew; k3, p1, p2 as the model says; s1..s4). The
  distortion formulas are OpenCV's in both programs. A single COLMAP focal length f becomes
  fx = fy = f with fy tied to fx (`ties = { fy = "fx" }`: one unknown, as in COLMAP). By
  default the focal length(s) and the distortion are free and the principal point fixed, as
  in COLMAP's bundle adjuster (refine_focal_length, refine_extra_params, not
  refine_principal_point); FULL_OPENCV's k4..k6 are kept fixed at COLMAP's values: with k1..k6
  all free the rational terms are numerically dependent over a normal field of view (the
  datum check refuses them), so free them explicitly (`free=`) for a wide-angle lens.
- **Points.** points3D become free tie points. COLMAP has no control: the datum of the
  imported project is the minimal constraint `datum="first_images"` (first image's six EOPs
  fixed, plus the largest coordinate difference of the second image's station: scale), or
  none (`datum=None`).

Plain NumPy; nothing here calls jax.
"""

import dataclasses
import json
import os
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from .._models._cameras._names import CAMERA_PARAMETER_NAMES
from .._models._rotation_numpy import matrix_to_opk, opk_to_matrix

PIXEL_ORIGIN_SHIFT = -0.5  # COLMAP pixel (corner origin) -> jaxba/OpenCV pixel (centre origin)
# The COLMAP camera frame (x right, y down, z forward) in the photogrammetric one: M = F R.
_CV_TO_PHOTOGRAMMETRIC = np.diag([1.0, -1.0, -1.0])

# COLMAP model -> (jaxba model, COLMAP parameter names, default free parameters),
# "f" stands for fx and fy.
COLMAP_CAMERA_MODELS: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": ("opencv", ("f", "cx", "cy"), ("f",)),
    "PINHOLE": ("opencv", ("fx", "fy", "cx", "cy"), ("fx", "fy")),
    "SIMPLE_RADIAL": ("opencv", ("f", "cx", "cy", "k1"), ("f", "k1")),
    "RADIAL": ("opencv", ("f", "cx", "cy", "k1", "k2"), ("f", "k1", "k2")),
    "OPENCV": ("opencv", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
               ("fx", "fy", "k1", "k2", "p1", "p2")),
    "FULL_OPENCV": ("opencv_full", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4",
                                    "k5", "k6"),
                    ("fx", "fy", "k1", "k2", "p1", "p2", "k3")),
    "OPENCV_FISHEYE": ("fisheye", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
                       ("fx", "fy", "k1", "k2", "k3", "k4")),
}
_JAXBA_PARAMETERS = {model: CAMERA_PARAMETER_NAMES[model]
                     for model in ("opencv", "opencv_full", "fisheye")}
_PIXEL_PARAMETERS = ("cx", "cy")  # shifted with the pixel origin


@dataclasses.dataclass(frozen=True)
class ColmapCamera:
    """One line of cameras.txt (COLMAP's pixel convention)."""

    id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class ColmapImage:
    """One image of images.txt: world-to-camera pose and its 2D points (COLMAP pixels).

    `points2d`: (x, y, point3d_id) in POINT2D_IDX order, point3d_id -1 where untriangulated.
    """

    id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str
    points2d: tuple[tuple[float, float, int], ...]


@dataclasses.dataclass(frozen=True)
class ColmapPoint:
    """One line of points3D.txt; `track`: (image_id, point2d_idx) pairs."""

    id: int
    xyz: tuple[float, float, float]
    rgb: tuple[int, int, int]
    error: float
    track: tuple[tuple[int, int], ...]


@dataclasses.dataclass(frozen=True)
class ColmapModel:
    """A COLMAP reconstruction: cameras, images and points by id."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: dict[int, ColmapPoint]


@dataclasses.dataclass(frozen=True)
class ColmapProject:
    """What `write_colmap_project` wrote: the project file and the counts."""

    project_file: pathlib.Path
    n_cameras: int
    n_images: int
    n_points: int
    n_image_points: int


# --- rotations (NumPy) -------------------------------------------------------------------------


def quaternion_to_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of the Hamilton quaternion (w, x, y, z), normalised first."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quaternion(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix (Shepperd's method)."""
    trace = np.trace(m)
    candidates = np.array([
        [1 + trace, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]],
        [m[2, 1] - m[1, 2], 1 + 2 * m[0, 0] - trace, m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]],
        [m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], 1 + 2 * m[1, 1] - trace, m[1, 2] + m[2, 1]],
        [m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1], 1 + 2 * m[2, 2] - trace],
    ])
    q = candidates[int(np.argmax([trace, m[0, 0], m[1, 1], m[2, 2]]))]
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def colmap_pose_to_eop(qvec: Sequence[float], tvec: Sequence[float]) -> np.ndarray:
    """COLMAP's world-to-camera (q, t) -> jaxba EOPs (X0, Y0, Z0, omega, phi, kappa [rad])."""
    rotation = quaternion_to_matrix(qvec)
    station = -rotation.T @ np.asarray(tvec, dtype=float)
    return np.r_[station, matrix_to_opk(_CV_TO_PHOTOGRAMMETRIC @ rotation)]


def eop_to_colmap_pose(eop: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """jaxba EOPs (X0, Y0, Z0, omega, phi, kappa [rad]) -> COLMAP's (q (w ≥ 0), t)."""
    eop = np.asarray(eop, dtype=float)
    rotation = _CV_TO_PHOTOGRAMMETRIC @ opk_to_matrix(eop[3:])
    return matrix_to_quaternion(rotation), -rotation @ eop[:3]


# --- the text files ----------------------------------------------------------------------------


def _data_lines(path: pathlib.Path):
    """(line number, tokens) of the non-comment lines; blank lines kept (images.txt needs them)."""
    if not path.is_file():
        raise ValueError(f"{path}: no such COLMAP file")
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.lstrip().startswith("#"):
            continue
        yield number, line.split()


def _numbers(path, number, tokens, kind=float):
    try:
        return [kind(token) for token in tokens]
    except ValueError:
        raise ValueError(f"{path}:{number}: expected numbers, got {' '.join(tokens)!r}") from None


def read_colmap_model(directory: str | os.PathLike) -> ColmapModel:
    """Read cameras.txt, images.txt and points3D.txt of a COLMAP text model in `directory`.

    Raises `ValueError` naming the file and line of anything malformed or unsupported.
    """
    directory = pathlib.Path(directory)
    cameras = {}
    path = directory / "cameras.txt"
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        if len(tokens) < 4:
            raise ValueError(f"{path}:{number}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        camera_id, width, height = _numbers(path, number, [tokens[0], *tokens[2:4]], int)
        model = tokens[1]
        if model not in COLMAP_CAMERA_MODELS:
            raise ValueError(f"{path}:{number}: unsupported camera model {model!r}; supported: "
                             f"{', '.join(COLMAP_CAMERA_MODELS)}")
        params = tuple(_numbers(path, number, tokens[4:]))
        expected = len(COLMAP_CAMERA_MODELS[model][1])
        if len(params) != expected:
            raise ValueError(f"{path}:{number}: {model} has {expected} parameters, "
                             f"got {len(params)}")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)

    images = {}
    path = directory / "images.txt"
    lines = list(_data_lines(path))
    k = 0
    while k < len(lines):
        number, tokens = lines[k]
        if not tokens:
            k += 1
            continue
        if len(tokens) < 10:
            raise ValueError(f"{path}:{number}: expected IMAGE_ID QW QX QY QZ TX TY TZ "
                             "CAMERA_ID NAME")
        image_id, camera_id = _numbers(path, number, [tokens[0], tokens[8]], int)
        pose = _numbers(path, number, tokens[1:8])
        name = " ".join(tokens[9:])
        if camera_id not in cameras:
            raise ValueError(f"{path}:{number}: unknown CAMERA_ID {camera_id}")
        points2d: list[tuple[float, float, int]] = []
        if k + 1 < len(lines):
            number2, tokens2 = lines[k + 1]
            if len(tokens2) % 3:
                raise ValueError(f"{path}:{number2}: POINTS2D: expected triples X Y POINT3D_ID")
            for j in range(0, len(tokens2), 3):
                x, y = _numbers(path, number2, tokens2[j:j + 2])
                (pid,) = _numbers(path, number2, tokens2[j + 2:j + 3], int)
                points2d.append((x, y, pid))
        images[image_id] = ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id,
                                       name, tuple(points2d))
        k += 2

    points = {}
    path = directory / "points3D.txt"
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        if len(tokens) < 8 or (len(tokens) - 8) % 2:
            raise ValueError(f"{path}:{number}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]")
        (point_id,) = _numbers(path, number, tokens[:1], int)
        xyz = _numbers(path, number, tokens[1:4])
        rgb = _numbers(path, number, tokens[4:7], int)
        (error,) = _numbers(path, number, tokens[7:8])
        track = _numbers(path, number, tokens[8:], int)
        pairs = tuple(zip(track[0::2], track[1::2]))
        for image_id, index in pairs:
            if image_id not in images or not 0 <= index < len(images[image_id].points2d):
                raise ValueError(f"{path}:{number}: track entry ({image_id}, {index}) names no "
                                 "2D point of images.txt")
        points[point_id] = ColmapPoint(point_id, tuple(xyz), tuple(rgb), error, pairs)
    return ColmapModel(cameras, images, points)


def colmap_model_texts(model: ColmapModel) -> dict[str, str]:
    """`model` as COLMAP text: file name (cameras.txt, images.txt, points3D.txt) -> text."""
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(model.cameras)}"]
    lines += [" ".join([str(c.id), c.model, str(c.width), str(c.height),
                        *(repr(float(v)) for v in c.params)]) for c in model.cameras.values()]
    texts = {"cameras.txt": "\n".join(lines) + "\n"}

    n_obs = sum(len(i.points2d) for i in model.images.values())
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(model.images)}, mean observations per image: "
             f"{n_obs / max(len(model.images), 1)}"]
    for image in model.images.values():
        lines.append(" ".join([str(image.id), *(repr(float(v)) for v in image.qvec),
                               *(repr(float(v)) for v in image.tvec), str(image.camera_id),
                               image.name]))
        lines.append(" ".join(f"{float(x)!r} {float(y)!r} {pid}" for x, y, pid in image.points2d))
    texts["images.txt"] = "\n".join(lines) + "\n"

    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(model.points)}"]
    lines += [" ".join([str(p.id), *(repr(float(v)) for v in p.xyz), *(str(v) for v in p.rgb),
                        repr(float(p.error)), *(f"{i} {j}" for i, j in p.track)])
              for p in model.points.values()]
    texts["points3D.txt"] = "\n".join(lines) + "\n"
    return texts


def write_colmap_model(model: ColmapModel, directory: str | os.PathLike) -> None:
    """Write `model` as COLMAP text (cameras.txt, images.txt, points3D.txt) into `directory`."""
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in colmap_model_texts(model).items():
        (directory / name).write_text(text)


# --- COLMAP -> jaxba project -------------------------------------------------------------------


def camera_to_jaxba(camera: ColmapCamera) -> tuple[str, dict[str, float], tuple[str, ...]]:
    """(jaxba model, parameter values in jaxba's pixel convention, default free list: fx
    alone for COLMAP's one focal length f, whose fy the project ties to fx)."""
    model, names, free = COLMAP_CAMERA_MODELS[camera.model]
    colmap = dict(zip(names, camera.params))
    values = {name: 0.0 for name in _JAXBA_PARAMETERS[model]}
    for name, value in colmap.items():
        if name == "f":
            values["fx"] = values["fy"] = value
        elif name in values:
            values[name] = value
    for name in _PIXEL_PARAMETERS:
        values[name] += PIXEL_ORIGIN_SHIFT
    jaxba_free = tuple("fx" if f == "f" else f for f in free)
    return model, values, jaxba_free


def _check_id(text: str, what: str) -> str:
    if not text or any(ch.isspace() for ch in text) or "#" in text or text == "-":
        raise ValueError(f"{what} {text!r}: jaxba ids cannot be empty, '-' or contain "
                         "whitespace or '#'")
    return text


def write_colmap_project(
    colmap_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    name: str = "colmap",
    free: Mapping[str, Sequence[str]] | None = None,
    image_sigma: float = 1.0,
    datum: str | None = "first_images",
) -> ColmapProject:
    """Write a COLMAP text model as a jaxba project (docs/project-files.md) into `out_dir`.

    **Arguments:**

    - `colmap_dir`: the folder with cameras.txt, images.txt and points3D.txt.
    - `out_dir`: where `NAME.toml`, cameras.toml, orientation.txt, image_coordinates.txt and
      points.txt go (created if missing).
    - `name`: the project name.
    - `free`: camera id -> free parameters, replacing the default (focal length(s) and
      distortion free, principal point fixed; module docstring).
    - `image_sigma`: σ of the image coordinates, pixels.
    - `datum`: `"first_images"` (the first image's EOPs and one station coordinate of the
      second fixed: a minimal constraint) or None (all EOPs free).

    Ids: cameras and points keep COLMAP's numeric ids, images are named by COLMAP's NAME.
    2D points that observe no 3D point and images that observe none are left out.
    """
    model = read_colmap_model(colmap_dir)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if datum not in ("first_images", None):
        raise ValueError(f"datum: expected 'first_images' or None, got {datum!r}")

    observations = []  # (image name, point id, x, y) in jaxba pixels
    used_images = []
    for image in model.images.values():
        name_id = _check_id(image.name, f"image {image.id}: NAME")
        seen = [(x, y, pid) for x, y, pid in image.points2d if pid != -1]
        for x, y, pid in seen:
            if pid not in model.points:
                raise ValueError(f"images.txt: image {image.id} observes unknown POINT3D_ID {pid}")
            observations.append((name_id, str(pid), x + PIXEL_ORIGIN_SHIFT,
                                 y + PIXEL_ORIGIN_SHIFT))
        if seen:
            used_images.append(image)
    names = [image.name for image in used_images]
    if len(set(names)) != len(names):
        raise ValueError("images.txt: image NAMEs are not unique")

    used_cameras = {image.camera_id for image in used_images}
    lines = [
        "# From COLMAP's cameras.txt: pixel coordinates shifted by -0.5 (COLMAP's origin is the",
        "# top-left corner of the image, jaxba's/OpenCV's the centre of the top-left pixel).",
    ]
    for camera in model.cameras.values():
        if camera.id not in used_cameras:
            continue
        jaxba_model, values, default_free = camera_to_jaxba(camera)
        camera_free = default_free if free is None or str(camera.id) not in free else tuple(
            free[str(camera.id)])
        one_focal = "f" in COLMAP_CAMERA_MODELS[camera.model][1] and "fy" not in camera_free
        lines += [
            f"[{camera.id}]",
            f'model = "{jaxba_model}"  # COLMAP {camera.model}',
            f"sensor = [{camera.width}, {camera.height}]",
            *(f"{p} = {float(v)!r}" for p, v in values.items()),
            f"free = {json.dumps(list(camera_free))}",
            *(['ties = { fy = "fx" }  # COLMAP\'s one focal length'] if one_focal else []),
            "",
        ]
    (out_dir / "cameras.toml").write_text("\n".join(lines))

    eops = [colmap_pose_to_eop(image.qvec, image.tvec) for image in used_images]
    fixed = [np.zeros(6, dtype=bool) for _ in used_images]
    if datum == "first_images" and len(used_images) >= 2:
        fixed[0][:] = True
        fixed[1][int(np.argmax(np.abs(eops[1][:3] - eops[0][:3])))] = True
    rows = ["# image_id camera_id X0 Y0 Z0 omega phi kappa (deg) sX0 sY0 sZ0 somega sphi "
            "skappa (0 fixed, - free); from COLMAP's images.txt (world-to-camera q, t)"]
    for image, eop, mask in zip(used_images, eops, fixed):
        values = np.r_[eop[:3], np.degrees(eop[3:])]
        rows.append(" ".join([image.name, str(image.camera_id),
                              *(repr(float(v)) for v in values),
                              *("0" if m else "-" for m in mask)]))
    (out_dir / "orientation.txt").write_text("\n".join(rows) + "\n")

    observed_points = {pid for _, pid, _, _ in observations}
    rows = ["# point_id X Y Z sX sY sZ: COLMAP's points3D as tie points (free)"]
    rows += [" ".join([str(p.id), *(repr(float(v)) for v in p.xyz), "-", "-", "-"])
             for p in model.points.values() if str(p.id) in observed_points]
    (out_dir / "points.txt").write_text("\n".join(rows) + "\n")

    rows = ["# image_id point_id col row (pixel; origin at the centre of the top-left pixel,",
            "# i.e. COLMAP's POINTS2D - 0.5)"]
    rows += [f"{image} {pid} {float(x)!r} {float(y)!r}" for image, pid, x, y in observations]
    (out_dir / "image_coordinates.txt").write_text("\n".join(rows) + "\n")

    project_file = out_dir / f"{name}.toml"
    project_file.write_text("\n".join([
        f"# COLMAP text model {pathlib.Path(colmap_dir).name} as a jaxba project.",
        "[project]",
        f"name = {json.dumps(name)}",
        'image_units = "pixel"',
        "",
        "[files]",
        'cameras = "cameras.toml"',
        'images = "orientation.txt"',
        'image_points = "image_coordinates.txt"',
        'points = "points.txt"',
        "",
        "[adjustment]",
        "sigma0 = 1.0",
        f"image_sigma = {float(image_sigma)!r}  # pixel",
        "max_iterations = 100",
        "",
    ]))
    return ColmapProject(project_file, len(used_cameras), len(used_images),
                         len(observed_points), len(observations))


# --- jaxba project -> COLMAP -------------------------------------------------------------------


def camera_to_colmap(model: str, values: Mapping[str, float]) -> tuple[str, tuple[float, ...]]:
    """The smallest COLMAP model (and its parameters, COLMAP pixels) that holds a camera.

    `model` is "opencv", "opencv_full" or "fisheye", `values` its parameters in jaxba's pixel
    convention. Raises `ValueError` for other models, for a skewed camera and for thin-prism
    terms (COLMAP's pinhole models have neither).
    """
    if model not in _JAXBA_PARAMETERS:
        raise ValueError(f"camera model {model!r} has no COLMAP equivalent "
                         f"({', '.join(_JAXBA_PARAMETERS)})")
    v = {name: float(values.get(name, 0.0)) for name in _JAXBA_PARAMETERS[model]}
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


def numeric_ids(ids: Sequence[str]) -> dict[str, int]:
    """jaxba id -> COLMAP id: the id itself where it is a positive integer, else the next free."""
    numeric = {i: int(i) for i in ids if i.isdigit() and int(i) > 0}
    if len(set(numeric.values())) != len(numeric):
        numeric = {}
    next_id = max(numeric.values(), default=0) + 1
    out = {}
    for i in ids:
        if i in numeric:
            out[i] = numeric[i]
        else:
            out[i], next_id = next_id, next_id + 1
    return out


def project_to_colmap(project, parameters=None) -> ColmapModel:
    """A jaxba `Project` with `parameters` (default: its starting values) as a COLMAP model.

    Cameras must be "opencv" or "opencv_full" (without skew or thin prism) or "fisheye" and
    the project's image_units "pixel". Image ids become COLMAP NAMEs (IMAGE_IDs 1, 2, ... in
    project order); numeric camera and point ids are kept. Pixel coordinates are shifted by
    +0.5 (module docstring). RGB is written as 0 0 0 and ERROR as -1 (jaxba keeps neither).
    """
    if project.spec.image_units != "pixel":
        raise ValueError(f"{project.spec.name}: only image_units = \"pixel\" projects export "
                         "to COLMAP")
    parameters = project.problem.initial if parameters is None else parameters
    camera_ids = numeric_ids(list(project.camera_rows))
    cameras = {}
    for camera_id, (model, row) in project.camera_rows.items():
        names = _JAXBA_PARAMETERS.get(model, ())
        values = dict(zip(names, np.asarray(parameters.cameras[model][row], dtype=float)))
        colmap_model, params = camera_to_colmap(model, values)
        width, height = project.spec.cameras[camera_id].sensor
        cid = camera_ids[camera_id]
        cameras[cid] = ColmapCamera(cid, colmap_model, width, height, params)

    point_ids = numeric_ids(project.point_ids)
    image_numbers = {image_id: k for k, image_id in enumerate(project.image_ids, start=1)}
    points2d: dict[str, list] = {image_id: [] for image_id in project.image_ids}
    tracks: dict[str, list] = {pid: [] for pid in project.point_ids}
    for m in project.spec.image_points:
        entries = points2d[m.image]
        tracks[m.point].append((image_numbers[m.image], len(entries)))
        entries.append((m.xy[0] - PIXEL_ORIGIN_SHIFT, m.xy[1] - PIXEL_ORIGIN_SHIFT,
                        point_ids[m.point]))

    images = {}
    eops = np.asarray(parameters.images, dtype=float)
    for k, image_id in enumerate(project.image_ids):
        q, t = eop_to_colmap_pose(eops[k])
        camera_id = camera_ids[project.spec.images[image_id].camera]
        number = image_numbers[image_id]
        images[number] = ColmapImage(number, tuple(q), tuple(t), camera_id, image_id,
                                     tuple(points2d[image_id]))

    xyz = np.asarray(parameters.points, dtype=float)
    points = {}
    for k, pid in enumerate(project.point_ids):
        number = point_ids[pid]
        points[number] = ColmapPoint(number, tuple(xyz[k]), (0, 0, 0), -1.0, tuple(tracks[pid]))
    return ColmapModel(cameras, images, points)


def write_colmap(project, out_dir: str | os.PathLike, parameters=None) -> ColmapModel:
    """Export a project (e.g. `adjust_project(project).parameters`) as COLMAP text into
    `out_dir`; see `project_to_colmap`. Returns the model written."""
    model = project_to_colmap(project, parameters)
    write_colmap_model(model, out_dir)
    return model
