"""Blunders among the image points of an initialised block, flagged where the evidence says so.

Before the adjustment a camera's distortion is unknown (0 in most projects): rays near the
format's edge are bent by up to tens of pixels, points intersected from them are off, and
their other rays miss by as much. Such misfits are no evidence of a blunder. An image point,
its residual |v| scaled for its point's number of rays, is a blunder (`flag`) when

1. it exceeds what the unknown distortion may leave there (`distortion_allowance`: a
   fraction `unknown_distortion` of the radius at the edge of the camera's image points,
   falling with the cube of the radius towards the centre as a radial distortion; the
   largest of its point's k rays, times 1 + 1 / (k - 2): a point intersected from a bent ray
   is off in every image, the more so the fewer rays hold it), plus the noise's familywise
   bound: `threshold` σ (the camera's robust σ), raised to sqrt(2 ln(n / FAMILYWISE_ALPHA)) σ
   for the camera's n image points (a 2D normal residual's norm exceeds t σ with probability
   exp(-t²/2)): clean data flag nothing but by chance 1 in 20;
2. and it stands out from the other rays of its point: OUTLYING times their median residual.
   Where an approximate camera bends a point's rays, several of them miss; a blunder misses
   alone. A point on 2 rays cannot say which one is wrong: it is flagged by neither (a blunder
   there shows when its rays do not meet).
"""

import numpy as np

FAMILYWISE_ALPHA = 0.05
"""Probability that clean image points of a camera flag one or more blunders."""
UNKNOWN_DISTORTION = 0.015
"""The misfit an unknown distortion may leave at the edge of a camera's image points, as a
fraction of their radius there: 54 px at the corner of a 6000 x 4000 px format, 7 px halfway
out. The close-range block's clean image points before calibration (30 px of distortion at
the corner, `write_close_range_project`) miss by up to 13 px at 70 % of the corner's radius,
where this allows 19 px."""
EDGE_QUANTILE = 0.99
"""The edge of a camera's image points: this quantile of their radii."""
OUTLYING = 3.0
"""A blunder stands out from its point's other rays: its residual exceeds this many times
their median."""


def distortion_allowance(q: np.ndarray, unknown_distortion: float) -> np.ndarray:
    """The misfit (n,) (normalised units) an unknown distortion may leave at one camera's
    image points of normalised coordinates q (n, 2): `unknown_distortion` ρ_e (ρ / ρ_e)³,
    ρ = |q|, ρ_e the EDGE_QUANTILE of ρ."""
    radius = np.linalg.norm(q, axis=1)
    edge = float(np.quantile(radius, EDGE_QUANTILE)) if len(radius) else 0.0
    if not edge > 0:
        return np.zeros(len(q))
    return unknown_distortion * edge * (radius / edge) ** 3


def point_allowance(q: np.ndarray, points: np.ndarray, unknown_distortion: float) -> np.ndarray:
    """What an unknown distortion may leave (n,) (normalised units) at one camera's image
    points of normalised coordinates q (n, 2) of `points` (n,): the largest
    `distortion_allowance` of the point's k rays (a point intersected from a bent ray is off
    in its other images too), times 1 + 1 / (k - 2) (the more so the fewer rays hold it)."""
    allowed = distortion_allowance(q, unknown_distortion)
    index, inverse = np.unique(points, return_inverse=True)
    worst = np.zeros(len(index))
    np.maximum.at(worst, inverse, allowed)
    rays = np.bincount(inverse, minlength=len(index))
    return worst[inverse] * (1 + 1 / np.maximum(rays[inverse] - 2, 1))


def familywise(count: int, threshold: float) -> float:
    """The cut in σ of the norm of one of `count` 2D residuals: `threshold`, raised to the
    familywise bound sqrt(2 ln(count / FAMILYWISE_ALPHA))."""
    return max(float(threshold), float(np.sqrt(2 * np.log(max(count, 1) / FAMILYWISE_ALPHA))))


def flag(norms: np.ndarray, sigma: float, allowed: np.ndarray, threshold: float,
         points: np.ndarray) -> np.ndarray:
    """Blunders (n,) bool among one camera's residual norms (n,) with σ `sigma`, of image
    points of `points` (n,), `allowed` (n,) the misfit an unknown distortion may leave there
    (module docstring, steps 2 and 3)."""
    over = ~(norms <= familywise(len(norms), threshold) * sigma + allowed)
    if not np.any(over):
        return over
    order = np.argsort(points, kind="stable")
    starts = np.flatnonzero(np.diff(points[order], prepend=-1))
    typical = np.full(len(norms), np.inf)
    for rows in np.split(order, starts[1:]):
        if len(rows) >= 3:
            typical[rows] = np.median(norms[rows])
    return over & (norms > OUTLYING * typical)
