"""The outcome of a block initialisation (module docstring of `_block`, steps 4 and 5): the
given values in place of the computed ones, the residuals, the blunders (`_blunders`), why the
images and points left out could not be initialised, and the log's summary.
"""

import numpy as np

from ._blunders import familywise, flag, point_allowance
from ._ideal import image_residuals
from ._result import BlockInitialisation
from ._robust import RAYLEIGH_MEDIAN


def outcome(block, frame, similarity) -> BlockInitialisation:
    """The `BlockInitialisation` of `block` in `frame` ("control" or "model"), moved onto
    the object frame by `similarity` (None: grown in it, or left in the model's)."""
    if frame != "model":
        given = np.all(np.isfinite(block.given), axis=1)
        for i in np.flatnonzero(given):
            if block.oriented[i] and block.image_method[i] != "given":
                off = np.linalg.norm(block.eops[i, :3] - block.given[i, :3])
                block.log.append(f"image {i}: its given EOPs replace the computed ones "
                                 f"(station off by {off:.3g} object units)")
            block.orient(i, block.given[i], "given")
        partial = np.isfinite(block.control)
        full = np.all(partial, axis=1)
        block.X[block.known] = np.where(partial[block.known], block.control[block.known],
                                        block.X[block.known])
        block.X[full] = block.control[full]
        for p in np.flatnonzero(full):
            block.known[p] = block.fixed[p] = True
            block.point_method[p] = "control"
            block.point_reason.pop(p, None)
    # Control that replaced the computed points after the growth (a block moved onto it) is
    # judged by its rays; control the block grew on, by its coordinates.
    by_rays = similarity is not None
    rays_X = block.control_by_rays() if by_rays else block.X
    residuals = np.full((block.n, 2), np.nan)
    judged = np.full(block.n, np.nan)
    rows = np.flatnonzero(block.valid)
    rows = rows[block.oriented[block.image[rows]] & block.known[block.point[rows]]]
    sigma = np.full(block.n_images, np.nan)
    blunders = np.zeros(block.n, dtype=bool)
    for g, (camera, group) in enumerate(block.groups):
        here = np.intersect1d(group, rows)
        if len(here) == 0:
            continue
        residuals[here] = image_residuals(camera, block.eops[block.image[here]],
                                          block.X[block.point[here]], block.xy[here])
        # Image points are judged by how their rays agree: a control point by its
        # intersection (its misfit to the control is the frame's, `to_object_frame`).
        left = block.residual_vectors(here, rays_X) * block.scale[here][:, None]
        # Residuals of points with few rays are small: judge them as if redundant.
        norms = np.linalg.norm(left, axis=1) / block.redundancy(here, by_rays=by_rays)
        estimate = float(np.median(norms) / RAYLEIGH_MEDIAN)
        images = block.camera_of_image == g
        floor = 0.0 if block.sigma_given is None else float(
            np.max(block.sigma_given[images]))
        sigma[images] = max(estimate, floor)
        judged[here] = norms / max(estimate, floor, np.finfo(float).tiny)
        allowed = block.scale[here] * point_allowance(block.q[here], block.point[here],
                                                      block.unknown_distortion)
        blunders[here] = flag(norms, max(estimate, floor), allowed,
                              block.blunder_threshold, block.point[here])
        unit = camera.image_units
        block.log.append(
            f"camera {block.camera_names[g]}: {len(here)} image points in "
            f"{int(np.sum(images))} images, RMS {np.sqrt(np.mean(norms**2)):.3g} {unit}, "
            f"robust σ {estimate:.3g} {unit}; "
            f"{int(np.sum(blunders[here]))} over "
            f"{familywise(len(here), block.blunder_threshold):.2g} σ (and what an unknown "
            "distortion may leave) flagged as blunders")
    failed_images = {}
    for i in np.flatnonzero(~block.oriented):
        reason = block.image_reason.get(i)
        if reason is None:
            rows_i = block.obs_of_image[i]
            count = int(np.sum(block.known[block.point[rows_i]]))
            reason = (f"{len(rows_i)} usable image points, {count} of them of points with "
                      f"coordinates; a resection needs {block.min_resection_points}")
        failed_images[int(i)] = reason
    failed_points = {}
    for p in np.flatnonzero(~block.known):
        rows_p = block.obs_of_point[p]
        images = len(rows_p)
        oriented = int(np.sum(block.oriented[block.image[rows_p]]))
        if images == 0:
            reason = "not observed (no usable image point)"
        elif images == 1:
            reason = f"seen in 1 image only (image {int(block.image[rows_p[0]])})"
        elif oriented < 2:
            reason = f"seen in {images} images, {oriented} of them initialised"
        else:
            reason = block.point_reason.get(p, "its rays do not meet")
        failed_points[int(p)] = reason
    block.log.append(f"initialised {int(np.sum(block.oriented))} of {block.n_images} images "
                     f"and {int(np.sum(block.known))} of {block.n_points} points; "
                     f"{int(np.sum(blunders))} blunders flagged")
    if failed_images:
        block.log.append(f"not initialised: images {sorted(failed_images)}")
    if failed_points:
        listed = sorted(failed_points)
        more = f" and {len(listed) - 20} more" if len(listed) > 20 else ""
        block.log.append(f"not initialised: points {listed[:20]}{more}")
    eops = np.where(block.oriented[:, None], block.eops, np.nan)
    points = np.where(block.known[:, None], block.X, np.nan)
    return BlockInitialisation(
        eops=eops, points=points, image_method=tuple(block.image_method),
        point_method=tuple(m if block.known[p] else None
                           for p, m in enumerate(block.point_method)),
        frame=frame, similarity=similarity, blunders=blunders, unusable=block.unusable,
        residuals=residuals, judged=judged, sigma=sigma, failed_images=failed_images,
        failed_points=failed_points, log=tuple(block.log))
