"""Block initialisation: approximations of every EOP and object point of a block
from its image points, approximate cameras and whatever control, distances or EOPs exist.
One module per step, each working on the `Block` state (`_state`).

1. Rays. Every measured point becomes its normalised ideal coordinates (a, b), the ray
   (a, b, -1) of its camera (`ideal_coordinates`), so that the approximation tools of
   `jaxba._approximations` work with c = 1 for every camera model (`_state`).
2. Seed (`_seed`). Images with given EOPs, and images that see enough full control points (robust
   `space_resection`), are oriented in the object frame; when that gives two or more images
   whose rays intersect, the block grows in that frame. Otherwise the best-conditioned image
   pair (among the pairs with most common points, the one with most inliers, weighted by its
   median intersection angle up to PAIR_ANGLE) is oriented relatively (`orient_pair`:
   essential-matrix, homography and near-vertical hypotheses, least median of squares, then
   `relative_orientation`), its first image at the origin with M = I, the base 1.
3. Growth (`_growth`). Points seen by two or more oriented images are intersected (robust
   `forward_intersection`, rays meeting at `min_angle` or more); then the next image is
   oriented (`step`): resected (RANSAC over `space_resection`) when it sees many points of
   known coordinates, else oriented relatively to its best-connected oriented neighbour with
   only the base length from the known points (`connect`), else resected on its
   `min_resection_points` or more; and so on. Whenever the oriented images have grown by
   half (POLISH_GROWTH), and `polish_rounds` times at the end, all images are resected again
   and all points intersected again: a cheap block refinement that spreads the errors of the
   sequence (the growth goes on if it let more points in).
4. Frame (`_placement`). A model-frame block is brought into the object frame by
   `absolute_orientation` onto the control points and given camera stations it determined (3
   or more full ones), else rotated and shifted onto one image's given EOPs, else fitted to
   partial control (`partial_similarity`), and scaled from the distances where needed. Given
   EOPs and control coordinates then replace the computed ones.
5. Outcome (`_outcome`). Every image point of an initialised image and point is projected
   through its camera (`image_residuals`, the camera's units); those whose residual, scaled
   for the point's number of rays, exceeds what an unknown distortion may leave plus
   `blunder_threshold` robust σ (per camera, raised to the familywise bound of its number of
   image points), and that stand out from their point's other rays, are flagged
   (`_blunders`); the images and points not initialised are listed with the reason.

The numbers come with a log (strings, one step a line) that says what was done.
"""

from collections.abc import Sequence

import numpy as np

from ..._float64 import require_float64
from ..._models._cameras import AbstractCamera
from ._blunders import UNKNOWN_DISTORTION
from ._growth import grow, polish
from ._outcome import outcome
from ._placement import normalise_model, to_object_frame
from ._result import BlockInitialisation
from ._seed import seed_in_frame, seed_pair
from ._state import INLIER_K, Block


def initialise_block(
    observations,
    cameras: Sequence[AbstractCamera],
    *,
    eops=None,
    control=None,
    distances=None,
    n_points: int | None = None,
    sigma=None,
    seed: int = 0,
    min_angle: float = np.radians(2.0),
    blunder_threshold: float = 4.0,
    min_resection_points: int = 6,
    min_pair_points: int = 12,
    pair_candidates: int = 8,
    polish_rounds: int = 3,
    camera_names: Sequence[str] | None = None,
    unknown_distortion: float = UNKNOWN_DISTORTION,
    inlier_k: float = INLIER_K,
) -> BlockInitialisation:
    """Approximations of every EOP and object point of a block (module docstring).

    Arguments:
    - `observations` (n, 4): image index, point index, x, y per image point, x, y in the
      image's camera's image units (mm in jaxba's image frame for the photogrammetric models,
      pixels for the pixel models);
    - `cameras`: per image, its jaxba camera model instance (`jaxba.CAMERA_MODELS`) with its
      approximate parameters; images that share a camera may share the instance;
    - `eops` (n_images, 6): known EOPs (X0, Y0, Z0, omega, phi, kappa in radians, e.g. from
      GNSS/INS or a previous run), NaN rows where unknown (a row with only X0, Y0, Z0 counts as
      a camera station for the absolute orientation);
    - `control` (n_points, 3): control coordinates, NaN for each unknown coordinate (a point
      may have only Z);
    - `distances` (m, 3): point a, point b, length (object units): the scale when there is no
      control;
    - `n_points`: number of points (default: `len(control)`, else the largest index + 1);
    - `sigma`: a priori σ of an image coordinate (image units), one or per image; None: it is
      estimated robustly as the block grows;
    - `seed`: of the random samples (the result is deterministic for a seed);
    - `min_angle`: the smallest intersection angle of a point's rays (radians);
    - `blunder_threshold`: image points off by more than this many robust σ (and the
      familywise bound of their camera's number of image points), beyond what an unknown
      distortion may leave, are blunders (`_blunders`);
    - `min_resection_points`: points of known coordinates an image needs for its resection;
    - `min_pair_points`, `pair_candidates`: common points a relative orientation needs (8 at
      least), and how many of the pairs with most of them are tried;
    - `polish_rounds`: rounds of resection and intersection of the whole block at the end;
    - `camera_names`: per image, the name of its camera for the log (default "of image k",
      k its camera's first image);
    - `unknown_distortion`: the misfit a camera's unknown distortion may leave at the edge of
      its image points, as a fraction of their radius (`distortion_allowance`), allowed
      before an image point is a blunder (0 for calibrated cameras);
    - `inlier_k`: the inlier cut of a ray's 2D reprojection error in robust σ (resections,
      intersections; default 3.5, chi² with 2 dof at 99.8 %).

    Returns a `BlockInitialisation`: EOPs, points, how each was found, flagged blunders and the
    log. Images and points that cannot be initialised are NaN and listed with the reason.
    Needs jax in float64. Raises ValueError for malformed input only.
    """
    require_float64("initialise_block")
    block = Block(observations, cameras, eops, control, distances, n_points, sigma, seed,
                  min_angle, blunder_threshold, min_resection_points, min_pair_points,
                  pair_candidates, polish_rounds, camera_names, unknown_distortion, inlier_k)
    block.log.insert(0, f"{block.n_images} images, {block.n_points} points, {block.n} image "
                        f"points ({int(np.sum(block.valid))} usable)")
    if seed_in_frame(block):
        frame, similarity = "control", None
    else:
        block._reset()
        if not seed_pair(block):
            for i in range(block.n_images):
                block.image_reason[i] = ("no control or given EOPs to start from, and no image "
                                         "pair could be oriented relatively (see the log)")
            return outcome(block, "model", None)
        frame = None
    grow(block)
    if block.polish_rounds:
        for _ in range(block.polish_rounds):
            polish(block, 1)
            grow(block)  # when the refinement let more points in
        rows = block.used_rows()
        rms = np.sqrt(np.mean(block.errors(rows) ** 2)) if len(rows) else np.nan
        block.log.append(f"refinement: {block.polish_rounds} rounds of resection and "
                         f"intersection of the whole block; RMS {block.in_units(rows, rms)}")
    if frame is None:
        normalise_model(block, *block.pair)
        frame, similarity = to_object_frame(block)
    return outcome(block, frame, similarity)
