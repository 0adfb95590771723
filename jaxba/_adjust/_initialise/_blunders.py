"""Blunders among the image points of an initialised block, judged as the evidence allows.

Before the adjustment the camera is approximate (distortion 0, c rounded): the residuals of
good image points carry a smooth field of several pixels at the format's edge, much larger
than the noise. Judged against a σ of the noise, every edge point would be a "blunder".

1. The systematic part is taken out per image (`systematic_free`): the residuals, in
   normalised units, are fitted by least squares with the field an unknown camera leaves,
   in the normalised ideal coordinates (a, b), r² = a² + b² (Brown's model):
   radial (a, b) r², r⁴, r⁶, principal distance (a, b), principal point (1, 0), (0, 1),
   decentring (r² + 2a², 2ab), (2ab, r² + 2b²) and affinity (b, 0); robustly (three passes,
   each on the residuals within INLIER_K robust σ of the last fit).
2. What is left is judged per camera against its robust σ (`flag`): an image point is a
   blunder when it exceeds `threshold` σ and the familywise bound of the camera's number of
   image points, sqrt(2 ln(n / FAMILYWISE_ALPHA)) σ (a 2D normal residual's norm exceeds
   t σ with probability exp(-t²/2)): clean data flag nothing but by chance 1 in 20.
3. And it stands out from the other rays of its point: OUTLYING times their median residual.
   Where an approximate camera bends the rays of a point near the format's edge, all of them
   miss by as much; a blunder misses alone. A point on 2 rays cannot say which one is wrong:
   it is flagged by neither (a blunder there shows when its rays do not meet).
"""

import numpy as np

from ._robust import RAYLEIGH_MEDIAN, SIGMA_FLOOR

INLIER_K = 3.5
"""Residuals within this many robust σ of a fit take part in the next one."""
FAMILYWISE_ALPHA = 0.05
"""Probability that clean image points of a camera flag one or more blunders."""
TERMS = 9
"""Terms of the systematic field fitted per image (module docstring)."""
OUTLYING = 3.0
"""A blunder stands out from its point's other rays: its residual exceeds this many times
their median."""
FIT_ROWS = 4
"""An image is fitted with TERMS terms only when it has this many times as many image
coordinates; else its residuals are judged as they are."""


def _basis(q: np.ndarray) -> np.ndarray:
    """The systematic field's terms (n, 2, TERMS) at normalised coordinates q (n, 2)."""
    a, b = q[:, 0], q[:, 1]
    r2 = a * a + b * b
    one, zero = np.ones_like(a), np.zeros_like(a)
    x = [a * r2, a * r2**2, a * r2**3, a, one, zero, r2 + 2 * a * a, 2 * a * b, b]
    y = [b * r2, b * r2**2, b * r2**3, b, zero, one, 2 * a * b, r2 + 2 * b * b, zero]
    return np.stack([np.stack(x, axis=1), np.stack(y, axis=1)], axis=1)


def systematic_free(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The residuals v (n, 2) of one image's points at normalised coordinates q (n, 2), both
    in normalised units, less their robust fit by the systematic field (module docstring);
    v as it is for fewer than FIT_ROWS * TERMS coordinates."""
    if 2 * len(v) < FIT_ROWS * TERMS:
        return v
    basis = _basis(q)
    keep = np.ones(len(v), dtype=bool)
    left = v
    for _ in range(3):
        if 2 * np.sum(keep) < FIT_ROWS * TERMS:
            break
        coefficients, *_ = np.linalg.lstsq(basis[keep].reshape(-1, TERMS), v[keep].reshape(-1),
                                           rcond=None)
        left = v - basis @ coefficients
        norms = np.linalg.norm(left, axis=1)
        sigma = max(float(np.median(norms[keep])) / RAYLEIGH_MEDIAN, SIGMA_FLOOR)
        keep = norms <= INLIER_K * sigma
    return left


def familywise(count: int, threshold: float) -> float:
    """The cut in σ of the norm of one of `count` 2D residuals: `threshold`, raised to the
    familywise bound sqrt(2 ln(count / FAMILYWISE_ALPHA))."""
    return max(float(threshold), float(np.sqrt(2 * np.log(max(count, 1) / FAMILYWISE_ALPHA))))


def flag(judged: np.ndarray, threshold: float, points: np.ndarray) -> np.ndarray:
    """Blunders (n,) bool among one camera's residual norms `judged` (n,) in σ, of image
    points of `points` (n,) (module docstring, steps 2 and 3)."""
    norms = judged
    over = ~(norms <= familywise(len(norms), threshold))
    if not np.any(over):
        return over
    order = np.argsort(points, kind="stable")
    starts = np.flatnonzero(np.diff(points[order], prepend=-1))
    typical = np.full(len(norms), np.inf)
    for rows in np.split(order, starts[1:]):
        if len(rows) >= 3:
            typical[rows] = np.median(norms[rows])
    return over & (norms > OUTLYING * typical)
