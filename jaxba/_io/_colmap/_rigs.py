"""COLMAP's rigs and frames and jaxba's (docs/project-files.md, "Rigs").

COLMAP -> jaxba: a rig of two cameras or more is a jaxba rig; its reference sensor's camera
is the reference (where the reference sensor is no camera, the first camera whose
sensor_from_rig is known), every other camera's pose relative to it its pose in the rig; the
images of a frame share the frame's pose, so an image's pose is its camera's sensor_from_rig
after its frame's rig_from_world. Sensors that are no camera (an IMU) take no images: they
are left out, and said so. A rig of one camera is no rig: its frames are its images.

jaxba -> COLMAP: every rig whose reference camera is exported is a COLMAP rig (the others'
poses in the rig as sensor_from_rig), every other camera a rig of its own; every frame of a
rig is a COLMAP frame (its pose rig_from_world), every other image a frame of its own. COLMAP
reads a model with rigs only if every image is in a frame of a rig of its camera.
"""

import dataclasses
from collections.abc import Mapping

import numpy as np

from ._model import CAMERA, ColmapFrame, ColmapModel, ColmapRig
from ._poses import (
    Rigid,
    colmap_pose_to_eop,
    compose,
    eop_to_colmap_pose,
    inverse,
    mount_to_sensor_from_rig,
    rigid,
    rigid_to_eop,
    sensor_from_rig_to_mount,
)

_IDENTITY: Rigid = (np.eye(3), np.zeros(3))


@dataclasses.dataclass(frozen=True)
class ImportedRigs:
    """COLMAP's rigs and frames as jaxba's (radians; COLMAP's ids).

    - `poses`: IMAGE_ID -> the image's EOPs (6,): composed from its frame's pose and its
      camera's in the rig where COLMAP knows that, else images.txt's;
    - `rigs`: RIG_ID -> (the reference CAMERA_ID, {CAMERA_ID: its pose in the rig (6,), None
      where COLMAP does not know it}) of the rigs of two used cameras or more;
    - `frames`: IMAGE_ID -> FRAME_ID of the used images of those rigs' cameras;
    - `skipped`: what was left out (sensors that are no camera), one message each.
    """

    poses: dict[int, np.ndarray]
    rigs: dict[int, tuple[int, dict[int, np.ndarray | None]]]
    frames: dict[int, int]
    skipped: list[str]


def imported_rigs(model: ColmapModel, used_images: set[int]) -> ImportedRigs:
    """The rigs and frames of `model` over its images `used_images` (module docstring)."""
    poses = {iid: colmap_pose_to_eop(image.qvec, image.tvec)
             for iid, image in model.images.items()}
    used_cameras = {model.images[iid].camera_id for iid in used_images}
    skipped, sensor_poses, rigs = [], {}, {}
    for rig in model.rigs.values():
        sensors = [(rig.reference, _IDENTITY),
                   *((s, None if pose is None else rigid(*pose)) for s, pose in rig.sensors)]
        others = [f"{kind} {sid}" for (kind, sid), _ in sensors if kind != CAMERA]
        if others:
            skipped.append(f"rig {rig.id}: sensor {', '.join(others)} left out: jaxba's rigs "
                           "are of cameras")
        cameras = {sid: pose for (kind, sid), pose in sensors if kind == CAMERA}
        sensor_poses[rig.id] = cameras
        cameras = {sid: pose for sid, pose in cameras.items() if sid in used_cameras}
        if len(cameras) < 2:
            continue
        known = [sid for sid, pose in cameras.items() if pose is not None]
        reference = known[0] if known else next(iter(cameras))
        to_reference = None if cameras[reference] is None else inverse(cameras[reference])
        rigs[rig.id] = (reference, {
            sid: None if pose is None or to_reference is None
            else sensor_from_rig_to_mount(compose(pose, to_reference))
            for sid, pose in cameras.items() if sid != reference})
    frames = {}
    in_rigs = {sid for _, mounts in rigs.values() for sid in mounts} | {
        reference for reference, _ in rigs.values()}
    for frame in model.frames.values():
        rig_from_world = rigid(frame.qvec, frame.tvec)
        for kind, sid, iid in frame.data:
            if kind != CAMERA:
                continue
            pose = sensor_poses[frame.rig_id][sid]
            if pose is not None:
                poses[iid] = rigid_to_eop(compose(pose, rig_from_world))
            if sid in in_rigs and iid in used_images:
                frames[iid] = frame.id
    return ImportedRigs(poses, rigs, frames, skipped)


def colmap_rigs(rigs: Mapping[str, tuple[str, Mapping[str, np.ndarray]]],
                images: Mapping[str, tuple[str, str, np.ndarray]],
                frame_poses: Mapping[str, np.ndarray], camera_numbers: Mapping[str, int],
                image_numbers: Mapping[str, int]) -> tuple[dict[int, ColmapRig],
                                                           dict[int, ColmapFrame]]:
    """COLMAP's rigs and frames (module docstring) of the exported cameras `camera_numbers`
    (camera ID -> CAMERA_ID) and images `image_numbers` (image ID -> IMAGE_ID).

    - `rigs`: rig ID -> (its reference camera, {camera: its pose in the rig (6,), radians});
    - `images`: image ID -> (camera, frame ID (the image's own where it is in no frame), its
      pose (6,), radians) of every exported image;
    - `frame_poses`: frame ID -> its pose (6,), radians.
    """
    colmap, rig_number, rig_of = {}, {}, {}
    for rig, (reference, mounts) in rigs.items():
        if reference not in camera_numbers:
            continue
        number = len(colmap) + 1
        sensors = []
        for camera, mount in mounts.items():
            if camera in camera_numbers:
                q, t = mount_to_sensor_from_rig(mount)
                sensors.append(((CAMERA, camera_numbers[camera]), (_floats(q), _floats(t))))
                rig_of[camera] = rig
        colmap[number] = ColmapRig(number, (CAMERA, camera_numbers[reference]), tuple(sensors))
        rig_number["rig", rig], rig_of[reference] = number, rig
    for camera, camera_number in camera_numbers.items():
        if camera not in rig_of:
            number = len(colmap) + 1
            colmap[number] = ColmapRig(number, (CAMERA, camera_number), ())
            rig_number["camera", camera] = number
    members: dict[tuple, list] = {}
    frame_rig, frame_pose = {}, {}
    for iid, (camera, frame, pose) in images.items():
        rigged = camera in rig_of
        key = ("rig", rig_of[camera], frame) if rigged else ("image", iid)
        if key not in members:
            members[key] = []
            frame_rig[key] = rig_number[("rig", rig_of[camera]) if rigged else ("camera", camera)]
            frame_pose[key] = frame_poses[frame] if rigged else pose
        members[key].append((CAMERA, camera_numbers[camera], image_numbers[iid]))
    frames = {}
    for number, (key, data) in enumerate(members.items(), start=1):
        q, t = eop_to_colmap_pose(frame_pose[key])
        frames[number] = ColmapFrame(number, frame_rig[key], _floats(q), _floats(t), tuple(data))
    return colmap, frames


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)
