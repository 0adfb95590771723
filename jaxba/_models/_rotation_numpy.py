"""jaxba's omega-phi-kappa rotation in plain NumPy, for the code that runs outside jax.

The same formulas as `opk_to_matrix` and `matrix_to_opk` of `jaxba._models._rotation`
(docs/conventions.md: M = R3(kappa) R2(phi) R1(omega) = R_m^c, `p_image = M @ (X - X0)`), plus
their closed-form derivative, vectorised over any leading axes. For the approximations, the
block initialisation and the file formats: small arrays evaluated many times one by one,
where a jax dispatch would cost a hundred times the arithmetic.
"""

import numpy as np


def _sines_cosines(opk) -> tuple[np.ndarray, ...]:
    """(so, sp, sk, co, cp, ck), each of the leading shape of `opk` (..., 3)."""
    opk = np.asarray(opk, dtype=np.float64)
    if opk.shape[-1:] != (3,):
        raise ValueError(f"omega, phi, kappa must have shape (..., 3), got {opk.shape}")
    sines, cosines = np.sin(opk), np.cos(opk)
    return (*np.moveaxis(sines, -1, 0), *np.moveaxis(cosines, -1, 0))


def _matrices(entries: list[list[np.ndarray]]) -> np.ndarray:
    """Rows of entries (each of one leading shape) as matrices (..., rows, columns)."""
    return np.stack([np.stack(row, axis=-1) for row in entries], axis=-2)


def opk_to_matrix(opk) -> np.ndarray:
    """M = R3(kappa) R2(phi) R1(omega) (..., 3, 3) of (omega, phi, kappa) (..., 3), radians."""
    so, sp, sk, co, cp, ck = _sines_cosines(opk)
    return _matrices([
        [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
        [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
        [sp, -so * cp, co * cp],
    ])


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
    return np.stack([_matrices(d) for d in (d_omega, d_phi, d_kappa)], axis=-1)


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
