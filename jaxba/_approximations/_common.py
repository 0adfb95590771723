"""What the approximation modules share: input checks, image rays, Hartley normalisation, the
nearest rotation and a small Levenberg-Marquardt.

The closed-form tools are plain NumPy in float64 (they run once, before any adjustment, on
small arrays). Rotations are jaxba's own in NumPy (`jaxba._models._rotation_numpy`,
docs/conventions.md), so that every orientation found here is exactly the one jaxba's
projection uses.
"""

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from .._float64 import require_float64

Correction = Callable[[np.ndarray], np.ndarray]


def wrap_angles(values: np.ndarray) -> np.ndarray:
    """Angles (radians) wrapped into [-π, π), each on its own (the rotation is unchanged)."""
    return (np.asarray(values) + np.pi) % (2 * np.pi) - np.pi


def check_float64(what: str) -> None:
    """`require_float64`: the tools' EOPs and points start a jaxba adjustment, which needs jax
    in float64; they refuse to run without it (the parallax relations excepted)."""
    require_float64(what)


def as_points(values, dimension: int, what: str, name: str) -> np.ndarray:
    """`values` as a float64 (n, dimension) array, or a ValueError naming `name`."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != dimension:
        raise ValueError(f"{what}: {name} must have shape (n, {dimension}), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what}: {name} contains non-finite values")
    return array


def same_count(what: str, **arrays: np.ndarray) -> int:
    """The common length of `arrays`, or a ValueError naming them."""
    counts = {name: len(array) for name, array in arrays.items()}
    if len(set(counts.values())) != 1:
        listed = ", ".join(f"{name} {count}" for name, count in counts.items())
        raise ValueError(f"{what}: the point lists differ in length ({listed})")
    return next(iter(counts.values()))


def per_item(value, count: int, shape: tuple[int, ...], what: str, name: str) -> np.ndarray:
    """`value` (one of `shape`, or `count` of them) broadcast to (count, *shape)."""
    array = np.asarray(value, dtype=np.float64)
    if array.shape == shape:
        return np.broadcast_to(array, (count, *shape)).copy()
    if array.shape == (count, *shape):
        return array.copy()
    raise ValueError(f"{what}: {name} must have shape {shape} or {(count, *shape)}, "
                     f"got {array.shape}")


def reduced_coordinates(
    image_points: np.ndarray, principal_point: np.ndarray, correction: Correction | None
) -> np.ndarray:
    """Distortion-corrected image coordinates reduced to the principal point, (n, 2).

    x̄ = correction(x) - xp: `correction` maps measured (n, 2) coordinates to ideal,
    distortion-free ones (the identity when None); the principal point is (2,) or (n, 2).
    """
    ideal = image_points if correction is None else np.asarray(
        correction(image_points), dtype=np.float64)
    if ideal.shape != image_points.shape or not np.all(np.isfinite(ideal)):
        raise ValueError(f"the correction returned shape {ideal.shape} or non-finite values "
                         f"for image points of shape {image_points.shape}")
    return ideal - principal_point


def image_rays(reduced: np.ndarray, c) -> np.ndarray:
    """Rays (x̄, ȳ, -c) (n, 3) in the image frame: positive multiples of M (X - X0)."""
    c = np.broadcast_to(np.asarray(c, dtype=np.float64), (len(reduced),))
    return np.c_[reduced, -c]


def check_principal_distance(c, what: str) -> None:
    if not np.all(np.asarray(c, dtype=np.float64) > 0):
        raise ValueError(f"{what}: the principal distance c must be > 0, got {c}")


def flatness(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centroid (3,), singular values (3,), axes (3, 3) as rows) of the centred points."""
    centroid = points.mean(axis=0)
    _, singular, axes = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, np.r_[singular, np.zeros(3 - len(singular))], axes


def normaliser(points: np.ndarray) -> np.ndarray:
    """Hartley's similarity T (d+1, d+1): centroid to 0, mean distance to sqrt(d)."""
    dimension = points.shape[1]
    centroid = points.mean(axis=0)
    spread = np.mean(np.linalg.norm(points - centroid, axis=1))
    if spread == 0:
        raise ValueError("all points coincide")
    scale = np.sqrt(dimension) / spread
    transform = np.eye(dimension + 1)
    transform[:dimension, :dimension] *= scale
    transform[:dimension, dimension] = -scale * centroid
    return transform


def homogeneous(points: np.ndarray) -> np.ndarray:
    return np.c_[points, np.ones(len(points))]


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation (det +1) nearest to `m` in the Frobenius norm (SVD)."""
    u, _, vt = np.linalg.svd(m)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def null_vector(rows: np.ndarray, what: str, cause: str) -> np.ndarray:
    """The unit vector minimising |rows @ v| (SVD), or a ValueError when that minimum is not
    unique (the second smallest singular value vanishes too): `cause` says why."""
    _, singular, vt = np.linalg.svd(rows)  # vt: all n right singular vectors
    # With fewer rows than unknowns the missing singular values are 0: a minimal set (8 rows
    # for the 9 entries of E, ...) has a unique null vector when the others are all > 0.
    singular = np.concatenate([singular, np.zeros(rows.shape[1] - len(singular))])
    if singular[-2] <= 1e-10 * singular[0]:
        raise ValueError(f"{what}: the linear system is degenerate ({cause})")
    return vt[-1]


ROUNDING_REDUCTION = 1e-10
"""Relative cost reduction below which `levenberg_marquardt` takes Gauss-Newton steps unjudged
(residuals of cancelling products carry relative rounding errors near 1e-13)."""


@dataclasses.dataclass(frozen=True)
class Fit:
    """The outcome of `levenberg_marquardt`: the solution `x`, its residuals v = observed -
    computed and Jacobian A = d computed / d x (both whitened), iterations, convergence."""

    x: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    iterations: int
    converged: bool


def levenberg_marquardt(
    model: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    *,
    max_iterations: int,
    tolerance: float,
) -> Fit:
    """Minimise |v(x)|² with v = observed - computed, `model(x)` giving (v (m,), A (m, u)), A =
    d computed / d x.

    Steps (AᵀA + λ diag(AᵀA)) δ = Aᵀ v (Marquardt's scaling), λ divided by 10 after a step
    that lowers the cost and multiplied by 10 otherwise. Converged when the undamped
    (Gauss-Newton) step at the current point has max |δ_i| / (1 + |x_i|) <= `tolerance`; not
    converged after `max_iterations` accepted steps or when no damped step lowers the cost.
    Close to the minimum, where the Gauss-Newton step would lower the cost by less than
    `ROUNDING_REDUCTION` of it, the cost cannot judge steps any more and they are taken
    undamped (Gauss-Newton converges there; the step test decides).
    """
    x = np.array(x0, dtype=np.float64)
    v, a = model(x)
    cost = v @ v
    damping = 1e-6
    for iteration in range(max_iterations + 1):
        normal = a.T @ a
        gradient = a.T @ v
        newton = np.linalg.lstsq(normal, gradient, rcond=None)[0]
        if np.max(np.abs(newton) / (1.0 + np.abs(x))) <= tolerance:
            return Fit(x, v, a, iteration, True)
        if iteration == max_iterations:
            break
        if newton @ gradient <= ROUNDING_REDUCTION * cost:
            # The step would lower the cost by less than its rounding can show: take it.
            x = x + newton
            v, a = model(x)
            cost = v @ v
            continue
        scale = np.where(np.diag(normal) > 0, np.diag(normal), 1.0)
        while True:
            try:
                step = np.linalg.solve(normal + damping * np.diag(scale), gradient)
            except np.linalg.LinAlgError:
                step = np.full_like(x, np.nan)
            if np.all(np.isfinite(step)):
                candidate = x + step
                v_new, a_new = model(candidate)
                cost_new = v_new @ v_new
                if np.isfinite(cost_new) and cost_new <= cost:
                    break
            damping *= 10.0
            if damping > 1e12:
                return Fit(x, v, a, iteration, False)
        x, v, a, cost = candidate, v_new, a_new, cost_new
        damping = max(damping / 10.0, 1e-12)
    return Fit(x, v, a, max_iterations, False)


def covariance(
    fit: Fit, redundancy: int, *, a_posteriori: bool
) -> tuple[np.ndarray, float]:
    """(Cxx, σ̂0²) of a whitened fit: σ̂0² = vᵀv / r, Cxx = σ̂0² (AᵀA)⁻¹ (or (AᵀA)⁻¹,
    σ0 = 1 a priori, when not `a_posteriori`). σ̂0² is NaN without redundancy."""
    variance_factor = float(fit.residuals @ fit.residuals / redundancy) if redundancy > 0 \
        else float("nan")
    cofactor = np.linalg.inv(fit.jacobian.T @ fit.jacobian)
    return (variance_factor if a_posteriori else 1.0) * cofactor, variance_factor


def as_callables(correction, count: int, what: str) -> Sequence[Correction | None]:
    """One correction (or None) per image from None, one callable or a sequence of them."""
    if correction is None or callable(correction):
        return [correction] * count
    corrections = list(correction)
    if len(corrections) != count or not all(c is None or callable(c) for c in corrections):
        raise ValueError(f"{what}: correction must be None, a callable or {count} of them")
    return corrections
