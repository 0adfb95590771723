"""Space resection: the six EOPs of one image from control points and a known camera (seed
chapter 8 and the stereo lecture's "Exterior orientation by space resection").

A closed-form start (the calibrated DLT for non-planar control, a plane-to-image homography
for planar control) refined by least squares on the collinearity equations (docs/conventions.md)

    x = xp - c U / W,   y = yp - c V / W,   (U, V, W) = M(omega, phi, kappa) (X - X0)

with the measured coordinates corrected for distortion first (a `correction` callable, or
coordinates the caller already corrected).
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_derivatives, opk_to_matrix
from ._common import (
    Correction,
    Fit,
    as_points,
    check_float64,
    check_principal_distance,
    covariance,
    flatness,
    homogeneous,
    levenberg_marquardt,
    nearest_rotation,
    normaliser,
    null_vector,
    per_item,
    reduced_coordinates,
    same_count,
    wrap_angles,
)
from ._dlt import COPLANAR_RATIO, dlt_matrix

EOP_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
COLLINEAR_RATIO = 1e-6
"""Control points whose second singular value (centred) is below this fraction of the first
count as collinear: they do not determine the roll about their line."""


@dataclasses.dataclass(frozen=True)
class Resection:
    """The exterior orientation of one image found by `space_resection`.

    - `eop` (6,): X0, Y0, Z0 (object units), omega, phi, kappa (radians), jaxba's images row;
    - `covariance` (6, 6): Cxx of `eop` in the same order and units (a posteriori σ̂0² (AᵀA)⁻¹
      σ², or a priori σ² (AᵀA)⁻¹, see `space_resection`); `sigma` (6,) its square roots;
    - `variance_factor`: σ̂0² = vᵀv / (σ² r) (NaN without redundancy);
    - `residuals` (n, 2): v = observed - computed image coordinates (image units, of the
      corrected coordinates); `redundancy` r = 2n - 6;
    - `start` (6,): the closed-form EOPs the refinement started from;
    - `iterations`, `converged`: of the least-squares refinement.
    """

    eop: np.ndarray
    covariance: np.ndarray
    variance_factor: float
    residuals: np.ndarray
    redundancy: int
    start: np.ndarray
    iterations: int
    converged: bool

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def rotation(self) -> np.ndarray:
        """M = R_m^c (3, 3) of `eop`."""
        return opk_to_matrix(self.eop[3:])


def collinearity(
    eop: np.ndarray, object_points: np.ndarray, c: float
) -> tuple[np.ndarray, np.ndarray]:
    """Computed reduced coordinates -c (U, V) / W (n, 2) and their Jacobian by the six EOPs
    (n, 2, 6), docs/conventions.md with jaxba's rotation."""
    m, dm = opk_to_matrix(eop[3:]), opk_derivatives(eop[3:])
    d = object_points - eop[:3]
    uvw = d @ m.T
    u, v, w = uvw.T
    computed = -c * uvw[:, :2] / w[:, None]
    # d computed / d (U, V, W): -c [[1/W, 0, -U/W²], [0, 1/W, -V/W²]].
    d_uvw = np.zeros((len(d), 2, 3))
    d_uvw[:, 0, 0] = d_uvw[:, 1, 1] = -c / w
    d_uvw[:, 0, 2] = c * u / w**2
    d_uvw[:, 1, 2] = c * v / w**2
    d_station = -m  # d (U, V, W) / d X0
    d_angles = np.einsum("ijk,nj->nik", dm, d)  # d (U, V, W) / d angle_k
    jacobian = np.concatenate(
        [d_uvw @ d_station, np.einsum("nij,njk->nik", d_uvw, d_angles)], axis=2)
    return computed, jacobian


def _calibrated_dlt(normalised: np.ndarray, object_points: np.ndarray, what: str) -> np.ndarray:
    """EOPs from the DLT of calibrated coordinates (U/W, V/W) ∝ [M | -M X0] (X, 1): M is the
    rotation nearest to A / s (s the mean singular value of A, signed so that W < 0)."""
    p = dlt_matrix(normalised, object_points, what)
    a, b = p[:, :3], p[:, 3]
    scale = np.mean(np.linalg.svd(a, compute_uv=False))
    if np.median(homogeneous(object_points) @ p[2]) > 0:
        scale = -scale
    m = nearest_rotation(a / scale)
    return np.r_[-m.T @ b / scale, matrix_to_opk(m)]


def _plane_homography(normalised: np.ndarray, object_points: np.ndarray,
                      what: str) -> np.ndarray:
    """EOPs from the homography of the (best-fitting) control plane X = o + s e1 + t e2 to the
    calibrated coordinates: (U/W, V/W, 1) ∝ H (s, t, 1) with H ∝ [M e1, M e2, M (o - X0)]; the
    scale makes H's first two columns unit vectors, its sign puts the points in front (W < 0).
    """
    origin, _, axes = flatness(object_points)
    e1, e2 = axes[0], axes[1]
    e3 = np.cross(e1, e2)
    plane = (object_points - origin) @ np.c_[e1, e2]
    t_plane, t_image = normaliser(plane), normaliser(normalised)
    src, dst = homogeneous(plane) @ t_plane.T, homogeneous(normalised) @ t_image.T
    zeros = np.zeros_like(src)
    rows = np.r_[np.c_[src, zeros, -dst[:, :1] * src], np.c_[zeros, src, -dst[:, 1:2] * src]]
    h = null_vector(rows, what, "the control points do not determine the plane's homography")
    h = np.linalg.inv(t_image) @ h.reshape(3, 3) @ t_plane
    scale = (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1])) / 2
    if np.median(homogeneous(plane) @ h[2]) > 0:
        scale = -scale
    m1, m2, t = h[:, 0] / scale, h[:, 1] / scale, h[:, 2] / scale
    m = nearest_rotation(np.c_[m1, m2, np.cross(m1, m2)]) @ np.c_[e1, e2, e3].T
    return np.r_[origin - m.T @ t, matrix_to_opk(m)]


def closed_form_resection(
    reduced: np.ndarray, object_points: np.ndarray, c: float, what: str
) -> np.ndarray:
    """Starting EOPs (6,) from reduced, corrected image coordinates (n, 2), n >= 4.

    Candidates: the plane homography (always, on the best-fitting plane) and, for >= 6
    non-coplanar points, the calibrated DLT; the one with the smaller image residuals wins.
    """
    normalised = reduced / -c  # (U/W, V/W)
    _, singular, _ = flatness(object_points)
    if singular[1] <= COLLINEAR_RATIO * singular[0]:
        raise ValueError(f"{what}: the control points are collinear (or coincide); they do not "
                         "determine the rotation about their line")
    candidates = [_plane_homography(normalised, object_points, what)]
    if len(reduced) >= 6 and singular[2] > COPLANAR_RATIO * singular[0]:
        try:
            candidates.append(_calibrated_dlt(normalised, object_points, what))
        except ValueError:
            pass  # a degenerate DLT: the plane's start remains

    def misfit(eop):
        computed, _ = collinearity(eop, object_points, c)
        value = np.sum((reduced - computed) ** 2)
        return value if np.isfinite(value) else np.inf

    return min(candidates, key=misfit)


def space_resection(
    image_points,
    object_points,
    c: float,
    *,
    principal_point=(0.0, 0.0),
    correction: Correction | None = None,
    start=None,
    sigma: float = 1.0,
    a_posteriori: bool = True,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
) -> Resection:
    """The EOPs of one image from >= 4 control points (>= 3 with a `start`), planar or not.

    Least squares on the collinearity equations (module docstring) with the interior
    orientation known, started from a closed form (`start` None) or from `start`.

    Arguments:
    - `image_points` (n, 2): measured image coordinates (image units, mm in jaxba's image
      frame: origin at the image centre, x right, y up);
    - `object_points` (n, 3): the control points' object coordinates (object units);
    - `c`: principal distance (image units, > 0); `principal_point` (2,): xp, yp;
    - `correction`: callable mapping measured (n, 2) coordinates to distortion-free ones
      (e.g. x - dist(x - xp) for jaxba's SMAC camera, whose corrections are evaluated at the
      measured point); None when the coordinates are already corrected;
    - `start` (6,): EOPs (object units, radians) to start from instead of the closed form;
    - `sigma`: a priori σ of an image coordinate (image units); `a_posteriori`: scale the
      covariance by σ̂0² (True) or take σ0 = 1 (False, e.g. with little redundancy);
    - `max_iterations`, `tolerance`: of the Levenberg-Marquardt refinement (relative step).

    Returns a `Resection` (EOPs as a jaxba images row, covariance, residuals). Raises
    ValueError for too few or collinear points, a non-positive c or bad shapes.
    """
    check_float64("space_resection")
    what = "space_resection"
    image_points = as_points(image_points, 2, what, "image_points")
    object_points = as_points(object_points, 3, what, "object_points")
    n = same_count(what, image_points=image_points, object_points=object_points)
    check_principal_distance(c, what)
    c = float(c)
    principal_point = per_item(principal_point, 1, (2,), what, "principal_point")[0]
    if n < 3 or (start is None and n < 4):
        raise ValueError(f"{what}: {n} control points; need at least 4 for a closed-form start "
                         "(6 for the non-planar DLT), or 3 with a start")
    reduced = reduced_coordinates(image_points, principal_point, correction)
    if start is None:
        start = closed_form_resection(reduced, object_points, c, what)
    else:
        start = per_item(start, 1, (6,), what, "start")[0]

    def model(eop):
        computed, jacobian = collinearity(eop, object_points, c)
        return (reduced - computed).ravel() / sigma, jacobian.reshape(-1, 6) / sigma

    fit = levenberg_marquardt(model, start, max_iterations=max_iterations, tolerance=tolerance)
    return _resection(fit, start, 2 * n - 6, sigma, a_posteriori)


def _resection(fit: Fit, start: np.ndarray, redundancy: int, sigma: float,
               a_posteriori: bool) -> Resection:
    cxx, variance_factor = covariance(fit, redundancy, a_posteriori=a_posteriori)
    eop = fit.x.copy()
    eop[3:] = wrap_angles(eop[3:])
    return Resection(
        eop=eop, covariance=cxx, variance_factor=variance_factor,
        residuals=fit.residuals.reshape(-1, 2) * sigma, redundancy=redundancy,
        start=start, iterations=fit.iterations, converged=fit.converged,
    )
