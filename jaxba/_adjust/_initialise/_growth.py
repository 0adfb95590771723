"""The growth of a block initialisation (module docstring of `_block`, step 3): intersect the
points two oriented images see, orient the next image (resection or relative orientation to an
oriented neighbour), and refine the whole block now and then (`polish`).
"""

import numpy as np

from ..._approximations import space_resection
from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from ._robust import (
    SIGMA_FLOOR,
    intersect,
    orient_pair,
    pair_points,
    reprojection,
    resect,
    robust_sigma,
)

STRONG_RESECTION = 3
"""An image that sees this many times `min_resection_points` points of known coordinates is
resected; one that sees fewer is rather oriented relatively to an oriented neighbour."""
POLISH_GROWTH = 1.5
"""During the growth, a refinement round follows when the number of oriented images has grown
by this factor since the last one (and by 3 images at least): a few rounds in all, so that
their cost, a resection of every image and an intersection of every point, stays a few
times that of the last round."""


def triangulate(block, points) -> int:
    """Intersect `points` that are not known from the oriented images; how many."""
    done = 0
    for p in points:
        if block.known[p]:
            continue
        rows = block.obs_of_point[p]
        rows = rows[block.oriented[block.image[rows]]]
        if len(rows) < 2:
            continue
        if intersect_point(block, p, rows):
            done += 1
    return done


def intersect_point(block, p, rows) -> bool:
    threshold = block.threshold(rows)
    if threshold is None:
        threshold = np.inf
    images = block.image[rows]
    result = intersect(block.q[rows], block.eops[images], block.matrices[images], threshold,
                       block.min_angle)
    if result.point is None:
        block.point_reason[p] = result.reason
        if np.isfinite(result.angle) and result.angle == 0.0:  # the rays do not meet
            miss = np.where(np.isfinite(result.errors), result.errors * block.scale[rows],
                            np.inf)
            worst = int(np.argmax(miss))
            block.point_reason[p] = (
                f"its {len(rows)} rays do not meet: the ray of image {images[worst]} "
                f"misses by {miss[worst]:.3g} {block.units[images[worst]]}")
        return False
    block.X[p] = result.point
    block.known[p] = True
    block.point_method[p] = "intersection"
    block.point_reason.pop(p, None)
    block.use[rows] = result.inliers
    return True


def reintersect(block, p):
    """Intersect known point `p` again from all its oriented rays; forget it if that
    fails."""
    rows = block.obs_of_point[p]
    if not intersect_point(block, p, rows[block.oriented[block.image[rows]]]):
        block.X[p] = np.nan
        block.known[p] = False
        block.point_method[p] = None


def grow(block):
    """Orient one image after the other (`step`) and intersect its new points until none
    is left; refine on the POLISH_GROWTH schedule, and once more when the growth stops
    (the refinement may let more points in)."""
    polished = int(np.sum(block.oriented))
    while True:
        if not step(block):
            if np.sum(block.oriented) > polished:
                polish(block, 1)
                polished = int(np.sum(block.oriented))
                continue
            break
        oriented = int(np.sum(block.oriented))
        if oriented >= max(POLISH_GROWTH * polished, polished + 3):
            polish(block, 1)
            polished = oriented


def step(block) -> bool:
    """Try to orient one more image; False when there is none to try.

    An image that sees STRONG_RESECTION times `min_resection_points` points of known
    coordinates is resected. Otherwise the image with most points in common with an
    oriented image (`min_pair_points` at least) is oriented relatively to it (`connect`):
    many common points fix its rotation and base direction, and the few points of known
    coordinates only the base's length. Failing that, an image with
    `min_resection_points` known points is resected.
    """
    unoriented = np.flatnonzero(~block.oriented)
    if len(unoriented) == 0:
        return False
    known = {int(i): int(np.sum(block.known[block.point[block.obs_of_image[i]]]))
             for i in unoriented}
    fresh = [i for i in known if known[i] > block.tried.get(i, -1)]
    strong = [i for i in fresh
              if known[i] >= STRONG_RESECTION * block.min_resection_points]
    if strong:
        resect_image(block, max(strong, key=known.get), known)
        return True
    oriented = np.flatnonzero(block.oriented)
    common = block.shared[unoriented][:, oriented].toarray()
    n_oriented = len(oriented)
    candidates = sorted(
        ((int(common[k].max()), int(i)) for k, i in enumerate(unoriented)
         if common[k].max() >= block.min_pair_points
         and block.connect_tried.get(int(i), -1) < n_oriented), reverse=True)
    for _, i in candidates:
        if connect(block, i):
            return True
        block.connect_tried[i] = n_oriented
    weak = [i for i in fresh if known[i] >= block.min_resection_points]
    if weak:
        resect_image(block, max(weak, key=known.get), known)
        return True
    return False


def resect_image(block, i, known):
    """Robust resection of image `i` on its points of known coordinates."""
    count = known[i]
    rows = block.obs_of_image[i]
    rows = rows[block.known[block.point[rows]]]
    try:
        fit = resect(block.q[rows], block.X[block.point[rows]], block.rng,
                     threshold=block.threshold(rows), min_inliers=block.min_resection_points)
    except ValueError as error:
        block.tried[i] = count
        block.image_reason[i] = f"resection on {count} points failed: {error}"
        block.log.append(f"image {i}: {block.image_reason[i]}")
        return
    block.orient(i, fit.eop, "resection")
    block.use[rows] = fit.inliers
    rms = np.sqrt(np.mean(fit.errors[fit.inliers] ** 2))
    new = triangulate(block, block.point[block.obs_of_image[i]])
    block.log.append(f"image {i}: resection on {count} points ({int(np.sum(fit.inliers))}"
                     f" inliers, RMS {block.in_units(rows, rms)}); {new} new points "
                     "intersected")


def connect(block, i) -> bool:
    """Orient image `i` relatively to an oriented neighbour j (`orient_pair`, in j's camera
    frame with base 1): M_i = R M_j, X0_i = X0_j + s M_jᵀ b, the base length s the median
    of |X - X0_j| / |X_model| over the common inlier points of known coordinates (2 at
    least, agreeing to 20 %). Accepted when half of i's points of known coordinates fit."""
    oriented = np.flatnonzero(block.oriented)
    common = block.shared[i][:, oriented].toarray()[0]
    for k in np.argsort(-common)[:2]:
        j = int(oriented[k])
        if common[k] < block.min_pair_points:
            break
        rj, ri = block.common(j, i)
        known = block.known[block.point[rj]]
        if np.sum(known) < 2:
            continue
        sigma = None if block.sigma_hat is None and block.sigma_given is None else float(
            np.median(block.sigma_normalised(np.r_[rj, ri])))
        try:
            pair = orient_pair(block.q[rj], block.q[ri], block.rng, sigma=sigma)
        except (ValueError, np.linalg.LinAlgError):
            continue
        both = pair.inliers & known
        if np.sum(both) < 2 or pair.median_angle < block.min_angle:
            continue
        m_rel, base = opk_to_matrix(pair.eops[1, 3:]), pair.eops[1, :3]
        model = pair_points(block.q[rj][both], block.q[ri][both], m_rel, base)
        world = block.X[block.point[rj][both]] - block.eops[j, :3]
        scales = np.linalg.norm(world, axis=1) / np.linalg.norm(model, axis=1)
        scale = float(np.median(scales))
        if not (scale > 0 and np.median(np.abs(scales - scale)) <= 0.2 * scale):
            continue
        m_j = block.matrices[j]
        eop = np.r_[block.eops[j, :3] + scale * m_j.T @ base, matrix_to_opk(m_rel @ m_j)]
        rows = block.obs_of_image[i]
        rows = rows[block.known[block.point[rows]]]
        errors = reprojection(m_rel @ m_j, eop[:3], block.X[block.point[rows]], block.q[rows])
        threshold = block.threshold(rows)
        cut = 3.5 * max(robust_sigma(errors), SIGMA_FLOOR)
        inliers = errors <= (cut if threshold is None else np.maximum(threshold, cut))
        if np.sum(inliers) < max(2, len(rows) / 2):
            continue
        block.orient(i, eop, "relative orientation")
        block.use[rows] = inliers
        new = triangulate(block, block.point[block.obs_of_image[i]])
        block.log.append(
            f"image {i}: relative orientation to image {j} on {int(np.sum(pair.inliers))} "
            f"of {len(ri)} common points, base from {int(np.sum(both))} points of known "
            f"coordinates ({int(np.sum(inliers))} of {len(rows)} fit); {new} new points "
            "intersected")
        return True
    return False


def polish(block, rounds):
    """Resect every image (but given ones) on its used points, then intersect every point
    (but fixed control) again from all its rays, `rounds` times."""
    for _ in range(rounds):
        for i in np.flatnonzero(block.oriented):
            if block.image_method[i] == "given":
                continue
            rows = block.obs_of_image[i]
            rows = rows[block.known[block.point[rows]] & block.use[rows]]
            if len(rows) < 4:
                continue
            try:
                fit = space_resection(block.q[rows], block.X[block.point[rows]], 1.0,
                                      start=block.eops[i], max_iterations=20)
            except (ValueError, np.linalg.LinAlgError):
                continue
            if np.all(np.isfinite(fit.eop)):
                block.orient(i, fit.eop, block.image_method[i])
        for p in np.flatnonzero(block.known & ~block.fixed):
            reintersect(block, p)
        triangulate(block, np.flatnonzero(~block.known))
        block.estimate_sigma()
