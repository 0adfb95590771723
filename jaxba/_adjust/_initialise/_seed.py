"""Where a block initialisation starts (module docstring of `_block`, step 2): in the object
frame from given EOPs and images resected on control (`seed_in_frame`), else from the
best-conditioned image pair oriented relatively (`seed_pair`).
"""

import numpy as np

from ._growth import reintersect, triangulate
from ._robust import orient_pair, resect, robust_sigma


def seed_in_frame(block) -> bool:
    """Orient images by given EOPs and control resection; True when the block can grow
    in the object frame from them."""
    given = np.flatnonzero(np.all(np.isfinite(block.given), axis=1))
    for i in given:
        block.orient(i, block.given[i], "given")
    full = np.all(np.isfinite(block.control), axis=1)
    resected, pooled = [], []
    if np.any(full):
        counts = [(int(np.sum(full[block.point[rows]])), i)
                  for i, rows in enumerate(block.obs_of_image) if not block.oriented[i]]
        for count, i in sorted(counts, key=lambda t: (-t[0], t[1])):
            if count < 4:
                break
            rows = block.obs_of_image[i][full[block.point[block.obs_of_image[i]]]]
            try:
                fit = resect(block.q[rows], block.control[block.point[rows]], block.rng,
                             threshold=block.threshold(rows), min_inliers=4)
            except ValueError as error:
                block.log.append(f"image {i}: no resection on its {count} control points "
                                 f"({error})")
                continue
            block.orient(i, fit.eop, "control resection")
            block.use[rows[~fit.inliers]] = False
            resected.append(i)
            # Residuals of a fit with 2n observations and 6 unknowns: σ sqrt(1 - 6 / 2n).
            inliers = int(np.sum(fit.inliers))
            pooled.append(fit.errors[fit.inliers]
                          * np.sqrt(2 * inliers / max(2 * inliers - 6, 1)))
            if block.sigma_given is None and sum(map(len, pooled)) >= 12:
                block.sigma_hat = robust_sigma(np.concatenate(pooled))
            rms = np.sqrt(np.mean(fit.errors[fit.inliers] ** 2))
            block.log.append(f"image {i}: resection on {count} control points "
                             f"({int(np.sum(fit.inliers))} inliers, RMS "
                             f"{block.in_units(rows, rms)})")
    if np.sum(block.oriented) < 2:
        return False
    block.X[full] = block.control[full]
    block.known[full] = block.fixed[full] = True
    for p in np.flatnonzero(full):
        block.point_method[p] = "control"
    intersected = triangulate(block, np.flatnonzero(~block.known))
    if block.sigma_hat is None and block.sigma_given is None:
        # The first intersections took every ray: judge them again with σ̂.
        block.estimate_sigma()
        if block.sigma_hat is not None:
            for p in np.flatnonzero(block.known & ~block.fixed):
                reintersect(block, p)
    growable = any(
        np.sum(block.known[block.point[rows]]) >= block.min_resection_points
        for i, rows in enumerate(block.obs_of_image) if not block.oriented[i])
    if intersected < 6 and not growable and not np.all(block.oriented):
        block.log.append(f"{len(given)} images with given EOPs and {len(resected)} resected "
                         f"on control intersect only {intersected} points: starting from a "
                         "relative orientation instead")
        return False
    block.log.append(f"frame: the object frame of the control and given EOPs "
                     f"({len(given)} images given, {len(resected)} resected on control); "
                     f"{intersected} points intersected")
    return True


def seed_pair(block) -> bool:
    """Orient the best-conditioned pair relatively; True on success."""
    counts = block.shared.tocoo()
    pairs = [(int(c), int(i), int(j)) for i, j, c in zip(counts.row, counts.col, counts.data)
             if i < j and c >= block.min_pair_points]
    if not pairs:
        block.log.append(f"no image pair has {block.min_pair_points} or more common points: "
                         "no relative orientation")
        return False
    pairs.sort(key=lambda t: (-t[0], t[1], t[2]))
    sigma = None
    best = None
    for count, i, j in pairs[:block.pair_candidates]:
        ri, rj = block.common(i, j)
        if block.sigma_given is not None:
            sigma = float(np.median(block.sigma_normalised(np.r_[ri, rj])))
        try:
            pair = orient_pair(block.q[ri], block.q[rj], block.rng, sigma=sigma)
        except (ValueError, np.linalg.LinAlgError) as error:
            block.log.append(f"pair {i}-{j}: no relative orientation ({error})")
            continue
        inliers, angle, score = int(np.sum(pair.inliers)), pair.median_angle, pair.score
        block.log.append(f"pair {i}-{j}: {inliers} of {count} common points fit its relative "
                         f"orientation, median intersection angle {np.degrees(angle):.1f}°, "
                         f"σ {block.in_units(ri, pair.sigma)}")
        if angle < block.min_angle:
            block.log.append(f"pair {i}-{j}: its rays meet at less than "
                             f"{np.degrees(block.min_angle):.1f}° (too short a base): not used")
            continue
        if best is None or score > best[0]:
            best = (score, i, j, pair, ri, rj)
    if best is None:
        return False
    _, i, j, pair, ri, rj = best
    block.pair = (i, j)
    block.orient(i, pair.eops[0], "relative orientation")
    block.orient(j, pair.eops[1], "relative orientation")
    if block.sigma_given is None:
        block.sigma_hat = pair.sigma
    intersected = triangulate(block, np.unique(block.point[ri[pair.inliers]]))
    block.log.append(f"frame: the model of pair {i}-{j} (image {i} at the origin, M = I, "
                     f"base 1); {intersected} points intersected")
    return True
