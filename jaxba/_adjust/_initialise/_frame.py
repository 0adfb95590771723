"""The model-to-object similarity from partial control: single coordinates of points (a height
point, the BASC lab's datum of 6 coordinates of 3 points) where `absolute_orientation`, whose
closed-form start needs 3 full points, cannot start.

X_G = T + S R X_M is fitted by least squares (scipy's Levenberg-Marquardt, R by its rotation
vector) to every given ground coordinate, from 24 starting rotations (the rotations of the
cube, T and S from the given coordinates' centroids and spreads); the scale is fixed when the
distances give it. Minimal control (7 coordinates, or 6 and a scale) fits several distinct
rotations exactly: they are all returned, best first, so that the caller can say so.
"""

import itertools

import numpy as np

DISTINCT_ANGLE = np.radians(1.0)
"""Two solutions whose rotations differ by more than this are distinct."""


def _cube_rotations():
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


def partial_similarity(model, ground, scale=None):
    """The similarities (T (3,), R (3, 3), S, RMS) that fit the given (finite) ground
    coordinates (n, 3) of model points (n, 3) best, best first: distinct rotations that fit
    within twice the best RMS (plus rounding), i.e. one unless the control is ambiguous.
    `scale`: S fixed (from distances), else estimated (needs 7 given coordinates). Empty when
    there are too few coordinates."""
    import scipy.optimize  # here: scipy.optimize's import (0.3 s) is not every run's
    from scipy.spatial.transform import Rotation

    model, ground = np.asarray(model, dtype=np.float64), np.asarray(ground, dtype=np.float64)
    given = np.isfinite(ground)
    unknowns = 6 if scale is not None else 7
    if np.sum(given) < unknowns or len(model) < 2:
        return []
    observed = ground[given]
    extent = float(np.max(np.ptp(model, axis=0))) or 1.0
    ground_extent = float(np.nanmax(np.abs(observed - np.mean(observed)))) or 1.0

    def unpack(x):
        r = Rotation.from_rotvec(x[3:6]).as_matrix()
        s = scale if scale is not None else np.exp(x[6])
        return x[:3], r, s

    def residuals(x):
        t, r, s = unpack(x)
        return (observed - (t + s * model @ r.T)[given]) / ground_extent

    s0 = scale if scale is not None else ground_extent / extent
    solutions = []
    for r0 in _cube_rotations():
        moved = s0 * model @ r0.T
        t0 = np.array([np.mean(ground[given[:, k], k] - moved[given[:, k], k])
                       if np.any(given[:, k]) else 0.0 for k in range(3)])
        x0 = np.r_[t0, Rotation.from_matrix(r0).as_rotvec()]
        if scale is None:
            x0 = np.r_[x0, np.log(s0)]
        fit = scipy.optimize.least_squares(residuals, x0, method="lm", xtol=1e-14, ftol=1e-14)
        t, r, s = unpack(fit.x)
        if not (np.all(np.isfinite(fit.x)) and s > 0):
            continue
        rms = float(np.sqrt(np.mean(fit.fun**2))) * ground_extent
        solutions.append((t, r, float(s), rms))
    solutions.sort(key=lambda solution: solution[3])
    distinct = []
    for solution in solutions:
        if all(Rotation.from_matrix(solution[1] @ other[1].T).magnitude() > DISTINCT_ANGLE
               for other in distinct):
            distinct.append(solution)
    if not distinct:
        return []
    best = distinct[0][3]
    return [d for d in distinct if d[3] <= 2 * best + 1e-9 * ground_extent]
