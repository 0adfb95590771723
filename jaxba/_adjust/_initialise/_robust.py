"""Robust versions of the approximation tools for block initialisation: relative orientation
of a pair, space resection and forward intersection with blunders among the image points.

Everything works on normalised ideal coordinates q = (a, b), the ray (a, b, -1) ∝ M (X - X0)
(`ideal_coordinates`), so the tools of `jaxba._approximations` take them with c = 1 and
principal point 0; residuals are in the same normalised units (radians, near the axis).

Hypotheses come from random minimal samples (a seeded `numpy.random.Generator`: the result is
deterministic) and are scored over all points: by the least median of squares when no threshold
is known yet (robust up to 50 % blunders; it also gives the noise level), by MSAC (truncated
squares) otherwise. The best hypothesis is refined by the least-squares tool on its inliers,
twice, re-selecting the inliers in between.
"""

import dataclasses

import numpy as np

from ..._approximations import (
    essential_matrix,
    forward_intersection,
    relative_orientation,
    space_resection,
)
from ..._approximations._intersection import closest_points
from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix

MAD_TO_SIGMA = 1.4826
"""σ of a normal distribution per median absolute deviation (1D residuals)."""
RAYLEIGH_MEDIAN = 1.1774
"""Median of the norm of a 2D residual with σ per coordinate, in σ: sqrt(2 ln 2)."""
SAMPSON_K = 3.0
"""Inlier threshold of a Sampson distance (1D) in σ."""
CONFIDENCE = 0.999
"""Probability that RANSAC drew at least one clean sample (its number of samples)."""
ESSENTIAL_SAMPLE = 9
"""Points of an essential-matrix sample: `essential_matrix` takes its null vector from the SVD
of the 9 x 9 system, so 9 points (8 leave the SVD one singular value short)."""
SIGMA_FLOOR = 1e-9
"""Smallest σ (normalised units) a threshold is made from (noise-free data)."""
PAIR_ANGLE = np.radians(5.0)
"""A pair whose median intersection angle reaches this scores by its inlier count alone;
below it, the count is weighted down in proportion."""
RAY_PAIRS = 2000
"""Most pairs of rays a robust intersection tries: all of them up to 63 rays, a seeded random
sample beyond (with half the rays blunders, no clean pair among 2000 has odds 0.75^2000)."""
ERRORS_PER_CHUNK = 200_000
"""Reprojection errors evaluated at once when scoring pair points (memory bound)."""


def rays(q: np.ndarray) -> np.ndarray:
    """Rays (a, b, -1) (n, 3) of normalised coordinates (n, 2)."""
    return np.c_[q, -np.ones(len(q))]


def project(m: np.ndarray, station: np.ndarray, points: np.ndarray):
    """Normalised coordinates (n, 2) = -(U, V) / W of points (n, 3) and W (n,) (W < 0: in
    front), (U, V, W) = M (X - X0)."""
    uvw = (points - station) @ m.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return -uvw[:, :2] / uvw[:, 2:], uvw[:, 2]


def reprojection(m, station, points, q) -> np.ndarray:
    """|q - projected| (n,) (normalised units); inf for points behind the image (W >= 0)."""
    computed, w = project(m, station, points)
    errors = np.linalg.norm(q - computed, axis=1)
    return np.where((w < 0) & np.isfinite(errors), errors, np.inf)


def samples_needed(inlier_fraction: float, size: int) -> float:
    """Samples for CONFIDENCE that one of `size` points is all inliers."""
    clean = inlier_fraction**size
    if clean >= 1.0:
        return 1.0
    if clean <= 0.0:
        return np.inf
    return np.log(1 - CONFIDENCE) / np.log(1 - clean)


def _score(errors: np.ndarray, threshold) -> float:
    """Least median of squares (threshold None) or MSAC, lower is better."""
    if threshold is None:
        return float(np.median(errors**2))
    return float(np.sum(np.minimum(errors, threshold) ** 2))


# ----------------------------------------------------------------------------------------
# Relative orientation of a pair.


@dataclasses.dataclass(frozen=True)
class Pair:
    """A robustly oriented pair, in the frame of its first image (at the origin, M = I) with a
    unit base: `eops` (2, 6); `inliers` (n,) bool; `sampson` (n,) coplanarity distances
    (normalised units); `sigma` the robust σ of a normalised coordinate; `angles` (n,) the
    intersection angles of the rays (radians); `hypotheses` tried."""

    eops: np.ndarray
    inliers: np.ndarray
    sampson: np.ndarray
    sigma: float
    angles: np.ndarray
    hypotheses: int

    @property
    def median_angle(self) -> float:
        """The median intersection angle of the inliers (radians)."""
        return float(np.median(self.angles[self.inliers])) if np.any(self.inliers) else 0.0

    @property
    def score(self) -> float:
        """Inliers, weighted by min(1, median intersection angle / PAIR_ANGLE)."""
        return float(np.sum(self.inliers)) * min(1.0, self.median_angle / PAIR_ANGLE)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _depths(r1, r2, m, base):
    """λ1, λ2 (n,) with λ1 r1 - λ2 Mᵀ r2 ≈ b in least squares, and Mᵀ r2 (n, 3)."""
    d2 = r2 @ m  # Mᵀ r2: image 2's rays in image 1's frame
    aa, ab, bb = np.sum(r1 * r1, 1), np.sum(r1 * d2, 1), np.sum(d2 * d2, 1)
    ab_, db_ = r1 @ base, d2 @ base
    det = aa * bb - ab * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        return (bb * ab_ - ab * db_) / det, (ab * ab_ - aa * db_) / det, d2


def pair_points(q1, q2, m, base):
    """Model points (n, 3) of a pair in image 1's frame (image 1 at the origin, M = I; image 2
    at `base` with rotation `m`): the midpoints of the shortest segments between the rays."""
    r1 = rays(q1)
    lambda1, lambda2, d2 = _depths(r1, rays(q2), m, base)
    return (lambda1[:, None] * r1 + base + lambda2[:, None] * d2) / 2


def pair_geometry(r1, r2, m, base):
    """Sampson distances (n,) of E = M [b]ₓ (r2ᵀ E r1 = 0) and the intersection angles (n,);
    points behind either image get an infinite distance. Image 1 at the origin with identity
    rotation, image 2 at `base` with rotation `m`."""
    e = m @ _skew(base)
    f = np.einsum("ni,ij,nj->n", r2, e, r1)
    g1, g2 = r2 @ e, r1 @ e.T  # dF/dr1, dF/dr2
    norm = np.sqrt(g1[:, 0] ** 2 + g1[:, 1] ** 2 + g2[:, 0] ** 2 + g2[:, 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        sampson = np.abs(f) / norm
    # λ1 r1 - λ2 Mᵀ r2 ≈ b in least squares: both positive in front of both images.
    lambda1, lambda2, d2 = _depths(r1, r2, m, base)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosines = np.sum(r1 * d2, 1) / np.sqrt(np.sum(r1 * r1, 1) * np.sum(d2 * d2, 1))
    front = (lambda1 > 0) & (lambda2 > 0)
    sampson = np.where(front & np.isfinite(sampson), sampson, np.inf)
    return sampson, np.arccos(np.clip(cosines, -1.0, 1.0))


def _independent_start(m, base):
    """The independent relative orientation's parameters (phi1, kappa1, omega2, phi2, kappa2)
    with bx = 1 of image 2 at unit `base` with rotation `m` (image 1 at the origin, M = I):
    M1's first column is the base, so that the model's x axis runs along it."""
    phi1 = np.arcsin(np.clip(base[2], -1.0, 1.0))
    kappa1 = np.arctan2(-base[1], base[0])
    m1 = opk_to_matrix(np.array([0.0, phi1, kappa1]))
    return np.r_[phi1, kappa1, matrix_to_opk(m @ m1)]


def _pair_frame(orientation):
    """(M, unit base) of image 2 in image 1's frame from a `RelativeOrientation`."""
    m1, m2 = opk_to_matrix(orientation.eops[0, 3:]), opk_to_matrix(orientation.eops[1, 3:])
    base = m1 @ orientation.eops[1, :3]
    return m2 @ m1.T, base / np.linalg.norm(base)


def _homography(r1, r2):
    """H (3, 3) with r2 ∝ H r1 from 4 or more ray pairs (DLT: r2 × H r1 = 0), or None."""
    zeros = np.zeros_like(r1)
    rows = np.r_[np.c_[zeros, -r2[:, 2:] * r1, r2[:, 1:2] * r1],
                 np.c_[r2[:, 2:] * r1, zeros, -r2[:, :1] * r1]]
    _, singular, vt = np.linalg.svd(rows)
    if singular[min(len(singular), 8) - 1] <= 1e-10 * singular[0]:
        return None
    return vt[-1].reshape(3, 3)


def _decompose_homography(h, r1, r2):
    """The (M, unit base) candidates of a calibrated homography H ∝ R + T Nᵀ / d (X2 = R X1 +
    T; Ma, Soatto, Košecká and Sastry, "An Invitation to 3-D Vision", 5.3.3): H scaled to
    its middle singular value 1 and signed so that r2ᵀ H r1 > 0 (depths positive), then the
    two solutions from the eigenvectors of HᵀH and their negatives (T -> -T); the base is
    b = -Rᵀ T (image 2 at b with M = R)."""
    h = h / np.linalg.svd(h, compute_uv=False)[1]
    if np.median(np.einsum("ni,ij,nj->n", r2, h, r1)) < 0:
        h = -h
    eigenvalues, v = np.linalg.eigh(h.T @ h)
    s3, _, s1 = eigenvalues  # ascending: σ3², σ2² (= 1), σ1²
    v1, v2, v3 = v[:, 2], v[:, 1], v[:, 0]
    if s1 - s3 < 1e-12:
        return []  # a pure rotation: no base
    a, b = np.sqrt(max(1 - s3, 0.0)), np.sqrt(max(s1 - 1, 0.0))
    out = []
    for u in ((a * v1 + b * v3) / np.sqrt(s1 - s3), (a * v1 - b * v3) / np.sqrt(s1 - s3)):
        hv2, hu = h @ v2, h @ u
        m = np.c_[hv2, hu, np.cross(hv2, hu)] @ np.c_[v2, u, np.cross(v2, u)].T
        normal = np.cross(v2, u)
        t = (h - m) @ normal
        length = np.linalg.norm(t)
        if not length > 0:
            continue
        base = -m.T @ t / length
        out += [(m, base), (m, -base)]
    return out


def _refine_pair(q1, q2, r1, r2, m, base, sigma) -> "Pair":
    """`relative_orientation` (independent, bx = 1) on the points within SAMPSON_K σ of the
    hypothesis (M, base), twice, re-selecting them in between."""
    n = len(q1)
    for _ in range(2):
        sampson, _ = pair_geometry(r1, r2, m, base)
        finite = sampson[np.isfinite(sampson)]
        if len(finite) < 8:
            raise ValueError("most points lie behind the images in the best hypothesis")
        spread = sigma if sigma is not None else MAD_TO_SIGMA * float(np.median(finite)) * (
            1 + 5 / max(len(finite) - 8, 1))
        inliers = sampson <= SAMPSON_K * max(spread, SIGMA_FLOOR)
        if np.sum(inliers) < 8:
            raise ValueError(f"only {int(np.sum(inliers))} of {n} points fit the best "
                             "relative orientation")
        refined = relative_orientation(q1[inliers], q2[inliers], 1.0,
                                       parameterisation="independent", bx=1.0,
                                       start=_independent_start(m, base))
        m, base = _pair_frame(refined)
    sampson, intersection = pair_geometry(r1, r2, m, base)
    finite = sampson[np.isfinite(sampson)]
    spread = sigma if sigma is not None else MAD_TO_SIGMA * float(np.median(finite)) * (
        1 + 5 / max(len(finite) - 8, 1))
    inliers = sampson <= SAMPSON_K * max(spread, SIGMA_FLOOR)
    eops = np.zeros((2, 6))
    eops[1] = np.r_[base, matrix_to_opk(m)]
    return Pair(eops=eops, inliers=inliers, sampson=sampson, sigma=float(spread),
                angles=intersection, hypotheses=0)


def orient_pair(q1, q2, rng, *, sigma=None, min_samples=30, rotation_samples=30,
                homography_samples=30, max_samples=500) -> Pair:
    """A robust relative orientation of two images from their conjugate normalised
    coordinates q1, q2 (n, 2), n >= 9.

    Hypotheses (rotation, base direction) of three kinds: the essential matrix of random
    9-point samples (`essential_matrix`; `min_samples`, more up to `max_samples` while the
    share of points within SAMPSON_K σ of the best so far asks for them, CONFIDENCE); the
    decompositions of the homography of random 4-point samples (a flat scene, where the
    essential matrix is degenerate); and the identity rotation with the base from random
    2-point samples, b ∝ (r1 × r2) × (r1' × r2') (near-vertical aerial pairs). Each is scored
    by the least median of squared Sampson distances over all points (points behind an image
    count as infinitely far): robust up to 50 % blunders, and it gives σ. The best of each
    kind is refined by `relative_orientation` (independent, bx = 1) on the points within
    SAMPSON_K σ; of those the one with the best `Pair.score` (inliers, weighted down for
    intersection angles below PAIR_ANGLE: a flat scene's twin solution has its base along
    the view) wins, then the smaller median Sampson distance. `sigma`: the σ of a normalised
    coordinate when known. Raises ValueError when no hypothesis holds.
    """
    n = len(q1)
    if n < ESSENTIAL_SAMPLE:
        raise ValueError(f"{n} common points; a pair needs at least {ESSENTIAL_SAMPLE}")
    r1, r2 = rays(q1), rays(q2)
    best = {"essential": (np.inf, None), "homography": (np.inf, None),
            "rotation": (np.inf, None)}
    tried = 0

    def consider(kind, m, base):
        nonlocal tried
        tried += 1
        sampson, _ = pair_geometry(r1, r2, m, base)
        score = float(np.median(sampson**2))
        if score < best[kind][0]:
            best[kind] = (score, (m, base))

    total, count = max_samples, 0
    while count < total:
        count += 1
        sample = rng.choice(n, ESSENTIAL_SAMPLE, replace=False)
        try:
            ess = essential_matrix(q1[sample], q2[sample], 1.0)
        except ValueError:
            continue
        consider("essential", ess.rotation, ess.base)
        if count >= min_samples and best["essential"][1] is not None:
            # As many samples as the share of points near the best hypothesis asks for.
            score, hypothesis = best["essential"]
            sampson, _ = pair_geometry(r1, r2, *hypothesis)
            spread = MAD_TO_SIGMA * np.sqrt(score) if sigma is None else sigma
            fraction = np.mean(sampson <= SAMPSON_K * max(spread, SIGMA_FLOOR))
            total = int(min(max_samples, max(min_samples,
                                             samples_needed(fraction, ESSENTIAL_SAMPLE))))
    for _ in range(homography_samples):
        sample = rng.choice(n, 4, replace=False)
        h = _homography(r1[sample], r2[sample])
        if h is None:
            continue
        for m, base in _decompose_homography(h, r1[sample], r2[sample]):
            consider("homography", m, base)
    identity = np.eye(3)
    for _ in range(rotation_samples):
        a, b = rng.choice(n, 2, replace=False)
        base = np.cross(np.cross(r1[a], r2[a]), np.cross(r1[b], r2[b]))
        length = np.linalg.norm(base)
        if not length > 0:
            continue
        consider("rotation", identity, base / length)
        consider("rotation", identity, -base / length)
    candidates, errors = [], []
    for kind, (_, hypothesis) in best.items():
        if hypothesis is None:
            continue
        try:
            candidates.append(_refine_pair(q1, q2, r1, r2, *hypothesis, sigma))
        except (ValueError, np.linalg.LinAlgError) as error:
            errors.append(f"{kind}: {error}")
    if not candidates:
        raise ValueError("; ".join(errors) or "no hypothesis from any sample (degenerate "
                         "point sets)")
    chosen = max(candidates, key=lambda pair: (
        pair.score, -float(np.median(pair.sampson[pair.inliers]))))
    return dataclasses.replace(chosen, hypotheses=tried)


# ----------------------------------------------------------------------------------------
# Space resection.


@dataclasses.dataclass(frozen=True)
class RobustResection:
    """`eop` (6,); `inliers` (n,) bool; `errors` (n,) reprojection errors |v| (normalised);
    `sigma`: the robust σ of a normalised coordinate of the inliers; `hypotheses` tried."""

    eop: np.ndarray
    inliers: np.ndarray
    errors: np.ndarray
    sigma: float
    hypotheses: int


def _space_resection(q, points, **options):
    """`space_resection` with c = 1; 4 points without a start get one of them twice (its
    closed form takes the null vector of an 8 x 9 system from an SVD that needs 9 rows)."""
    if len(q) == 4 and options.get("start") is None:
        q, points = np.r_[q, q[:1]], np.r_[points, points[:1]]
    return space_resection(q, points, 1.0, **options)


def _errors(eop, points, q):
    return reprojection(opk_to_matrix(eop[3:]), eop[:3], points, q)


def resect(q, points, rng, *, threshold=None, start=None, min_samples=20, max_samples=200,
           min_inliers=4) -> RobustResection:
    """A robust space resection from normalised coordinates q (n, 2) of known points (n, 3).

    Hypotheses: `space_resection` of random 6-point samples (n when n < 7; its closed form
    takes the plane homography or the calibrated DLT, a few Levenberg-Marquardt steps) and
    `start` if given; scored by the least median of squared reprojection errors (`threshold`
    None) or MSAC with `threshold` (n,) or scalar (normalised units, on |v|). The best is
    refined by `space_resection` on its inliers (|v| within 3.5 robust σ of its own errors,
    or `threshold` if larger), twice.
    Raises ValueError for fewer than `min_inliers` inliers or no hypothesis.
    """
    n = len(q)
    if n < max(4, min_inliers):
        raise ValueError(f"{n} points of known coordinates; need at least {max(4, min_inliers)}")
    size = 6 if n >= 7 else min(n, 5)
    best = (np.inf, None)
    tried = 0

    def consider(eop):
        nonlocal best
        errors = _errors(eop, points, q)
        score = _score(errors, threshold)
        if score < best[0]:
            best = (score, eop)

    if start is not None and np.all(np.isfinite(start)):
        consider(np.asarray(start, dtype=np.float64))
    total, count = max_samples, 0
    while count < total:
        count += 1
        sample = rng.choice(n, size, replace=False)
        try:
            fit = _space_resection(q[sample], points[sample], max_iterations=5)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if not np.all(np.isfinite(fit.eop)):
            continue
        tried += 1
        consider(fit.eop)
        if count >= min_samples and best[1] is not None:
            errors = _errors(best[1], points, q)
            cut = _cut(errors, threshold)
            total = int(min(max_samples, max(min_samples,
                                              samples_needed(np.mean(errors <= cut), size))))
    if best[1] is None:
        raise ValueError("no resection from any sample (collinear or degenerate points)")
    eop = best[1]
    for _ in range(2):
        errors = _errors(eop, points, q)
        inliers = errors <= _cut(errors, threshold)
        if np.sum(inliers) < max(4, min_inliers):
            raise ValueError(f"only {int(np.sum(inliers))} of {n} points fit the best "
                             "resection")
        try:
            eop = _space_resection(q[inliers], points[inliers], start=eop).eop
        except (ValueError, np.linalg.LinAlgError) as error:
            raise ValueError(f"the resection on its inliers failed: {error}") from None
    errors = _errors(eop, points, q)
    inliers = errors <= _cut(errors, threshold)
    return RobustResection(eop=eop, inliers=inliers, errors=errors,
                           sigma=robust_sigma(errors), hypotheses=tried)


def robust_sigma(errors) -> float:
    """σ per coordinate from the median of 2D residual norms (Rayleigh), ignoring infinities."""
    finite = np.asarray(errors)[np.isfinite(errors)]
    return float(np.median(finite) / RAYLEIGH_MEDIAN) if len(finite) else np.inf


def _cut(errors, threshold):
    """The inlier cut of the 2D residual norms of a resection: 3.5 robust σ of `errors`
    (chi² 2 dof 99.8 %) with Rousseeuw's small-sample factor 1 + 5 / (2n - 6), or
    `threshold` if larger (the errors of intersected points add to those of the image
    coordinates: the image's own spread may exceed the block's σ)."""
    small = 1 + 5 / max(2 * len(errors) - 6, 1)
    own = 3.5 * max(robust_sigma(errors) * small, SIGMA_FLOOR)
    return own if threshold is None else np.maximum(threshold, own)


# ----------------------------------------------------------------------------------------
# Forward intersection.


@dataclasses.dataclass(frozen=True)
class RobustIntersection:
    """`point` (3,) or None with `reason`; `inliers` (k,) bool; `errors` (k,) |v|
    (normalised; inf behind an image); `angle`: the largest angle between inlier rays."""

    point: np.ndarray | None
    inliers: np.ndarray
    errors: np.ndarray
    angle: float
    reason: str = ""


def _largest_angle(directions):
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return float(np.max(np.arccos(np.clip(units @ units.T, -1.0, 1.0))))


def _ray_pairs(k):
    """(i, j) (p,) each: every pair i < j of k rays in order, or `RAY_PAIRS` random pairs
    i != j (seeded by k: deterministic) when there are more."""
    if k * (k - 1) // 2 <= RAY_PAIRS:
        return np.triu_indices(k, 1)
    rng = np.random.default_rng(k)
    first = rng.integers(k, size=RAY_PAIRS)
    return first, (first + rng.integers(1, k, size=RAY_PAIRS)) % k


def intersect(q, eops, matrices, threshold, min_angle) -> RobustIntersection:
    """A robust forward intersection of one point from k >= 2 rays (normalised coordinates q
    (k, 2) in images `eops` (k, 6) with rotations `matrices` (k, 3, 3)).

    All rays first (`forward_intersection`); when some misses by more than `threshold` (k,)
    and k >= 3, every pair of rays (or `RAY_PAIRS` of them, `_ray_pairs`) proposes a point
    (the point closest to both rays), the one that most rays fit (then the least truncated
    squares) wins and is refined on them. The point needs two inlier rays
    meeting at `min_angle` (radians) or more.
    """
    k = len(q)
    directions = np.einsum("kji,kj->ki", matrices, rays(q))  # Mᵀ r
    threshold = np.broadcast_to(np.asarray(threshold, dtype=np.float64), (k,))

    def errors_of(points):
        """|v| (..., k) of every ray at points (..., 3); inf behind an image."""
        uvw = np.einsum("kij,...kj->...ki", matrices, points[..., None, :] - eops[:, :3])
        with np.errstate(divide="ignore", invalid="ignore"):
            errors = np.linalg.norm(q + uvw[..., :2] / uvw[..., 2:], axis=-1)
        return np.where((uvw[..., 2] < 0) & np.isfinite(errors), errors, np.inf)

    def fit(index):
        try:
            return forward_intersection(q[index], eops[index], 1.0, max_iterations=10).point
        except (ValueError, np.linalg.LinAlgError):
            return None

    every = np.arange(k)
    point = fit(every)
    errors = errors_of(point) if point is not None else np.full(k, np.inf)
    inliers = errors <= threshold
    if not np.all(inliers) and k >= 3:
        best = (np.sum(inliers), -np.sum(np.minimum(errors, threshold) ** 2), point)
        pairs = np.stack(_ray_pairs(k), axis=-1)
        candidates, parallel = closest_points(eops[:, :3][pairs], directions[pairs])
        candidates = candidates[~parallel]
        chunk = max(1, ERRORS_PER_CHUNK // k)
        for start in range(0, len(candidates), chunk):
            e = errors_of(candidates[start:start + chunk])
            counts = np.sum(e <= threshold, axis=1)
            scores = -np.sum(np.minimum(e, threshold) ** 2, axis=1)
            top = np.flatnonzero(counts == counts.max())
            winner = top[np.argmax(scores[top])]  # the first of the best, as a loop over pairs
            if (counts[winner], scores[winner]) > best[:2]:
                best = (counts[winner], scores[winner], candidates[start + winner])
        if best[2] is not None and best[0] >= 2:
            chosen = np.flatnonzero(errors_of(best[2]) <= threshold)
            refined = fit(chosen)
            if refined is not None:
                point, errors = refined, errors_of(refined)
                inliers = errors <= threshold
    if point is None or np.sum(inliers) < 2:
        worst = float(np.max(errors)) if np.all(np.isfinite(errors)) else np.inf
        return RobustIntersection(None, inliers, errors, 0.0,
                                  f"its {k} rays do not meet (largest miss {worst:.2e} "
                                  "normalised units): a blunder?")
    angle = _largest_angle(directions[inliers])
    if angle < min_angle:
        return RobustIntersection(None, inliers, errors, angle,
                                  f"its rays meet at {np.degrees(angle):.2f}° < "
                                  f"{np.degrees(min_angle):.2f}°")
    return RobustIntersection(point, inliers, errors, angle)
