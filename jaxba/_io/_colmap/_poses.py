"""COLMAP's poses and jaxba's (docs/conventions.md), in NumPy.

COLMAP's pose (q, t) maps a frame into a camera's: x_cam = R(q) x + t, q = (w, x, y, z) a
Hamilton unit quaternion, the camera frame x right, y down, looking along +z (OpenCV's).
jaxba's photogrammetric camera frame is F = diag(1, -1, -1) of it.

- An image's cam_from_world, and a frame's rig_from_world (the rig frame is the reference
  camera's): M = F R, X0 = -Rᵀ t (`colmap_pose_to_eop`).
- A rig camera's sensor_from_rig maps the reference camera's OpenCV frame into its own, so
  in jaxba's frames M_k = F R F and its perspective centre in the rig frame b = -F Rᵀ t
  (`sensor_from_rig_to_mount`). Composed: M = M_k M_f = F R_s R_f and X0 = X0_f + M_fᵀ b:
  COLMAP's cam_from_world = sensor_from_rig ∘ rig_from_world.
"""

from collections.abc import Sequence

import numpy as np

from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix

FLIP = np.diag([1.0, -1.0, -1.0])  # COLMAP's (OpenCV's) camera frame <-> jaxba's

Rigid = tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)): x -> R x + t


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


def rigid(qvec: Sequence[float], tvec: Sequence[float]) -> Rigid:
    """COLMAP's (q, t) as (R, t)."""
    return quaternion_to_matrix(qvec), np.asarray(tvec, dtype=float)


def compose(a: Rigid, b: Rigid) -> Rigid:
    """a ∘ b: b, then a."""
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def inverse(a: Rigid) -> Rigid:
    return a[0].T, -a[0].T @ a[1]


def colmap_pose_to_eop(qvec: Sequence[float], tvec: Sequence[float]) -> np.ndarray:
    """COLMAP's world-to-camera (q, t) -> jaxba EOPs (X0, Y0, Z0, omega, phi, kappa [rad])."""
    return rigid_to_eop(rigid(qvec, tvec))


def rigid_to_eop(pose: Rigid) -> np.ndarray:
    """A world-to-camera (R, t) in COLMAP's camera frame -> jaxba EOPs (radians)."""
    rotation, translation = pose
    return np.r_[-rotation.T @ translation, matrix_to_opk(FLIP @ rotation)]


def eop_to_colmap_pose(eop: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """jaxba EOPs (X0, Y0, Z0, omega, phi, kappa [rad]) -> COLMAP's (q (w ≥ 0), t)."""
    eop = np.asarray(eop, dtype=float)
    rotation = FLIP @ opk_to_matrix(eop[3:])
    return matrix_to_quaternion(rotation), -rotation @ eop[:3]


def sensor_from_rig_to_mount(pose: Rigid) -> np.ndarray:
    """COLMAP's sensor_from_rig (R, t) -> jaxba's pose in the rig (X0, Y0, Z0, omega, phi,
    kappa [rad]; rigs.toml's, the angles in radians)."""
    rotation, translation = pose
    return np.r_[-FLIP @ rotation.T @ translation, matrix_to_opk(FLIP @ rotation @ FLIP)]


def mount_to_sensor_from_rig(mount: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """jaxba's pose in the rig (X0, Y0, Z0, omega, phi, kappa [rad]) -> COLMAP's
    sensor_from_rig (q (w ≥ 0), t)."""
    mount = np.asarray(mount, dtype=float)
    rotation = FLIP @ opk_to_matrix(mount[3:]) @ FLIP
    return matrix_to_quaternion(rotation), -rotation @ FLIP @ mount[:3]

