"""Forward (space) intersection: an object point from its image points in n >= 2 oriented images
(seed chapter 8, "Stereo photogrammetry": two rays, four equations, three unknowns).

Each image point defines the ray X0_i + λ Mᵢᵀ (x̄, ȳ, -c) (λ > 0, docs/conventions.md). The closed
form is the point nearest to all rays in least squares; the refinement minimises the image
residuals of the collinearity equations over the point's three coordinates.
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import opk_to_matrix
from ._common import (
    Correction,
    Fit,
    as_points,
    check_float64,
    check_principal_distance,
    covariance,
    image_rays,
    levenberg_marquardt,
    per_item,
    reduced_coordinates,
    same_count,
)

PARALLEL_RATIO = 1e-12
"""Rays count as parallel when the smallest eigenvalue of Σ (I - dᵢdᵢᵀ) is below this fraction
of the largest (for two rays, an intersection angle below about 1.4e-6 rad)."""


@dataclasses.dataclass(frozen=True)
class Intersection:
    """An object point found by `forward_intersection`.

    - `point` (3,): X, Y, Z (object units);
    - `covariance` (3, 3): its Cxx from the collinearity equations at `point` (σ̂0² σ² (AᵀA)⁻¹,
      or σ² (AᵀA)⁻¹ a priori); `sigma` (3,) the square roots of its diagonal;
    - `variance_factor`: σ̂0² = vᵀv / (σ² r), r = 2n - 3; `residuals` (n, 2): v = observed -
      computed image coordinates (image units); `closest` (3,): the closed-form point nearest
      to the rays; `iterations`, `converged`: of the refinement (0 and True without one).
    """

    point: np.ndarray
    covariance: np.ndarray
    variance_factor: float
    residuals: np.ndarray
    redundancy: int
    closest: np.ndarray
    iterations: int
    converged: bool

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def closest_points(stations: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points (..., 3) minimising Σ distance² to the rays stations_i + λ directions_i
    (..., n, 3), each set of n rays on its own: Σ (I - dᵢdᵢᵀ) X = Σ (I - dᵢdᵢᵀ) X0ᵢ with unit
    dᵢ; and (...,) True where the rays are parallel or not finite (the point is then NaN)."""
    units = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    projectors = np.eye(3) - units[..., :, None] * units[..., None, :]
    normal = projectors.sum(axis=-3)
    finite = np.all(np.isfinite(normal), axis=(-2, -1))
    normal = np.where(finite[..., None, None], normal, np.eye(3))
    eigenvalues = np.linalg.eigvalsh(normal)
    parallel = ~finite | (eigenvalues[..., 0] <= PARALLEL_RATIO * eigenvalues[..., -1])
    right = np.einsum("...nij,...nj->...i", projectors, stations)
    points = np.linalg.solve(np.where(parallel[..., None, None], np.eye(3), normal),
                             right[..., None])[..., 0]
    return np.where(parallel[..., None], np.nan, points), parallel


def closest_point(stations: np.ndarray, directions: np.ndarray, what: str) -> np.ndarray:
    """The point (3,) closest to the rays (n, 3) (`closest_points`). Raises ValueError for
    parallel rays."""
    point, parallel = closest_points(stations, directions)
    if parallel:
        units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        cosines = np.clip(units @ units.T, -1.0, 1.0)
        largest = float(np.max(np.arccos(cosines)))
        raise ValueError(f"{what}: the {len(units)} rays are parallel (largest angle between "
                         f"them {largest:.1e} rad); they do not fix the point's distance")
    return point


def forward_intersection(
    image_points,
    eops,
    c,
    *,
    principal_point=(0.0, 0.0),
    correction: Correction | None = None,
    refine: bool = True,
    sigma: float = 1.0,
    a_posteriori: bool = True,
    max_iterations: int = 30,
    tolerance: float = 1e-12,
) -> Intersection:
    """An object point from its image points in n >= 2 images of known orientation.

    Arguments:
    - `image_points` (n, 2): the point's measured coordinates in each image (image units,
      jaxba's image frame);
    - `eops` (n, 6): each image's X0, Y0, Z0 (object units), omega, phi, kappa (radians);
    - `c`: principal distance, one (scalar) or one per image (n,) (image units, > 0);
      `principal_point` (2,) or (n, 2);
    - `correction`: callable mapping the measured (n, 2) coordinates to distortion-free ones,
      or None when they are already corrected (images of several cameras: correct them first);
    - `refine`: refine the closest point by least squares on the collinearity equations;
    - `sigma`: a priori σ of an image coordinate (image units); `a_posteriori`: scale the
      covariance by σ̂0² (True) or take σ0 = 1 (False: with two images r = 1 only);
    - `max_iterations`, `tolerance`: of the refinement (Levenberg-Marquardt, relative step).

    Returns an `Intersection`. Raises ValueError for fewer than 2 rays, parallel rays, or a
    point behind an image (W >= 0: the rays meet behind its camera).
    """
    check_float64("forward_intersection")
    what = "forward_intersection"
    image_points = as_points(image_points, 2, what, "image_points")
    eops = as_points(eops, 6, what, "eops")
    n = same_count(what, image_points=image_points, eops=eops)
    if n < 2:
        raise ValueError(f"{what}: {n} ray(s); a point needs at least 2")
    c = per_item(c, n, (), what, "c")
    check_principal_distance(c, what)
    principal_point = per_item(principal_point, n, (2,), what, "principal_point")
    reduced = reduced_coordinates(image_points, principal_point, correction)
    matrices = opk_to_matrix(eops[:, 3:])
    stations = eops[:, :3]
    directions = np.einsum("nji,nj->ni", matrices, image_rays(reduced, c))  # Mᵀ (x̄, ȳ, -c)
    closest = closest_point(stations, directions, what)

    def model(point):
        uvw = np.einsum("nij,nj->ni", matrices, point - stations)
        u, v, w = uvw.T
        computed = -c[:, None] * uvw[:, :2] / w[:, None]
        d_uvw = np.zeros((n, 2, 3))
        d_uvw[:, 0, 0] = d_uvw[:, 1, 1] = -c / w
        d_uvw[:, 0, 2] = c * u / w**2
        d_uvw[:, 1, 2] = c * v / w**2
        jacobian = d_uvw @ matrices  # d (U, V, W) / d X = M
        return (reduced - computed).ravel() / sigma, jacobian.reshape(-1, 3) / sigma

    behind = np.flatnonzero(np.einsum("ni,ni->n", matrices[:, 2], closest - stations) >= 0)
    if behind.size:
        raise ValueError(f"{what}: the rays meet behind image(s) {behind.tolist()} (W >= 0): "
                         "the image points or orientations do not belong together")
    if refine:
        fit = levenberg_marquardt(model, closest, max_iterations=max_iterations,
                                  tolerance=tolerance)
    else:
        fit = Fit(closest, *model(closest), iterations=0, converged=True)
    cxx, variance_factor = covariance(fit, 2 * n - 3, a_posteriori=a_posteriori)
    return Intersection(
        point=fit.x, covariance=cxx, variance_factor=variance_factor,
        residuals=fit.residuals.reshape(-1, 2) * sigma, redundancy=2 * n - 3,
        closest=closest, iterations=fit.iterations, converged=fit.converged,
    )
