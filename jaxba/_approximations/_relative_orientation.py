"""Relative orientation of an image pair: the coplanarity condition (seed chapter 8,
"Relative orientation", dependent and independent) and the essential matrix (its computer
vision equivalent, for a start from nothing).

With rays rₖ = (x̄ₖ, ȳₖ, -cₖ) in each image frame (positive multiples of Mₖ (X - X0ₖ),
docs/conventions.md), conjugate rays and the base b = X02 - X01 are coplanar in the model frame:

    F = b · (M1ᵀ r1 × M2ᵀ r2) = 0.

Seven of the pair's twelve EOPs fix the model frame (origin, rotation, scale); five remain:
- dependent: image 1 at the origin with M1 = I, image 2 at (bx, by, bz) with bx fixed;
  unknowns by, bz, omega2, phi2, kappa2;
- independent: image 1 at the origin, image 2 at (bx, 0, 0), omega1 = 0; unknowns
  phi1, kappa1, omega2, phi2, kappa2.
"""

import dataclasses

import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_derivatives, opk_to_matrix
from ._common import (
    Correction,
    as_callables,
    as_points,
    check_float64,
    check_principal_distance,
    covariance,
    homogeneous,
    image_rays,
    levenberg_marquardt,
    nearest_rotation,
    normaliser,
    null_vector,
    per_item,
    reduced_coordinates,
    same_count,
    wrap_angles,
)

RELATIVE_ORIENTATION_PARAMETERS = {
    "dependent": ("by", "bz", "omega2", "phi2", "kappa2"),
    "independent": ("phi1", "kappa1", "omega2", "phi2", "kappa2"),
}
"""The five unknowns of each parameterisation (object units of the model, radians)."""

ZERO_BASE_ANGLE = 1e-9
"""Rays of the two images that one rotation aligns to within this angle (radians) show no
parallax: the base is zero (or all points are at infinity)."""


@dataclasses.dataclass(frozen=True)
class EssentialMatrix:
    """The relative orientation of an image pair from the essential matrix (`essential_matrix`).

    - `matrix` (3, 3): E = R [b]ₓ with r2ᵀ E r1 = 0 for the rays rₖ = (x̄ₖ, ȳₖ, -cₖ);
    - `rotation` (3, 3): R, rotating image 1's frame into image 2's: image 2's M when image
      1's is the identity (dependent frame);
    - `base` (3,): unit vector from image 1 to image 2 in image 1's frame;
    - `in_front`: how many points are in front of both images (the choice among the four
      (R, ±b) that E admits, by cheirality).
    """

    matrix: np.ndarray
    rotation: np.ndarray
    base: np.ndarray
    in_front: int


@dataclasses.dataclass(frozen=True)
class RelativeOrientation:
    """An image pair's relative orientation by `relative_orientation`.

    - `parameterisation`: "dependent" or "independent"; `parameter_names` its five unknowns;
    - `parameters` (5,): their values (model units, radians); `covariance` (5, 5), `sigma` (5,);
    - `eops` (2, 6): both images' X0, Y0, Z0, omega, phi, kappa in the model frame (model units,
      radians), jaxba's images rows;
    - `points` (n, 3): the model coordinates of the points, each the midpoint of the shortest
      segment between its two rays;
    - `residuals` (n,): the coplanarity misclosure as an image distance, -F / |∂F/∂(x1, y1, x2,
      y2)| (image units; the smallest change of the four coordinates that clears it);
    - `variance_factor` σ̂0² = Σ (F / (σ |∂F/∂l|))² / r, r = n - 5 (`redundancy`);
    - `iterations`, `converged`: of the least squares.
    """

    parameterisation: str
    parameter_names: tuple[str, ...]
    parameters: np.ndarray
    covariance: np.ndarray
    eops: np.ndarray
    points: np.ndarray
    residuals: np.ndarray
    variance_factor: float
    redundancy: int
    iterations: int
    converged: bool

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def _pair_rays(image_points_1, image_points_2, c, principal_point, correction, what):
    """The rays (x̄, ȳ, -c) (n, 3) of both images, corrected and reduced."""
    points = [as_points(image_points_1, 2, what, "image_points_1"),
              as_points(image_points_2, 2, what, "image_points_2")]
    n = same_count(what, image_points_1=points[0], image_points_2=points[1])
    cs = per_item(c, 2, (), what, "c")
    check_principal_distance(cs, what)
    principal_points = per_item(principal_point, 2, (2,), what, "principal_point")
    corrections = as_callables(correction, 2, what)
    rays = [image_rays(reduced_coordinates(p, pp, corr), ck)
            for p, pp, corr, ck in zip(points, principal_points, corrections, cs)]
    return rays[0], rays[1], n


def _check_parallax(r1: np.ndarray, r2: np.ndarray, what: str) -> None:
    """ValueError when one rotation maps every ray of image 1 onto its ray in image 2."""
    u1 = r1 / np.linalg.norm(r1, axis=1, keepdims=True)
    u2 = r2 / np.linalg.norm(r2, axis=1, keepdims=True)
    q = nearest_rotation(u2.T @ u1)  # Kabsch: u2 ≈ Q u1
    misfit = np.max(np.linalg.norm(u2 - u1 @ q.T, axis=1))
    if misfit <= ZERO_BASE_ANGLE:
        raise ValueError(f"{what}: the images show no parallax (one rotation aligns all rays "
                         f"to {misfit:.1e} rad): the base is zero, or the points are at infinity")


def _depths(r1, r2, m, t):
    """λ1, λ2 (n,) of λ2 r2 = λ1 M r1 + t in least squares (positive: in front)."""
    a = r1 @ m.T
    aa, ab, bb = np.sum(a * a, 1), np.sum(a * r2, 1), np.sum(r2 * r2, 1)
    at, bt = a @ t, r2 @ t
    det = ab * ab - aa * bb  # of [[aa, -ab], [ab, -bb]]
    lambda1 = (-at * -bb - (-ab) * -bt) / det
    lambda2 = (aa * -bt - ab * -at) / det
    return lambda1, lambda2


def _essential(r1: np.ndarray, r2: np.ndarray, what: str) -> EssentialMatrix:
    n = len(r1)
    if n < 8:
        raise ValueError(f"{what}: {n} points; the normalised 8-point algorithm needs at "
                         "least 8")
    _check_parallax(r1, r2, what)
    q1, q2 = r1[:, :2] / r1[:, 2:], r2[:, :2] / r2[:, 2:]  # (q, 1) ∝ r
    t1, t2 = normaliser(q1), normaliser(q2)
    a, b = homogeneous(q1) @ t1.T, homogeneous(q2) @ t2.T
    rows = np.einsum("ni,nj->nij", b, a).reshape(n, 9)
    e = null_vector(rows, what, "the points lie on a plane or a critical surface")
    e = t2.T @ e.reshape(3, 3) @ t1  # for (q, 1) ∝ r: the same E up to scale
    u, _, vt = np.linalg.svd(e)
    u, vt = u * np.linalg.det(u), vt * np.linalg.det(vt)
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    best = None
    for m in (u @ w @ vt, u @ w.T @ vt):
        for t in (u[:, 2], -u[:, 2]):
            lambda1, lambda2 = _depths(r1, r2, m, t)
            count = int(np.sum((lambda1 > 0) & (lambda2 > 0)))
            if best is None or count > best[0]:
                best = (count, m, t)
    count, m, t = best
    base = -m.T @ t  # p2 = M (p1 - b) = M p1 + t
    skew = np.array([[0, -base[2], base[1]], [base[2], 0, -base[0]], [-base[1], base[0], 0]])
    return EssentialMatrix(matrix=m @ skew, rotation=m, base=base, in_front=count)


def essential_matrix(
    image_points_1,
    image_points_2,
    c,
    *,
    principal_point=(0.0, 0.0),
    correction: Correction | None = None,
) -> EssentialMatrix:
    """The essential matrix of an image pair by the normalised 8-point algorithm, and the
    relative rotation and base direction it implies (Hartley & Zisserman, "Multiple View
    Geometry", 2nd ed., 9.6 and 11.2).

    E is the least-squares null vector of r2ᵀ E r1 = 0 over n >= 8 conjugate points (image
    coordinates Hartley-normalised), with its singular values set to (1, 1, 0). Of the four
    (R, ±b) it admits, the one with most points in front of both images (λ > 0 in
    λ2 r2 = λ1 R r1 - R b) wins.

    Arguments:
    - `image_points_1`, `image_points_2` (n, 2): conjugate image coordinates (image units,
      jaxba's image frame);
    - `c`: principal distance (image units), one or one per image (2,); `principal_point` (2,)
      or per image (2, 2);
    - `correction`: None, a callable mapping measured (n, 2) coordinates to distortion-free
      ones, or one per image.

    Returns an `EssentialMatrix` (unit base: the scale is not observable). Raises ValueError
    for fewer than 8 points, a zero base (no parallax) or a degenerate (planar) configuration.
    """
    check_float64("essential_matrix")
    what = "essential_matrix"
    r1, r2, _ = _pair_rays(image_points_1, image_points_2, c, principal_point, correction, what)
    return _essential(r1, r2, what)


def _frames(parameters: np.ndarray, parameterisation: str, bx: float):
    """M1, M2 (3, 3), b (3,) and their derivatives by the five parameters (3, 3, 5), (3, 5)."""
    dm1, dm2, db = np.zeros((3, 3, 5)), np.zeros((3, 3, 5)), np.zeros((3, 5))
    opk2 = parameters[2:]
    m2 = opk_to_matrix(opk2)
    dm2[:, :, 2:] = opk_derivatives(opk2)
    if parameterisation == "dependent":
        m1 = np.eye(3)
        base = np.array([bx, parameters[0], parameters[1]])
        db[1, 0] = db[2, 1] = 1.0
    else:
        opk1 = np.array([0.0, parameters[0], parameters[1]])
        m1 = opk_to_matrix(opk1)
        dm1[:, :, :2] = opk_derivatives(opk1)[:, :, 1:]
        base = np.array([bx, 0.0, 0.0])
    return m1, m2, base, dm1, dm2, db


def _coplanarity(parameters, r1, r2, parameterisation, bx):
    """Sampson distances e = F / |B| (n,) and de/d parameters (n, 5), B = dF/d(x1, y1, x2, y2).

    F = b · (a × d) with a = M1ᵀ r1, d = M2ᵀ r2 (the rays in the model frame); B = ((d × b) ·
    M1[0], (d × b) · M1[1], (b × a) · M2[0], (b × a) · M2[1]) since da/dx1 = M1ᵀ e1 = M1[0].
    """
    m1, m2, base, dm1, dm2, db = _frames(parameters, parameterisation, bx)
    a, d = r1 @ m1, r2 @ m2
    da = np.einsum("ni,ijk->njk", r1, dm1)  # (n, 3, 5)
    dd = np.einsum("ni,ijk->njk", r2, dm2)
    a_cross_d = np.cross(a, d)
    f = a_cross_d @ base
    df = (a_cross_d @ db
          + np.einsum("j,njk->nk", base, np.cross(da, d[:, :, None], axis=1))
          + np.einsum("j,njk->nk", base, np.cross(a[:, :, None], dd, axis=1)))
    d_cross_b, b_cross_a = np.cross(d, base), np.cross(base, a)
    d_d_cross_b = (np.cross(dd, base[None, :, None], axis=1)
                   + np.cross(d[:, :, None], db[None], axis=1))
    d_b_cross_a = (np.cross(db[None], a[:, :, None], axis=1)
                   + np.cross(base[None, :, None], da, axis=1))
    b_rows, d_b_rows = [], []
    for vector, d_vector, m, dm in ((d_cross_b, d_d_cross_b, m1, dm1),
                                    (b_cross_a, d_b_cross_a, m2, dm2)):
        for row in (0, 1):
            b_rows.append(vector @ m[row])
            d_b_rows.append(np.einsum("njk,j->nk", d_vector, m[row]) + vector @ dm[row])
    b_rows, d_b_rows = np.stack(b_rows, axis=1), np.stack(d_b_rows, axis=1)  # (n, 4), (n, 4, 5)
    norm = np.linalg.norm(b_rows, axis=1)
    d_norm = np.einsum("ni,nik->nk", b_rows, d_b_rows) / norm[:, None]
    return f / norm, df / norm[:, None] - (f / norm**2)[:, None] * d_norm


def _start(essential: EssentialMatrix, parameterisation: str, bx: float, what: str):
    u = essential.base
    if parameterisation == "dependent":
        if abs(u[0]) < 1e-3:
            raise ValueError(f"{what}: the base is (nearly) perpendicular to image 1's x axis "
                             f"(unit base {np.round(u, 4).tolist()}): the dependent "
                             "parameterisation with bx fixed cannot hold it; use independent")
        if np.sign(u[0]) != np.sign(bx):
            raise ValueError(f"{what}: image 2 lies on the {'negative' if u[0] < 0 else 'positive'}"
                             f" x side of image 1 (unit base {np.round(u, 4).tolist()}): "
                             f"fix bx = {-bx} instead of {bx}")
        base = u * bx / u[0]
        return np.r_[base[1:], matrix_to_opk(essential.rotation)]
    s = np.sign(bx)
    phi1 = np.arcsin(np.clip(s * u[2], -1.0, 1.0))
    kappa1 = np.arctan2(-s * u[1], s * u[0])
    m1 = opk_to_matrix(np.array([0.0, phi1, kappa1]))
    return np.r_[phi1, kappa1, matrix_to_opk(essential.rotation @ m1)]


def _model_points(r1, r2, m1, m2, base):
    """Midpoints of the shortest segments between the rays λ1 M1ᵀ r1 and b + λ2 M2ᵀ r2, with
    λ1, λ2 (n,)."""
    a, d = r1 @ m1, r2 @ m2
    lambda1, lambda2 = _depths(a, d, np.eye(3), -base)  # λ2 d = λ1 a - b
    return (lambda1[:, None] * a + base + lambda2[:, None] * d) / 2, lambda1, lambda2


def relative_orientation(
    image_points_1,
    image_points_2,
    c,
    *,
    principal_point=(0.0, 0.0),
    correction: Correction | None = None,
    parameterisation: str = "dependent",
    bx: float = 1.0,
    start=None,
    sigma: float = 1.0,
    a_posteriori: bool = True,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
) -> RelativeOrientation:
    """Relative orientation of an image pair by least squares on the coplanarity condition
    (module docstring), dependent or independent, from n >= 5 conjugate points.

    Each point gives F = b · (M1ᵀ r1 × M2ᵀ r2) = 0; the five unknowns minimise the sum of
    squared Sampson distances Σ Fᵢ² / (σ² |Bᵢ|²), Bᵢ = ∂Fᵢ/∂(x1, y1, x2, y2): each the
    first-order image distance of a point pair from coplanarity (to first order the
    Gauss-Helmert estimate), by Levenberg-Marquardt. Cxx = σ̂0² (AᵀA)⁻¹ with A = ∂(F/(σ|B|))/∂θ.

    Arguments:
    - `image_points_1`, `image_points_2` (n, 2): conjugate image coordinates (image units,
      jaxba's image frame);
    - `c`: principal distance (image units), one or per image (2,); `principal_point` (2,)
      or (2, 2); `correction`: None, a callable (measured -> distortion-free (n, 2)) or two;
    - `parameterisation`: "dependent" or "independent" (RELATIVE_ORIENTATION_PARAMETERS);
    - `bx`: the fixed x component of the base (model units, nonzero): the model's scale, and
      its sign says on which side of image 1 image 2 lies;
    - `start` (5,): starting parameters (model units, radians), e.g. zeros for a near-vertical
      aerial pair; None: from the essential matrix (needs n >= 8);
    - `sigma`, `a_posteriori`, `max_iterations`, `tolerance`: as in `space_resection`.

    Returns a `RelativeOrientation` (parameters, both EOPs in the model frame, model points).
    Raises ValueError for too few points, a zero bx, no parallax (zero base), or a model whose
    points lie behind the images.
    """
    check_float64("relative_orientation")
    what = "relative_orientation"
    if parameterisation not in RELATIVE_ORIENTATION_PARAMETERS:
        raise ValueError(f"{what}: parameterisation must be one of "
                         f"{tuple(RELATIVE_ORIENTATION_PARAMETERS)}, got {parameterisation!r}")
    if not (np.isfinite(bx) and bx != 0):
        raise ValueError(f"{what}: bx = {bx}; the base's x component fixes the model's scale "
                         "and must be nonzero")
    bx = float(bx)
    r1, r2, n = _pair_rays(image_points_1, image_points_2, c, principal_point, correction, what)
    if n < 5:
        raise ValueError(f"{what}: {n} points; the five parameters need at least 5")
    if start is None:
        if n < 8:
            raise ValueError(f"{what}: {n} points; a start from the essential matrix needs 8 "
                             "(pass start=, e.g. zeros for a near-vertical pair)")
        start = _start(_essential(r1, r2, what), parameterisation, bx, what)
    else:
        _check_parallax(r1, r2, what)
        start = per_item(start, 1, (5,), what, "start")[0]

    def model(parameters):
        distance, jacobian = _coplanarity(parameters, r1, r2, parameterisation, bx)
        return -distance / sigma, jacobian / sigma

    fit = levenberg_marquardt(model, start, max_iterations=max_iterations, tolerance=tolerance)
    parameters = fit.x.copy()
    parameters[2:] = wrap_angles(parameters[2:])
    if parameterisation == "independent":
        parameters[:2] = wrap_angles(parameters[:2])
    m1, m2, base, *_ = _frames(parameters, parameterisation, bx)
    points, lambda1, lambda2 = _model_points(r1, r2, m1, m2, base)
    behind = int(np.sum((lambda1 <= 0) | (lambda2 <= 0)))
    if behind > n / 2:
        raise ValueError(f"{what}: {behind} of {n} model points lie behind the images: the "
                         f"model is mirrored (fix bx = {-bx}?) or the start was too far off")
    cxx, variance_factor = covariance(fit, n - 5, a_posteriori=a_posteriori)
    eops = np.zeros((2, 6))
    eops[0, 3:] = matrix_to_opk(m1)
    eops[1] = np.r_[base, parameters[2:]]
    return RelativeOrientation(
        parameterisation=parameterisation,
        parameter_names=RELATIVE_ORIENTATION_PARAMETERS[parameterisation],
        parameters=parameters, covariance=cxx, eops=eops, points=points,
        residuals=fit.residuals * sigma, variance_factor=variance_factor,
        redundancy=n - 5, iterations=fit.iterations, converged=fit.converged,
    )
