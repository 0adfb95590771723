"""The BAL camera model and a BAL problem as a two-block least-squares problem.

Camera (9 values): Rodrigues rotation r, translation t, focal length f, radial k1, k2.
Point (3 values): X. Projection (Snavely's Bundler convention, camera looks down -z):

    P = R(r) X + t,   p = -P[:2] / P[2],   x = f (1 + k1 |p|² + k2 |p|⁴) p.

The residual of one observation is x - observed (pixels), as in Ceres'
`SnavelyReprojectionError`; the cost is ½ Σ |residual|².
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._custom_types import Vector2, Vector3
from .._schur import TwoBlockProblem
from ._reader import BalProblem


def rotate_point(r: Vector3, x: Vector3) -> Vector3:
    """R(r) x for the Rodrigues (axis-angle) vector r, written out with cross products.

    R x = x + (sin θ / θ) r × x + ((1 - cos θ) / θ²) r × (r × x), θ = |r|, with the
    Taylor expansions 1 - θ²/6 and 1/2 - θ²/24 near θ = 0 (values and derivatives stay
    exact). Same rotation as `jaxba.rodrigues_to_matrix(r) @ x` and Ceres'
    `AngleAxisRotatePoint`; written elementwise because vmapped 3x3 matrix products
    are slow on CPU (this makes the solver's linearisation ~3x faster on BAL).
    """
    theta2 = r[0] ** 2 + r[1] ** 2 + r[2] ** 2
    small = theta2 < 1e-24
    safe_theta2 = jnp.where(small, 1.0, theta2)
    theta = jnp.sqrt(safe_theta2)
    sin_term = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(theta) / theta)
    cos_term = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(theta)) / safe_theta2)
    cross = _cross(r, x)
    double_cross = _cross(r, cross)
    return jnp.stack([x[i] + sin_term * cross[i] + cos_term * double_cross[i] for i in range(3)])


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def bal_project(camera: Float[Array, "9"], point: Vector3) -> Vector2:
    """Image point x = f (1 + k1 |p|² + k2 |p|⁴) p, p = -P[:2]/P[2], P = R(r) X + t (pixels)."""
    in_camera = rotate_point(camera[:3], point) + camera[3:6]
    p = -in_camera[:2] / in_camera[2]
    r2 = p[0] ** 2 + p[1] ** 2
    focal, k1, k2 = camera[6], camera[7], camera[8]
    return focal * (1.0 + k1 * r2 + k2 * r2**2) * p


def bal_residual(camera: Float[Array, "9"], point: Vector3, observed: Vector2) -> Vector2:
    """Reprojection residual `bal_project(camera, point) - observed` of one observation."""
    return bal_project(camera, point) - observed


def bal_two_block(problem: BalProblem) -> TwoBlockProblem:
    """The BAL problem as min ½ Σ_i |bal_residual(cameras[c_i], points[p_i], observed_i)|².

    The unknowns y = (cameras (n_cameras, 9), points (n_points, 3)); the initial values
    are `bal_initial(problem)`.
    """
    return TwoBlockProblem(
        bal_residual,
        problem.camera_index,
        problem.point_index,
        jnp.asarray(problem.observed),
        n_cameras=problem.n_cameras,
        n_points=problem.n_points,
    )


def bal_initial(
    problem: BalProblem,
) -> tuple[Float[Array, "n_cameras 9"], Float[Array, "n_points 3"]]:
    """The initial unknowns (cameras, points) as jax arrays."""
    return jnp.asarray(problem.cameras), jnp.asarray(problem.points)
