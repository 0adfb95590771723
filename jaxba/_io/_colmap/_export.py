"""A jaxba project as a COLMAP model (`project_to_colmap`, `write_colmap`); with rigs, COLMAP's
rigs and frames too (`_rigs.colmap_rigs`)."""

import os
from collections.abc import Sequence

import numpy as np

from ._cameras import JAXBA_PARAMETERS, PIXEL_ORIGIN_SHIFT, camera_to_colmap
from ._model import ColmapCamera, ColmapImage, ColmapModel, ColmapPoint
from ._poses import eop_to_colmap_pose
from ._rigs import colmap_rigs
from ._text import write_colmap_model


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
    +0.5 (the package's docstring). RGB is written as 0 0 0 and ERROR as -1 (jaxba keeps
    neither). With rigs, every image's pose is its frame's then its camera's in the rig, and
    the model has COLMAP's rigs and frames.
    """
    if project.spec.image_units != "pixel":
        raise ValueError(f"{project.spec.name}: only image_units = \"pixel\" projects export "
                         "to COLMAP")
    parameters = project.problem.initial if parameters is None else parameters
    camera_ids = numeric_ids(list(project.camera_rows))
    cameras = {}
    for camera_id, (model, row) in project.camera_rows.items():
        names = JAXBA_PARAMETERS.get(model, ())
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

    layout = project.rigs
    if layout is not None:  # jax's: the package stays plain NumPy for `jaxba export`'s checks
        from ..._statistics._rigs import composed_poses
    eops = (np.asarray(parameters.images, dtype=float) if layout is None else
            composed_poses(parameters, project.problem.pose, layout.image_frame,
                           layout.image_mount))
    images = {}
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
    if layout is None or not project.spec.rigs:
        return ColmapModel(cameras, images, points)
    frames = np.asarray(parameters.images, dtype=float)
    mounts = np.asarray(parameters.mounts, dtype=float)
    row_of = {owner: row for row, owner in enumerate(layout.mount_cameras) if owner is not None}
    rigs = {rig: (spec.reference, {camera: mounts[row_of[rig, camera]] for camera in spec.mounts})
            for rig, spec in project.spec.rigs.items()}
    image_rows = {iid: (project.spec.images[iid].camera, layout.frame_ids[layout.image_frame[k]],
                        eops[k]) for k, iid in enumerate(project.image_ids)}
    colmap_rig_table, colmap_frames = colmap_rigs(
        rigs, image_rows, dict(zip(layout.frame_ids, frames)), camera_ids, image_numbers)
    return ColmapModel(cameras, images, points, colmap_rig_table, colmap_frames)


def write_colmap(project, out_dir: str | os.PathLike, parameters=None) -> ColmapModel:
    """Export a project (e.g. `adjust_project(project).parameters`) as COLMAP text into
    `out_dir`; see `project_to_colmap`. Returns the model written."""
    model = project_to_colmap(project, parameters)
    write_colmap_model(model, out_dir)
    return model
