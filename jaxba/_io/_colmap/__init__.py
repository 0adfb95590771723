"""COLMAP models (binary or text; COLMAP 3.12's rigs and frames too) to and from jaxba
projects.

Conventions, and how they map onto jaxba's (docs/conventions.md):

- **Poses.** (q, t) maps world to camera, x_cam = R(q) X + t, in COLMAP's camera frame: x
  right, y down, looking along +z (OpenCV's). jaxba's photogrammetric frame is
  diag(1, -1, -1) of it, so M = diag(1, -1, -1) R(q), X0 = -R(q)ᵀ t, and (omega, phi, kappa)
  are M's angles. q = (qw, qx, qy, qz) is a Hamilton unit quaternion.
- **Rigs.** A frame's rig_from_world is a pose as above (the rig frame is the reference
  camera's); a camera's sensor_from_rig is its pose in the rig, M_k = F R F and X0 = -F Rᵀ t
  with F = diag(1, -1, -1) (`_poses`, `_rigs`).
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

Modules: `_model` (the records), `_poses`, `_cameras`, `_text` and `_binary` (the files),
`_read` (a folder), `_rigs`, `_import` (COLMAP -> project), `_export` (project -> COLMAP).
"""

from ._cameras import PIXEL_ORIGIN_SHIFT, camera_to_colmap, camera_to_jaxba
from ._export import numeric_ids, project_to_colmap, write_colmap
from ._import import ColmapProject, write_colmap_project
from ._model import (
    COLMAP_CAMERA_MODELS,
    ColmapCamera,
    ColmapFrame,
    ColmapImage,
    ColmapModel,
    ColmapPoint,
    ColmapRig,
)
from ._poses import (
    colmap_pose_to_eop,
    eop_to_colmap_pose,
    matrix_to_quaternion,
    mount_to_sensor_from_rig,
    quaternion_to_matrix,
    sensor_from_rig_to_mount,
)
from ._read import read_colmap_model
from ._rigs import colmap_rigs
from ._text import colmap_model_texts, write_colmap_model

__all__ = [
    "COLMAP_CAMERA_MODELS", "PIXEL_ORIGIN_SHIFT", "ColmapCamera", "ColmapFrame", "ColmapImage",
    "ColmapModel", "ColmapPoint", "ColmapProject", "ColmapRig", "camera_to_colmap",
    "camera_to_jaxba", "colmap_model_texts", "colmap_pose_to_eop", "colmap_rigs",
    "eop_to_colmap_pose", "matrix_to_quaternion", "mount_to_sensor_from_rig", "numeric_ids",
    "project_to_colmap", "quaternion_to_matrix", "read_colmap_model", "sensor_from_rig_to_mount",
    "write_colmap", "write_colmap_model", "write_colmap_project",
]
