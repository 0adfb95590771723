"""A COLMAP model as a jaxba project (`write_colmap_project`): the package's docstring says
how cameras, pixels, poses, points and rigs convert."""

import dataclasses
import json
import os
import pathlib
import warnings
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..._project._spec import MOUNT_NAMES
from .._project._project_file import project_toml
from ._cameras import PIXEL_ORIGIN_SHIFT, camera_to_jaxba
from ._model import COLMAP_CAMERA_MODELS
from ._read import read_colmap_model
from ._rigs import ImportedRigs, imported_rigs


@dataclasses.dataclass(frozen=True)
class ColmapProject:
    """What `write_colmap_project` wrote: the project file and the counts (`n_rigs`: rigs of
    two cameras or more, `n_frames`: their frames)."""

    project_file: pathlib.Path
    n_cameras: int
    n_images: int
    n_points: int
    n_image_points: int
    n_rigs: int = 0
    n_frames: int = 0


def _check_id(text: str, what: str) -> str:
    if not text or any(ch.isspace() for ch in text) or "#" in text or text == "-":
        raise ValueError(f"{what} {text!r}: jaxba ids cannot be empty, '-' or contain "
                         "whitespace or '#'")
    return text


def _warn(message: str) -> None:
    warnings.warn(message, stacklevel=3)


def write_colmap_project(
    colmap_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    name: str = "colmap",
    free: Mapping[str, Sequence[str]] | None = None,
    image_sigma: float = 1.0,
    datum: str | None = "first_images",
    warn: Callable[[str], None] = _warn,
) -> ColmapProject:
    """Write a COLMAP model (binary or text; `read_colmap_model`) as a jaxba project
    (docs/project-files.md) into `out_dir`.

    **Arguments:**

    - `colmap_dir`: the folder with the model.
    - `out_dir`: where `NAME.toml`, cameras.toml, orientation.txt, image_coordinates.txt,
      points.txt and, for a model with rigs, rigs.toml and frames.txt go (created if missing).
    - `name`: the project name.
    - `free`: camera id -> free parameters, replacing the default (focal length(s) and
      distortion free, principal point fixed; the package's docstring).
    - `image_sigma`: σ of the image coordinates, pixels.
    - `datum`: `"first_images"` (the first image's EOPs and one station coordinate of the
      second fixed, images whose pose is their frame's and their camera's in a rig skipped:
      a minimal constraint) or None (all EOPs free).
    - `warn`: called with a message for each rig sensor left out (an IMU); default
      `warnings.warn`.

    Ids: cameras and points keep COLMAP's numeric ids, images are named by COLMAP's NAME,
    rigs "rig<RIG_ID>", frames by FRAME_ID ("frame<FRAME_ID>" where one is an image's NAME).
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
                raise ValueError(f"images: image {image.id} observes unknown POINT3D_ID {pid}")
            observations.append((name_id, str(pid), x + PIXEL_ORIGIN_SHIFT,
                                 y + PIXEL_ORIGIN_SHIFT))
        if seen:
            used_images.append(image)
    names = [image.name for image in used_images]
    if len(set(names)) != len(names):
        raise ValueError("images: image NAMEs are not unique")
    rigs = imported_rigs(model, {image.id for image in used_images})
    for message in rigs.skipped:
        warn(message)

    used_cameras = {image.camera_id for image in used_images}
    _write_cameras(out_dir / "cameras.toml", model, used_cameras, free)
    files = {"cameras": "cameras.toml", "images": "orientation.txt",
             "image_points": "image_coordinates.txt", "points": "points.txt"}
    if rigs.rigs:
        _write_rigs(out_dir, rigs, {image.id: image.name for image in used_images})
        files |= {"rigs": "rigs.toml", "frames": "frames.txt"}

    eops = [rigs.poses[image.id] for image in used_images]
    in_rig = {sid for _, mounts in rigs.rigs.values() for sid in mounts}
    carriers = [k for k, image in enumerate(used_images) if image.camera_id not in in_rig]
    fixed = [np.zeros(6, dtype=bool) for _ in used_images]
    if datum == "first_images" and len(carriers) >= 2:
        first, second = carriers[:2]
        fixed[first][:] = True
        fixed[second][int(np.argmax(np.abs(eops[second][:3] - eops[first][:3])))] = True
    rows = ["# image_id camera_id X0 Y0 Z0 omega phi kappa (deg) sX0 sY0 sZ0 somega sphi "
            "skappa (0 fixed, - free); from COLMAP's images (world-to-camera q, t; in a rig "
            "its frame's then its camera's)"]
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
    project_file.write_text(project_toml(
        name, "pixel", files,
        {"sigma0": 1.0, "image_sigma": float(image_sigma), "max_iterations": 100},
        comment=[f"COLMAP model {pathlib.Path(colmap_dir).name} as a jaxba project."],
        notes={"image_sigma": "pixel"}), encoding="utf-8")
    return ColmapProject(project_file, len(used_cameras), len(used_images),
                         len(observed_points), len(observations), len(rigs.rigs),
                         len(set(rigs.frames.values())))


def _write_cameras(path: pathlib.Path, model, used_cameras: set[int],
                   free: Mapping[str, Sequence[str]] | None) -> None:
    lines = [
        "# From COLMAP's cameras: pixel coordinates shifted by -0.5 (COLMAP's origin is the",
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
    path.write_text("\n".join(lines))


def _write_rigs(out_dir: pathlib.Path, rigs: ImportedRigs, names: Mapping[int, str]) -> None:
    """rigs.toml (every camera's pose in the rig free, as COLMAP's bundle adjuster refines
    it; left out where COLMAP does not know it) and the frames table."""
    lines = ["# From COLMAP's rigs: each camera's sensor_from_rig relative to the reference"]
    for rig_id, (reference, mounts) in rigs.rigs.items():
        lines += [f"[rig{rig_id}]", f'reference = "{reference}"']
        for camera, mount in mounts.items():
            lines.append(f"[rig{rig_id}.{camera}]")
            if mount is not None:
                values = np.r_[mount[:3], np.degrees(mount[3:])]
                lines += [f"{n} = {float(v)!r}" for n, v in zip(MOUNT_NAMES, values)]
            lines.append(f"free = {json.dumps(list(MOUNT_NAMES))}")
        lines.append("")
    (out_dir / "rigs.toml").write_text("\n".join(lines))
    clash = {str(fid) for fid in rigs.frames.values()} & set(names.values())
    prefix = "frame" if clash else ""
    rows = ["# image_id frame_id: from COLMAP's frames"]
    rows += [f"{names[iid]} {prefix}{fid}" for iid, fid in rigs.frames.items()]
    (out_dir / "frames.txt").write_text("\n".join(rows) + "\n")
