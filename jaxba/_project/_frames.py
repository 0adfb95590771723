"""A project's rigs as blocks: the images block holds one pose per frame, the mounts block one
relative pose per rig camera (`Parameters.mounts`), and every image its frame and mount.

Approximations: a frame's pose is its reference camera's image's (else another member's,
moved back through that camera's mount); a mount's values are rigs.toml's where given, else
the mean relative pose of its camera over the frames that hold an image of it and one of the
reference camera (rotations averaged by the SVD projection of their mean onto SO(3)).

A camera on a GNSS/INS platform (`CameraSpec.mount`) is the same mechanism: each of its images
is a frame of its own, the body's pose (the images table's values and GNSS/INS σ are the
body's), followed by the camera's lever arm and boresight, a mount row "platform/<camera>".
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from ._errors import ProjectError
from ._spec import MOUNT_NAMES, ProjectSpec

# The identity mount (row 0): every rig's reference camera and every image outside a rig.
REFERENCE_MOUNT = "reference"
PLATFORM = "platform"  # the "rig" of a camera on a GNSS/INS platform


@dataclasses.dataclass(frozen=True)
class RigLayout:
    """Frames and mounts of a project (angles in radians).

    - `frame_ids`: the rows of the images block; `frames`, `frame_free`, `frame_sigma`
      (n_frames, 6) their approximations, free mask and GNSS/INS σ (inf: none);
    - `mount_ids`: the rows of the mounts block ("reference", then "<rig>/<camera>", then
      "platform/<camera>"); `mount_cameras` (rig or "platform", camera) per row (None for
      "reference"); `mounts`, `mount_free`,
      `mount_sigma` (n_mounts, 6) as for frames (σ: rigs.toml's priors);
    - `image_frame`, `image_mount` (n_images,): every image's rows, in the images table's
      order.
    """

    frame_ids: list[str]
    frames: np.ndarray
    frame_free: np.ndarray
    frame_sigma: np.ndarray
    mount_ids: list[str]
    mount_cameras: list[tuple[str, str] | None]
    mounts: np.ndarray
    mount_free: np.ndarray
    mount_sigma: np.ndarray
    image_frame: np.ndarray
    image_mount: np.ndarray


def rig_layout(spec: ProjectSpec, image_ids: list[str], eop: np.ndarray, free: np.ndarray,
               sigma: np.ndarray) -> RigLayout:
    """The frames and mounts of `spec` from every image's approximation `eop`, free mask and
    σ (n_images, 6; radians). GNSS/INS observations and fixed EOPs go to the frame where the
    reference camera took the image, or where a platform's camera did (the body's); on
    another rig camera's image they are refused."""
    mount_ids, cameras, mount_of = [REFERENCE_MOUNT], [None], {}
    for rig in spec.rigs.values():
        for camera in rig.mounts:
            mount_of[camera] = len(mount_ids)
            mount_ids.append(f"{rig.id}/{camera}")
            cameras.append((rig.id, camera))
    in_rigs = {camera for rig in spec.rigs.values() for camera in rig.cameras}
    for camera in (c for c in spec.cameras.values() if c.mount is not None):
        if camera.id in in_rigs:
            raise ProjectError(f"camera {camera.id!r} is in a rig and has a [{camera.id}.mount]"
                               " on a GNSS/INS platform: one or the other")
        mount_of[camera.id] = len(mount_ids)
        mount_ids.append(f"{PLATFORM}/{camera.id}")
        cameras.append((PLATFORM, camera.id))
    frame_of = [spec.frames.get(iid, iid) for iid in image_ids]
    frame_ids = list(dict.fromkeys(frame_of))
    frame_row = {fid: k for k, fid in enumerate(frame_ids)}
    image_frame = np.array([frame_row[f] for f in frame_of], dtype=int)
    image_mount = np.array([mount_of.get(spec.images[iid].camera, 0) for iid in image_ids],
                           dtype=int)
    on_platform = np.array([cameras[m] is not None and cameras[m][0] == PLATFORM
                            for m in image_mount], dtype=bool)
    for k in np.flatnonzero((image_mount > 0) & ~on_platform):
        if not (free[k].all() and np.isinf(sigma[k]).all()):
            image = spec.images[image_ids[k]]
            raise ProjectError(
                f"{spec.file_names.get('images', 'images')}:{image.line}: image {image.id!r} "
                f"of rig camera {image.camera!r} has fixed or observed EOPs; its pose is its "
                "frame's and its camera's in the rig: give them on the reference camera's image")
    mounts = _mount_values(spec, cameras, eop, image_frame, image_mount)
    frames = np.zeros((len(frame_ids), 6))
    frame_free = np.ones((len(frame_ids), 6), dtype=bool)
    frame_sigma = np.full((len(frame_ids), 6), np.inf)
    # Reference images last: where a frame has one, its pose and states win.
    for k in np.argsort(image_mount == 0, kind="stable"):
        row = image_frame[k]
        frames[row] = (eop[k] if on_platform[k]  # the body's pose, as GNSS/INS give it
                       else _frame_from_image(eop[k], mounts[image_mount[k]]))
        frame_free[row], frame_sigma[row] = free[k], sigma[k]
    mount_free = np.zeros((len(mount_ids), 6), dtype=bool)
    mount_sigma = np.full((len(mount_ids), 6), np.inf)
    for row, (rig, camera) in enumerate(cameras[1:], start=1):
        mount = _mount_spec(spec, rig, camera)
        for j, name in enumerate(MOUNT_NAMES):
            mount_free[row, j] = name in mount.free or name in mount.sigma
            given = mount.sigma.get(name, np.inf)
            mount_sigma[row, j] = np.radians(given) if j >= 3 else given
    return RigLayout(frame_ids, frames, frame_free, frame_sigma, mount_ids, cameras, mounts,
                     mount_free, mount_sigma, image_frame, image_mount)


def _frame_from_image(image: np.ndarray, mount: np.ndarray) -> np.ndarray:
    """The frame pose whose composition with `mount` is the image's pose `image` (radians):
    M_f = M_cᵀ M, X0_f = X0 - M_fᵀ X0_c."""
    rotation = opk_to_matrix(mount[3:]).T @ opk_to_matrix(image[3:])
    return np.concatenate([image[:3] - rotation.T @ mount[:3], matrix_to_opk(rotation)])


def _mount_values(spec, cameras, eop, image_frame, image_mount) -> np.ndarray:
    """(n_mounts, 6) approximations of the mounts (module docstring); row 0 the identity."""
    mounts = np.zeros((len(cameras), 6))
    for row, (rig, camera) in enumerate(cameras[1:], start=1):
        given = _mount_spec(spec, rig, camera).values
        values = np.array([np.nan if given[n] is None else given[n] for n in MOUNT_NAMES])
        values[3:] = np.radians(values[3:])
        if np.isnan(values).any():
            estimate = _mean_relative_pose(spec, rig, eop, image_frame, image_mount == row)
            if estimate is None:
                raise ProjectError(
                    f"{spec.file_names.get('rigs', 'rigs')}: [{rig}.{camera}]: no frame holds "
                    f"an image of {camera!r} and one of the reference camera "
                    f"{spec.rigs[rig].reference!r}: give its pose in the rig (X0 .. kappa)")
            values = np.where(np.isnan(values), estimate, values)
        mounts[row] = values
    return mounts


def _mount_spec(spec: ProjectSpec, rig: str, camera: str):
    """The `MountSpec` of `camera` in `rig` (rigs.toml), or of its platform (cameras.toml)."""
    return spec.cameras[camera].mount if rig == PLATFORM else spec.rigs[rig].mounts[camera]


def _mean_relative_pose(spec, rig: str, eop, image_frame, of_camera) -> np.ndarray | None:
    """The mean pose of a camera (`of_camera` marks its images) relative to `rig`'s
    reference camera over the frames with both, or None where none has both."""
    reference = spec.rigs[rig].reference
    camera_of = [image.camera for image in spec.images.values()]
    by_frame = {image_frame[k]: k for k, c in enumerate(camera_of) if c == reference}
    rotations, centres = [], []
    for k in np.flatnonzero(of_camera):
        if image_frame[k] in by_frame:
            ref = eop[by_frame[image_frame[k]]]
            m_ref = opk_to_matrix(ref[3:])
            rotations.append(opk_to_matrix(eop[k, 3:]) @ m_ref.T)
            centres.append(m_ref @ (eop[k, :3] - ref[:3]))
    if not rotations:
        return None
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    rotation = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    return np.concatenate([np.mean(centres, axis=0), matrix_to_opk(rotation)])
