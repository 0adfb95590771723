"""Starting values as DBAT computes them before its bundle: a planar resection per image from
the control points (homography by DLT, then the nearest rotation) and a least-squares
intersection of the rays of every other point. Plain NumPy.
"""

import numpy as np


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """H with dst ~ H src (homogeneous 2D points, n ≥ 4) by Hartley-normalised DLT."""

    def normaliser(points):
        centroid = points.mean(axis=0)
        scale = np.sqrt(2) / np.mean(np.linalg.norm(points - centroid, axis=1))
        return np.array([[scale, 0, -scale * centroid[0]], [0, scale, -scale * centroid[1]],
                         [0, 0, 1]])

    t_src, t_dst = normaliser(src), normaliser(dst)
    a = np.c_[src, np.ones(len(src))] @ t_src.T
    b = np.c_[dst, np.ones(len(dst))] @ t_dst.T
    zeros = np.zeros_like(a)
    rows = np.r_[np.c_[a, zeros, -b[:, :1] * a], np.c_[zeros, a, -b[:, 1:2] * a]]
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    return np.linalg.inv(t_dst) @ h @ t_src


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def planar_resection(
    object_points: np.ndarray, image_points: np.ndarray, c: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pose (M, X0) of an image from ≥ 4 coplanar points, distortion-free, principal point 0.

    With the control plane X = o + s e1 + t e2 and (x, y, -c) ∝ M (X - X0) (docs/conventions.md),
    (x/-c, y/-c, 1) ∝ H (s, t, 1) with H ∝ [M e1, M e2, M (o - X0)]; the scale of H makes its
    first two columns unit vectors and puts the points in front of the camera (W < 0).
    """
    origin = object_points.mean(axis=0)
    _, singular, vt = np.linalg.svd(object_points - origin)
    if singular[2] > 1e-6 * singular[0]:
        raise ValueError("planar resection: the control points are not coplanar")
    e1, e2 = vt[0], vt[1]
    e3 = np.cross(e1, e2)
    plane = (object_points - origin) @ np.c_[e1, e2]
    h = _homography(plane, image_points / -c)
    scale = (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1])) / 2
    # M (X - X0) = H (s, t, 1) / scale must have W < 0 (the camera looks along -z).
    if (h @ np.r_[plane[0], 1.0])[2] > 0:
        scale = -scale
    m1, m2, t = h[:, 0] / scale, h[:, 1] / scale, h[:, 2] / scale
    m_plane = _nearest_rotation(np.c_[m1, m2, np.cross(m1, m2)])  # M [e1 e2 e3]
    rotation = m_plane @ np.c_[e1, e2, e3].T
    station = origin - rotation.T @ t
    return rotation, station


def intersect(stations: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to the rays station_i + λ direction_i, (n, 3) each."""
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    projectors = np.eye(3) - units[:, :, None] * units[:, None, :]
    return np.linalg.solve(projectors.sum(axis=0), np.einsum("nij,nj->i", projectors, stations))
