"""Rotation parameterisations and exact conversions between them.

Every function maps one rotation (no batch axis; `jax.vmap` for many). The matrix `M` is
always R_m^c of docs/conventions.md: it rotates object-space vectors into the image (camera)
frame, `p_image = M @ (X - X0)`. Axis-angle vectors and quaternions describe that same `M`:
`rodrigues_to_matrix(r)` is the matrix that rotates by |r| about r/|r|, as in BAL and
OpenCV's `cv::Rodrigues`; quaternions are unit Hamilton quaternions `(w, x, y, z)`.
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._custom_types import Matrix3, Vector3


def opk_to_matrix(opk: Float[Array, "3"]) -> Matrix3:
    """M = R3(kappa) R2(phi) R1(omega), element by element as in docs/conventions.md.

    Arguments: `opk`, (omega, phi, kappa) in radians. Returns the 3x3 matrix R_m^c.
    """
    omega, phi, kappa = opk
    so, co = jnp.sin(omega), jnp.cos(omega)
    sp, cp = jnp.sin(phi), jnp.cos(phi)
    sk, ck = jnp.sin(kappa), jnp.cos(kappa)
    return jnp.array(
        [
            [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
            [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
            [sp, -so * cp, co * cp],
        ]
    )


def matrix_to_opk(m: Matrix3) -> Float[Array, "3"]:
    """Inverse of `opk_to_matrix` for |phi| < 90 degrees.

    omega = atan2(-m32, m33), phi = asin(m31), kappa = atan2(-m21, m11); phi is taken
    with atan2 for accuracy near ±90°.
    """
    omega = jnp.arctan2(-m[2, 1], m[2, 2])
    phi = jnp.arctan2(m[2, 0], jnp.hypot(m[2, 1], m[2, 2]))
    kappa = jnp.arctan2(-m[1, 0], m[0, 0])
    return jnp.array([omega, phi, kappa])


def _safe_norm(v: Vector3) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """(|v|, |v|², is_small); |v| is a placeholder 1 where small, so its gradient stays finite.

    Where `is_small`, callers must use Taylor expansions in |v|² only.
    """
    squared = jnp.sum(v**2)
    small = squared < 1e-24
    return jnp.sqrt(jnp.where(small, 1.0, squared)), squared, small


def rodrigues_to_matrix(r: Vector3) -> Matrix3:
    """Rotation matrix of the axis-angle vector `r` (radians), Rodrigues' formula.

    R = I + sin(θ) K + (1 - cos(θ)) K², K = [r/θ]_x, θ = |r|. Near θ = 0 the Taylor
    expansion R ≈ I + [r]_x + [r]_x²/2 keeps values and derivatives exact.
    """
    theta, squared, small = _safe_norm(r)
    k = _skew(r)
    sin_term = jnp.where(small, 1.0 - squared / 6.0, jnp.sin(theta) / theta)
    cos_term = jnp.where(small, 0.5 - squared / 24.0, (1.0 - jnp.cos(theta)) / theta**2)
    return jnp.eye(3) + sin_term * k + cos_term * (k @ k)


def quaternion_to_matrix(q: Float[Array, "4"]) -> Matrix3:
    """Rotation matrix of the quaternion q = (w, x, y, z), normalised first."""
    w, x, y, z = q / jnp.linalg.norm(q)
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(m: Matrix3) -> Float[Array, "4"]:
    """Unit quaternion (w, x, y, z) with w >= 0 of the rotation matrix `m`.

    Shepperd's method: of the four candidate formulas, use the one whose pivot
    (1 + trace, or 1 + 2 m_ii - trace) is largest, which is always well conditioned.
    """
    trace = jnp.trace(m)
    pivots = jnp.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    candidates = jnp.array(
        [
            [1 + trace, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]],
            [m[2, 1] - m[1, 2], 1 + 2 * m[0, 0] - trace, m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]],
            [m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], 1 + 2 * m[1, 1] - trace, m[1, 2] + m[2, 1]],
            [m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1], 1 + 2 * m[2, 2] - trace],
        ]
    )
    q = candidates[jnp.argmax(pivots)]
    q = q / jnp.linalg.norm(q)
    return jnp.where(q[0] < 0, -q, q)


def quaternion_to_rodrigues(q: Float[Array, "4"]) -> Vector3:
    """Axis-angle vector (angle in [0, π]) of the quaternion q = (w, x, y, z)."""
    q = q / jnp.linalg.norm(q)
    q = jnp.where(q[0] < 0, -q, q)
    w, v = q[0], q[1:]
    sin_half, _, small = _safe_norm(v)
    # θ = 2 atan2(|v|, w); θ / |v| → 2 / w as |v| → 0.
    factor = jnp.where(small, 2.0 / w, 2.0 * jnp.arctan2(sin_half, w) / sin_half)
    return factor * v


def rodrigues_to_quaternion(r: Vector3) -> Float[Array, "4"]:
    """Unit quaternion (w, x, y, z) of the axis-angle vector `r` (radians)."""
    theta, squared, small = _safe_norm(r)
    half = 0.5 * theta
    cos_half = jnp.where(small, 1.0 - squared / 8.0, jnp.cos(half))
    sinc_half = jnp.where(small, 0.5 - squared / 48.0, jnp.sin(half) / theta)
    return jnp.concatenate([cos_half[None], sinc_half * r])


def matrix_to_rodrigues(m: Matrix3) -> Vector3:
    """Axis-angle vector of the rotation matrix `m` (through the quaternion; exact near 0 and π)."""
    return quaternion_to_rodrigues(matrix_to_quaternion(m))


def _skew(v: Vector3) -> Matrix3:
    """Cross-product matrix: _skew(a) @ b == cross(a, b)."""
    return jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
