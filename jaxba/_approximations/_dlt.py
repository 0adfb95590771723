"""The 3D direct linear transformation (DLT) and its decomposition into interior and exterior
orientation (seed chapter 7/8: "Direct Linear Transformation"; Hartley & Zisserman,
"Multiple View Geometry", 2nd ed., sections 4.4 and 6.2).

    x = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
    y = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)

In homogeneous form (x, y, 1) ∝ P (X, Y, Z, 1) with the 3x4 matrix P, which in jaxba's
convention (docs/conventions.md) is P ∝ K M [I | -X0] with

    K = [[-c / (1 + A1), -A2 c / ((1 + A1)(1 - A1)), xp],
         [0,              -c / (1 - A1),             yp],
         [0,               0,                         1]]

the interior orientation including jaxba's affinity (Δx = -A1 x̄ + A2 ȳ, Δy = A1 ȳ at the
measured point): the DLT's 11 parameters are exactly c, xp, yp, A1, A2 and the six EOPs.
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import matrix_to_opk
from ._common import (
    as_points,
    check_float64,
    flatness,
    homogeneous,
    normaliser,
    null_vector,
    same_count,
)

COPLANAR_RATIO = 1e-6
"""Object points whose thickness (smallest singular value of the centred points) is below this
fraction of their extent (largest singular value) count as coplanar."""


@dataclasses.dataclass(frozen=True)
class Dlt:
    """A 3D DLT fitted by `dlt`.

    - `matrix` (3, 4): P with (x, y, 1) ∝ P (X, Y, Z, 1), scaled so that its third row's
      first three entries are a unit vector and W = P[2] · (X, Y, Z, 1) < 0 for points in
      front of the camera (W is then the camera-frame depth of jaxba's M (X - X0));
    - `parameters` (11,): L1 .. L11, P divided by P[2, 3] (NaN when the object origin lies in
      the camera's principal plane, P[2, 3] = 0);
    - `residuals` (n, 2): observed - computed image coordinates (image units).
    """

    matrix: np.ndarray
    parameters: np.ndarray
    residuals: np.ndarray


@dataclasses.dataclass(frozen=True)
class DltOrientation:
    """Interior and exterior orientation of a DLT matrix (`decompose_dlt`).

    `c`, `xp`, `yp` in image units; `A1`, `A2` jaxba's affinity (dimensionless, 0 for an
    ideal camera); `eop` (6,): X0, Y0, Z0 (object units), omega, phi, kappa (radians).
    """

    c: float
    xp: float
    yp: float
    A1: float
    A2: float
    eop: np.ndarray


def dlt_matrix(image_points: np.ndarray, object_points: np.ndarray, what: str) -> np.ndarray:
    """P (3, 4) with (x, y, 1) ∝ P (X, 1) by Hartley-normalised homogeneous least squares.

    Both point sets are normalised (centroid 0, mean distance sqrt(2) and sqrt(3)); P̂ is the
    right singular vector of the smallest singular value of the 2n x 12 system
    [X̂ᵀ 0 -x̂ X̂ᵀ; 0 X̂ᵀ -ŷ X̂ᵀ], then P = T_image⁻¹ P̂ T_object. Sign and scale are arbitrary.
    """
    t_image, t_object = normaliser(image_points), normaliser(object_points)
    x = homogeneous(image_points) @ t_image.T
    big_x = homogeneous(object_points) @ t_object.T
    zeros = np.zeros_like(big_x)
    rows = np.r_[np.c_[big_x, zeros, -x[:, :1] * big_x], np.c_[zeros, big_x, -x[:, 1:2] * big_x]]
    p = null_vector(rows, what, "the points do not determine the 11 parameters; they lie "
                    "(nearly) on a plane or on a twisted cubic with the camera").reshape(3, 4)
    return np.linalg.inv(t_image) @ p @ t_object


def _in_front(p: np.ndarray, object_points: np.ndarray) -> np.ndarray:
    """P scaled to a unit third row (first three entries) and signed so that the points have
    W = P[2] · (X, 1) < 0 (in front of a camera that looks along -z)."""
    p = p / np.linalg.norm(p[2, :3])
    depth = homogeneous(object_points) @ p[2]
    return -p if np.median(depth) > 0 else p


def dlt(image_points, object_points) -> Dlt:
    """The 3D DLT of one image from >= 6 non-coplanar points: 11 parameters, exact for
    noise-free data of a distortion-free camera (with affinity).

    Arguments:
    - `image_points` (n, 2): image coordinates (any 2D unit, e.g. mm or pixels; distortion
      already corrected if the camera has any);
    - `object_points` (n, 3): object coordinates (object units).

    Returns a `Dlt` (matrix P, L1..L11, residuals). Raises ValueError for fewer than 6
    points, coplanar points (a plane does not determine the DLT: use `space_resection`) or
    another degenerate configuration. Linear (algebraic) least squares: a start for
    `space_resection` or a bundle, not a rigorous adjustment.
    """
    what = "dlt"
    image_points = as_points(image_points, 2, what, "image_points")
    object_points = as_points(object_points, 3, what, "object_points")
    n = same_count(what, image_points=image_points, object_points=object_points)
    if n < 6:
        raise ValueError(f"{what}: {n} points; the 11 DLT parameters need at least 6 "
                         "non-coplanar points")
    _, singular, _ = flatness(object_points)
    if singular[2] <= COPLANAR_RATIO * singular[0]:
        raise ValueError(f"{what}: the object points are coplanar (thickness / extent "
                         f"{singular[2] / singular[0]:.1e}); a plane does not determine the 11 "
                         "DLT parameters: use space_resection, which takes planar control")
    p = _in_front(dlt_matrix(image_points, object_points, what), object_points)
    projected = homogeneous(object_points) @ p.T
    residuals = image_points - projected[:, :2] / projected[:, 2:]
    parameters = (p.ravel()[:11] / p[2, 3]) if p[2, 3] != 0 else np.full(11, np.nan)
    return Dlt(p, parameters, residuals)


def _rq(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A = R Q with R upper triangular and Q orthogonal (QR of the flipped transpose)."""
    flip = np.eye(3)[::-1]
    q, r = np.linalg.qr((flip @ a).T)
    return flip @ r.T @ flip, flip @ q.T


def decompose_dlt(matrix) -> DltOrientation:
    """Interior orientation (c, xp, yp, A1, A2) and EOPs of a DLT matrix P (3, 4).

    P ∝ K M [I | -X0] (module docstring): X0 = -A⁻¹ b with P = [A | b]; K and M by the RQ
    decomposition of A, with K's diagonal signed (-, -, +) (jaxba's camera looks along -z,
    x = xp - c U / W) and K[2, 2] = 1. With cx = -K11, cy = -K22, s = K12:
    c = 2 cx cy / (cx + cy), A1 = c / cx - 1, A2 = -s c / (cx cy).

    `matrix` is P up to a positive factor, signed as `dlt` returns it (W < 0 in front of the
    camera, det A > 0); the L1..L11 of another program are `np.r_[L, 1].reshape(3, 4)`, up
    to sign. Returns a `DltOrientation` (angles in radians). Raises ValueError for a singular
    or mirroring (det A < 0, wrong sign) matrix.
    """
    check_float64("decompose_dlt")
    what = "decompose_dlt"
    p = np.asarray(matrix, dtype=np.float64)
    if p.shape != (3, 4) or not np.all(np.isfinite(p)):
        raise ValueError(f"{what}: the DLT matrix must be a finite (3, 4) array, got {p.shape}")
    norm = np.linalg.norm(p[2, :3])
    if norm == 0:
        raise ValueError(f"{what}: the DLT matrix's third row is zero (no camera)")
    p = p / norm
    a, b = p[:, :3], p[:, 3]
    determinant = np.linalg.det(a)
    if abs(determinant) <= 1e-12 * np.linalg.norm(a) ** 3:
        raise ValueError(f"{what}: the DLT matrix is singular (no perspective centre)")
    if determinant < 0:
        raise ValueError(f"{what}: the DLT matrix mirrors the image (det < 0): pass it signed "
                         "as dlt returns it (W < 0 for points in front of the camera)")
    station = -np.linalg.solve(a, b)
    k, q = _rq(a)
    signs = np.sign(np.diag(k)) * np.array([-1.0, -1.0, 1.0])
    k, m = k * signs, signs[:, None] * q
    k = k / k[2, 2]
    cx, cy, skew = -k[0, 0], -k[1, 1], k[0, 1]
    c = 2 * cx * cy / (cx + cy)
    return DltOrientation(
        c=float(c), xp=float(k[0, 2]), yp=float(k[1, 2]),
        A1=float(c / cx - 1), A2=float(-skew * c / (cx * cy)),
        eop=np.r_[station, matrix_to_opk(m)],
    )
