"""jaxba's omega-phi-kappa rotation in plain NumPy, for the code that runs outside jax.

The same formulas as `opk_to_matrix` and `matrix_to_opk` of `jaxba._models._rotation`
(docs/conventions.md: M = R3(kappa) R2(phi) R1(omega) = R_m^c, `p_image = M @ (X - X0)`), plus
their closed-form derivative, vectorised over any leading axes, and Rodrigues' formula for
one rotation vector (`rodrigues_to_matrix`, the datum's similarity). For the approximations, the
block initialisation and the file formats: small arrays evaluated many times one by one,
where a jax dispatch would cost a hundred times the arithmetic.
"""

import numpy as np


def _sines_cosines(opk) -> tuple[np.ndarray, ...]:
    """(so, sp, sk, co, cp, ck), each of the leading shape of `opk` (..., 3)."""
    opk = np.asarray(opk, dtype=np.float64)
    if opk.shape[-1:] != (3,):
        raise ValueError(f"omega, phi, kappa must have shape (..., 3), got {opk.shape}")
    s, c = np.sin(opk), np.cos(opk)
    return s[..., 0], s[..., 1], s[..., 2], c[..., 0], c[..., 1], c[..., 2]


def _array(entries: list, shape: tuple[int, ...]) -> np.ndarray:
    """Entries (each of one leading shape), in row-major order, as an array (..., *shape)."""
    return np.stack(entries, axis=-1).reshape(*entries[0].shape, *shape)


def opk_to_matrix(opk) -> np.ndarray:
    """M = R3(kappa) R2(phi) R1(omega) (..., 3, 3) of (omega, phi, kappa) (..., 3), radians."""
    so, sp, sk, co, cp, ck = _sines_cosines(opk)
    return _array([
        cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck,
        -cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk,
        sp, -so * cp, co * cp,
    ], (3, 3))


def opk_derivatives(opk) -> np.ndarray:
    """dM/d(omega, phi, kappa) (..., 3, 3, 3) of `opk` (..., 3): entry [..., i, j, k] is
    dM_ij / d angle_k (per radian), the layout of `jax.jacfwd(opk_to_matrix)`."""
    so, sp, sk, co, cp, ck = _sines_cosines(opk)
    zero = np.zeros_like(so)
    d_omega = [
        [zero, -so * sk + co * sp * ck, co * sk + so * sp * ck],
        [zero, -so * ck - co * sp * sk, co * ck - so * sp * sk],
        [zero, -co * cp, -so * cp],
    ]
    d_phi = [
        [-sp * ck, so * cp * ck, -co * cp * ck],
        [sp * sk, -so * cp * sk, co * cp * sk],
        [cp, so * sp, -co * sp],
    ]
    d_kappa = [
        [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
        [-cp * ck, -co * sk - so * sp * ck, -so * sk + co * sp * ck],
        [zero, zero, zero],
    ]
    by_angle = (d_omega, d_phi, d_kappa)
    return _array([by_angle[k][i][j] for i in range(3) for j in range(3) for k in range(3)],
                  (3, 3, 3))


def matrix_to_opk(m) -> np.ndarray:
    """(omega, phi, kappa) (..., 3) in radians of rotation matrices `m` (..., 3, 3), the
    inverse of `opk_to_matrix` for |phi| < 90°: omega = atan2(-m32, m33),
    phi = atan2(m31, hypot(m32, m33)) (accurate near ±90°), kappa = atan2(-m21, m11)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"a rotation matrix must have shape (..., 3, 3), got {m.shape}")
    return np.stack([
        np.arctan2(-m[..., 2, 1], m[..., 2, 2]),
        np.arctan2(m[..., 2, 0], np.hypot(m[..., 2, 1], m[..., 2, 2])),
        np.arctan2(-m[..., 1, 0], m[..., 0, 0]),
    ], axis=-1)


def rodrigues_to_matrix(r) -> np.ndarray:
    """Rotation matrix (3, 3) of the axis-angle vector `r` (3,), radians: R = I + sin(θ) K +
    (1 - cos(θ)) K², K = [r/θ]_x, θ = |r| (as `jaxba._models._rotation`'s, with its Taylor
    terms below θ² = 1e-24)."""
    r = np.asarray(r, dtype=np.float64)
    squared = float(r @ r)
    k = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    if squared < 1e-24:
        sin_term, cos_term = 1.0 - squared / 6.0, 0.5 - squared / 24.0
    else:
        theta = np.sqrt(squared)
        sin_term, cos_term = np.sin(theta) / theta, (1.0 - np.cos(theta)) / squared
    return np.eye(3) + sin_term * k + cos_term * (k @ k)
