"""A camera of a rig and the rig's reference camera as OpenCV's stereo pair: R, T, E, F.

jaxba's rig (docs/conventions.md): camera k's pose in the rig frame (the reference camera's
frame) is its perspective centre b (3,) and M (3, 3) from its (omega, phi, kappa), rotating
rig vectors into camera k's frame: p_k = M (p_rig - b), both frames jaxba's (x right, y up,
looking down -z). OpenCV's camera frame is G = diag(1, -1, -1) of jaxba's (x right, y down,
looking along +z), and `cv2.stereoCalibrate`'s (R, T) map camera 1's OpenCV frame to camera
2's, x2 = R x1 + T. With camera 1 the reference (p_rig = G x1) and camera 2 camera k:

    R = G M G,    T = -G M b,    E = [T]x R,    F = K2^-T E K1^-1 / (its [2, 2] entry),

T in object units; F scaled as OpenCV scales it (F[2, 2] = 1 where that entry is not 0).
Plain NumPy; nothing here calls jax.
"""

import numpy as np

from .._models._rotation_numpy import opk_to_matrix

_OPENCV_FRAME = np.diag([1.0, -1.0, -1.0])  # jaxba's camera frame <-> OpenCV's (its own inverse)


def stereo_extrinsics(station, opk_degrees) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), T (3, 1)) of camera 2 relative to the rig's reference camera 1 (module
    docstring) from camera 2's perspective centre `station` (3,) in the rig frame (object
    units) and its (omega, phi, kappa) `opk_degrees` (3,) (rig -> camera, degrees)."""
    rotation = opk_to_matrix(np.radians(np.asarray(opk_degrees, dtype=float)))
    r = _OPENCV_FRAME @ rotation @ _OPENCV_FRAME
    t = -_OPENCV_FRAME @ rotation @ np.asarray(station, dtype=float)
    return r, t.reshape(3, 1)


def essential_matrix(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """E = [T]x R (3, 3): x2ᵀ E x1 = 0 for the normalised points x1, x2 (OpenCV frames) of one
    object point."""
    tx, ty, tz = np.ravel(t)
    cross = np.array([[0.0, -tz, ty], [tz, 0.0, -tx], [-ty, tx, 0.0]])
    return cross @ r


def fundamental_matrix(essential: np.ndarray, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
    """F = K2^-T E K1^-1 (3, 3) for undistorted pixels, scaled to F[2, 2] = 1 where that is not
    0 (as `cv2.stereoCalibrate` returns it)."""
    f = np.linalg.inv(k2).T @ essential @ np.linalg.inv(k1)
    return f / f[2, 2] if f[2, 2] != 0 else f
