"""Absolute orientation: the 7-parameter 3D similarity from model to ground coordinates (seed
chapter 8, "Absolute orientation: mathematical model")

    X_G = T + S R X_M,   R = M(Omega, Phi, Kappa)ᵀ

with M jaxba's rotation (docs/conventions.md): (Omega, Phi, Kappa) rotate the ground frame into the
model frame, as an image's (omega, phi, kappa) rotate the object frame into the image frame.
Closed form by Umeyama's SVD (the least-squares similarity, "Least-squares estimation of
transformation parameters between two point patterns", IEEE PAMI 13(4), 1991; Horn's
quaternion solution is the same minimum), then least squares over the seven parameters with
their covariance, using every ground coordinate that is given.
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_derivatives, opk_to_matrix
from ._common import (
    Fit,
    check_float64,
    covariance,
    flatness,
    levenberg_marquardt,
    same_count,
    wrap_angles,
)

SIMILARITY_PARAMETERS = ("X_T", "Y_T", "Z_T", "Omega", "Phi", "Kappa", "scale")
"""The seven parameters of `Similarity.parameters`: translation (ground units), the rotation's
angles (radians), scale (ground units per model unit)."""

COLLINEAR_RATIO = 1e-9
"""Points whose second singular value (centred) is below this fraction of the first are
collinear: the rotation about their line is undetermined."""


@dataclasses.dataclass(frozen=True)
class Similarity:
    """X_G = T + S R X_M, found by `absolute_orientation`.

    - `parameters` (7,): X_T, Y_T, Z_T (ground units), Omega, Phi, Kappa (radians; R =
      `opk_to_matrix`(Omega, Phi, Kappa)ᵀ), S (SIMILARITY_PARAMETERS);
    - `covariance` (7, 7): their Cxx (σ̂0² (AᵀPA)⁻¹ or a priori (AᵀPA)⁻¹); `sigma` (7,);
    - `residuals` (n, 3): v = ground - transformed model coordinates (ground units; NaN where
      a ground coordinate was not given); `variance_factor` σ̂0² = vᵀPv / r, r = (given
      coordinates) - 7 (`redundancy`); `iterations`, `converged`: of the refinement.
    """

    parameters: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    variance_factor: float
    redundancy: int
    iterations: int
    converged: bool

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def translation(self) -> np.ndarray:
        return self.parameters[:3]

    @property
    def rotation(self) -> np.ndarray:
        """R (3, 3), rotating model-frame vectors into the ground frame."""
        return opk_to_matrix(self.parameters[3:6]).T

    @property
    def scale(self) -> float:
        return float(self.parameters[6])

    def transform(self, model_points) -> np.ndarray:
        """Ground coordinates T + S R X_M (n, 3) of model points (n, 3) (or one, (3,))."""
        points = np.asarray(model_points, dtype=np.float64)
        return self.translation + self.scale * points @ self.rotation.T

    def transform_eops(self, eops) -> np.ndarray:
        """Images rows (n, 6) (or one, (6,)) from the model frame to the ground frame:
        X0_G = T + S R X0_M, M_G = M_M Rᵀ (the camera-frame point scales by 1/S, which leaves
        the projection unchanged). Angles in radians."""
        eops = np.asarray(eops, dtype=np.float64)
        rows = np.atleast_2d(eops)
        turned = matrix_to_opk(opk_to_matrix(rows[:, 3:]) @ self.rotation.T)
        out = np.c_[self.transform(rows[:, :3]), turned]
        return out.reshape(eops.shape)


def umeyama(model_points: np.ndarray, ground_points: np.ndarray,
            what: str) -> tuple[float, np.ndarray, np.ndarray]:
    """(S, R, T) minimising Σ |X_G - T - S R X_M|² over n >= 3 non-collinear full points.

    With centred coordinates, Σ_GM = Σ g mᵀ / n = U D Vᵀ: R = U diag(1, 1, det(U V)) Vᵀ,
    S = trace(D diag(1, 1, det(U V))) / (Σ |m|² / n), T = mean(X_G) - S R mean(X_M).
    """
    for name, points in (("model", model_points), ("ground", ground_points)):
        _, singular, _ = flatness(points)
        if singular[1] <= COLLINEAR_RATIO * singular[0]:
            raise ValueError(f"{what}: the {name} points are collinear (or coincide): the "
                             "rotation about their line is undetermined")
    mean_m, mean_g = model_points.mean(axis=0), ground_points.mean(axis=0)
    m, g = model_points - mean_m, ground_points - mean_g
    u, d, vt = np.linalg.svd(g.T @ m / len(m))
    signs = np.array([1.0, 1.0, np.linalg.det(u) * np.linalg.det(vt)])
    r = u @ np.diag(signs) @ vt
    scale = float(np.sum(d * signs) / np.mean(np.sum(m**2, axis=1)))
    return scale, r, mean_g - scale * r @ mean_m


def absolute_orientation(
    model_points,
    ground_points,
    *,
    sigma=1.0,
    refine: bool = True,
    a_posteriori: bool = True,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
) -> Similarity:
    """The 3D similarity X_G = T + S R X_M from points known in both frames (module docstring).

    Closed form (Umeyama) from the points whose three ground coordinates are all given, then
    (`refine`) weighted least squares over the seven parameters with every given ground
    coordinate as an observation (model coordinates errorless): a point with only Z given
    (a vertical control point) counts too.

    Arguments:
    - `model_points` (n, 3): model coordinates (model units), e.g. `RelativeOrientation.points`;
    - `ground_points` (n, 3): ground coordinates (ground units); NaN where not given;
    - `sigma`: a priori σ of a ground coordinate, scalar or (n, 3) (ground units);
    - `a_posteriori`: scale the covariance by σ̂0² (True) or take σ0 = 1 (False);
    - `max_iterations`, `tolerance`: of the Levenberg-Marquardt refinement (relative step).

    Returns a `Similarity`. Raises ValueError for fewer than 3 full points or collinear
    points.
    """
    check_float64("absolute_orientation")
    what = "absolute_orientation"
    model_points = np.asarray(model_points, dtype=np.float64)
    ground_points = np.asarray(ground_points, dtype=np.float64)
    for name, points in (("model_points", model_points), ("ground_points", ground_points)):
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"{what}: {name} must have shape (n, 3), got {points.shape}")
    same_count(what, model_points=model_points, ground_points=ground_points)
    if not np.all(np.isfinite(model_points)):
        raise ValueError(f"{what}: model_points contains non-finite values")
    if np.any(np.isinf(ground_points)):
        raise ValueError(f"{what}: ground_points contains infinite values (NaN marks a "
                         "coordinate that is not given)")
    sigma = np.broadcast_to(np.asarray(sigma, dtype=np.float64), ground_points.shape)
    given = np.isfinite(ground_points)
    if not np.all(sigma[given] > 0):
        raise ValueError(f"{what}: sigma must be > 0")
    full = np.all(given, axis=1)
    if np.sum(full) < 3:
        raise ValueError(f"{what}: {int(np.sum(full))} points with all three ground "
                         "coordinates; the closed-form start needs 3 non-collinear ones")
    count = int(np.sum(given))
    scale, r, t = umeyama(model_points[full], ground_points[full], what)
    start = np.r_[t, matrix_to_opk(r.T), scale]
    observed = ground_points[given] / sigma[given]

    def model(parameters):
        opk, s = parameters[3:6], parameters[6]
        rot, d_rot = opk_to_matrix(opk).T, np.transpose(opk_derivatives(opk), (1, 0, 2))
        turned = model_points @ rot.T  # R X_M
        computed = parameters[:3] + s * turned
        jacobian = np.zeros((*model_points.shape, 7))
        jacobian[:, :, :3] = np.eye(3)
        jacobian[:, :, 3:6] = s * np.einsum("ijk,nj->nik", d_rot, model_points)
        jacobian[:, :, 6] = turned
        return (observed - computed[given] / sigma[given],
                jacobian[given] / sigma[given][:, None])

    if refine:
        fit = levenberg_marquardt(model, start, max_iterations=max_iterations,
                                  tolerance=tolerance)
    else:
        fit = Fit(start, *model(start), iterations=0, converged=True)
    parameters = fit.x.copy()
    parameters[3:6] = wrap_angles(parameters[3:6])
    cxx, variance_factor = covariance(fit, count - 7, a_posteriori=a_posteriori)
    residuals = np.full(ground_points.shape, np.nan)
    residuals[given] = fit.residuals * sigma[given]
    return Similarity(
        parameters=parameters, covariance=cxx, residuals=residuals,
        variance_factor=variance_factor, redundancy=count - 7,
        iterations=fit.iterations, converged=fit.converged,
    )
