"""Block initialisation: approximations of every EOP and object point of a block
from its image points, approximate cameras and whatever control, distances or EOPs exist.

1. Rays. Every measured point becomes its normalised ideal coordinates (a, b), the ray
   (a, b, -1) of its camera (`ideal_coordinates`), so that the approximation tools of
   `jaxba._approximations` work with c = 1 for every camera model.
2. Seed. Images with given EOPs, and images that see enough full control points (robust
   `space_resection`), are oriented in the object frame; when that gives two or more images
   whose rays intersect, the block grows in that frame. Otherwise the best-conditioned image
   pair (among the pairs with most common points, the one with most inliers, weighted by its
   median intersection angle up to PAIR_ANGLE) is oriented relatively (`orient_pair`:
   essential-matrix, homography and near-vertical hypotheses, least median of squares, then
   `relative_orientation`), its first image at the origin with M = I, the base 1.
3. Growth. Points seen by two or more oriented images are intersected (robust
   `forward_intersection`, rays meeting at `min_angle` or more); then the next image is
   oriented (`step`): resected (RANSAC over `space_resection`) when it sees many points of
   known coordinates, else oriented relatively to its best-connected oriented neighbour with
   only the base length from the known points (`connect`), else resected on its
   `min_resection_points` or more; and so on. Whenever the oriented images have grown by
   half (POLISH_GROWTH), and `polish_rounds` times at the end, all images are resected again
   and all points intersected again: a cheap block refinement that spreads the errors of the
   sequence (the growth goes on if it let more points in).
4. Frame. A model-frame block is brought into the object frame by `absolute_orientation`
   onto the control points and given camera stations it determined (3 or more full ones),
   else rotated and shifted onto one image's given EOPs, else fitted to partial control
   (`partial_similarity`), and scaled from the distances where needed. Given EOPs and
   control coordinates then replace the computed ones.
5. Blunders. Every image point of an initialised image and point is projected through its
   camera (`image_residuals`, the camera's units); the field an approximate camera leaves is
   taken out per image, and those whose residual, scaled for the point's number of rays,
   exceeds `blunder_threshold` robust σ (per camera, and the familywise bound of its number
   of image points) are flagged (`_blunders`).

The numbers come with a log (strings, one step a line) that says what was done.
"""

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..._approximations import Similarity, absolute_orientation, space_resection
from ..._float64 import require_float64
from ..._models._cameras import AbstractCamera
from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from ._blunders import UNKNOWN_DISTORTION, distortion_allowance, familywise, flag
from ._frame import partial_similarity
from ._ideal import ideal_coordinates, image_residuals
from ._robust import (
    RAYLEIGH_MEDIAN,
    SIGMA_FLOOR,
    intersect,
    orient_pair,
    pair_points,
    project,
    reprojection,
    resect,
    robust_sigma,
)

INLIER_K = 3.5
"""Inlier cut of a 2D reprojection error during the growth, in σ (chi² with 2 dof, 99.8 %)."""
STRONG_RESECTION = 3
"""An image that sees this many times `min_resection_points` points of known coordinates is
resected; one that sees fewer is rather oriented relatively to an oriented neighbour."""
POLISH_GROWTH = 1.5
"""During the growth, a refinement round follows when the number of oriented images has grown
by this factor since the last one (and by 3 images at least): a few rounds in all, so that
their cost, a resection of every image and an intersection of every point, stays a few
times that of the last round."""

IMAGE_METHODS = ("given", "control resection", "relative orientation", "resection")
POINT_METHODS = ("control", "intersection")


@dataclasses.dataclass(frozen=True)
class BlockInitialisation:
    """The result of `initialise_block`.

    - `eops` (n_images, 6): X0, Y0, Z0 (object units), omega, phi, kappa (radians), jaxba's
      images rows; NaN rows for images that could not be initialised;
    - `points` (n_points, 3): X, Y, Z (object units); NaN rows for points not determined;
    - `image_method`, `point_method`: per image / point how it was found (IMAGE_METHODS:
      "given", "control resection", "relative orientation", "resection"; POINT_METHODS:
      "control", "intersection"), None where not initialised;
    - `frame`: "control" (the control points' and given EOPs' object frame), or "model"
      (no control or EOPs to define it: the first image of the initial pair at the origin
      with M = I, the base to the second image of length 1, or scaled by the distances);
    - `similarity`: the `Similarity` (model -> object frame) applied, or None;
    - `blunders` (n_observations,): image points flagged as blunders (reprojection error over
      `blunder_threshold` robust σ); `unusable` (n_observations,): image points that were not
      used at all (duplicate, non-finite, image index unknown, no ray: see the log);
    - `residuals` (n_observations, 2): v = measured - computed in the camera's image units
      at the initialised EOPs and points (NaN where one of them is missing);
    - `judged` (n_observations,): what the blunders are judged by, in σ: |v| less the field
      an approximate camera leaves, scaled for the point's rays (`_blunders`); NaN where v is;
    - `sigma` (n_images,): the robust σ of an image coordinate of each image's camera
      (image units) that the blunders are judged by;
    - `failed_images`, `failed_points`: index -> why it could not be initialised;
    - `log`: what was done, one step a line.
    """

    eops: np.ndarray
    points: np.ndarray
    image_method: tuple[str | None, ...]
    point_method: tuple[str | None, ...]
    frame: str
    similarity: Similarity | None
    blunders: np.ndarray
    unusable: np.ndarray
    residuals: np.ndarray
    judged: np.ndarray
    sigma: np.ndarray
    failed_images: dict[int, str]
    failed_points: dict[int, str]
    log: tuple[str, ...]

    @property
    def initialised_images(self) -> np.ndarray:
        """(n_images,) bool: images with EOPs."""
        return np.all(np.isfinite(self.eops), axis=1)

    @property
    def initialised_points(self) -> np.ndarray:
        """(n_points,) bool: points with coordinates."""
        return np.all(np.isfinite(self.points), axis=1)


def _rows(values, shape_tail, count, name):
    if values is None:
        return np.full((count, *shape_tail), np.nan)
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (count, *shape_tail):
        raise ValueError(f"initialise_block: {name} must have shape {(count, *shape_tail)}, "
                         f"got {array.shape}")
    if np.any(np.isinf(array)):
        raise ValueError(f"initialise_block: {name} contains infinite values (NaN marks "
                         "an unknown)")
    return array


class _Block:
    """The state of one initialisation: oriented images, known points, used image points."""

    def __init__(self, observations, cameras, eops, control, distances, n_points, sigma,
                 seed, min_angle, blunder_threshold, min_resection_points, min_pair_points,
                 pair_candidates, polish_rounds, camera_names, unknown_distortion):
        self.log: list[str] = []
        cameras = list(cameras)
        if not all(isinstance(camera, AbstractCamera) for camera in cameras):
            raise ValueError("initialise_block: cameras must be jaxba camera models "
                             "(jaxba.CAMERA_MODELS), one per image")
        self.cameras = cameras
        self.n_images = len(cameras)
        observations = np.asarray(observations, dtype=np.float64)
        if observations.ndim != 2 or observations.shape[1] != 4:
            raise ValueError("initialise_block: observations must have shape (n, 4): image "
                             f"index, point index, x, y; got {observations.shape}")
        index = observations[:, :2]
        if not np.all(np.isfinite(index) & (index == np.round(index)) & (index >= 0)):
            raise ValueError("initialise_block: image and point indices must be integers >= 0")
        self.image = index[:, 0].astype(int)
        self.point = index[:, 1].astype(int)
        self.xy = observations[:, 2:].copy()
        self.n = len(observations)
        if n_points is None:
            n_points = len(control) if control is not None else (
                int(self.point.max()) + 1 if self.n else 0)
        self.n_points = int(n_points)
        if self.n and (self.point.max() >= self.n_points):
            raise ValueError(f"initialise_block: point index {int(self.point.max())} >= "
                             f"n_points {self.n_points}")
        self.given = _rows(eops, (6,), self.n_images, "eops")
        self.control = _rows(control, (3,), self.n_points, "control")
        self.distances = np.zeros((0, 3)) if distances is None else np.asarray(
            distances, dtype=np.float64).reshape(-1, 3)
        ends = self.distances[:, :2]
        if not np.all((ends == np.round(ends)) & (ends >= 0) & (ends < self.n_points)):
            raise ValueError("initialise_block: distances must name points by index "
                             f"(0 .. {self.n_points - 1})")
        if camera_names is not None and len(camera_names) != self.n_images:
            raise ValueError(f"initialise_block: camera_names must name the camera of each of "
                             f"the {self.n_images} images, got {len(camera_names)}")
        self.rng = np.random.default_rng(seed)
        self.min_angle = float(min_angle)
        self.blunder_threshold = float(blunder_threshold)
        self.unknown_distortion = float(unknown_distortion)
        self.min_resection_points = int(min_resection_points)
        self.min_pair_points = max(9, int(min_pair_points))
        self.pair_candidates = int(pair_candidates)
        self.polish_rounds = int(polish_rounds)
        self._rays(sigma, camera_names)
        self._reset()

    # -- input ---------------------------------------------------------------------------

    def _rays(self, sigma, camera_names):
        self.unusable = np.zeros(self.n, dtype=bool)
        bad_image = self.image >= self.n_images
        if np.any(bad_image):
            self.log.append(f"{int(np.sum(bad_image))} image points name an image index >= "
                            f"{self.n_images} (the number of cameras given): not used")
        self.unusable |= bad_image
        finite = np.all(np.isfinite(self.xy), axis=1)
        if not np.all(finite):
            self.log.append(f"{int(np.sum(~finite))} image points with non-finite "
                            "coordinates: not used")
        self.unusable |= ~finite
        keys = self.image * max(self.n_points, 1) + self.point
        _, first = np.unique(keys, return_index=True)
        duplicate = np.ones(self.n, dtype=bool)
        duplicate[first] = False
        if np.any(duplicate):
            self.log.append(f"{int(np.sum(duplicate))} image points repeat an (image, point) "
                            "pair: only the first is used")
        self.unusable |= duplicate
        self.q = np.full((self.n, 2), np.nan)
        self.scale = np.full(self.n, np.nan)
        self.groups: list[tuple[AbstractCamera, np.ndarray]] = []
        self.camera_names: list[str] = []
        by_camera: dict[int, list[int]] = {}
        for i, camera in enumerate(self.cameras):
            by_camera.setdefault(id(camera), []).append(i)
        self.camera_of_image = np.zeros(self.n_images, dtype=int)
        for g, images in enumerate(by_camera.values()):
            self.camera_of_image[images] = g
            camera = self.cameras[images[0]]
            rows = np.flatnonzero(np.isin(self.image, images) & ~self.unusable)
            self.groups.append((camera, rows))
            self.camera_names.append(f"of image {images[0]}" if camera_names is None
                                     else str(camera_names[images[0]]))
            if len(rows) == 0:
                continue
            ideal = ideal_coordinates(camera, self.xy[rows])
            self.q[rows] = ideal.normalised
            self.scale[rows] = ideal.scale
            failed = ~ideal.converged
            if np.any(failed):
                self.log.append(f"camera {self.camera_names[g]}: {int(np.sum(failed))} image "
                                "points have no ray through the camera model (outside its "
                                "valid range?): not used")
                self.unusable[rows[failed]] = True
        self.valid = ~self.unusable
        self.units = [self.cameras[i].image_units for i in range(self.n_images)]
        self.sigma_given = None
        if sigma is not None:
            values = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (self.n_images,))
            if not np.all(values > 0):
                raise ValueError("initialise_block: sigma must be > 0")
            self.sigma_given = values
        self.obs_of_image = [np.flatnonzero((self.image == i) & self.valid)
                             for i in range(self.n_images)]
        order = np.argsort(self.point[self.valid], kind="stable")
        rows = np.flatnonzero(self.valid)[order]
        bounds = np.searchsorted(self.point[rows], np.arange(self.n_points + 1))
        self.obs_of_point = [rows[bounds[p]:bounds[p + 1]] for p in range(self.n_points)]
        import scipy.sparse  # here: its import (0.1 s) is not every run's

        used = np.flatnonzero(self.valid)
        incidence = scipy.sparse.csr_matrix(
            (np.ones(len(used)), (self.image[used], self.point[used])),
            shape=(self.n_images, self.n_points))
        self.shared = (incidence @ incidence.T).tocsr()  # common points of image pairs

    def _reset(self):
        self.eops = np.full((self.n_images, 6), np.nan)
        self.matrices = np.full((self.n_images, 3, 3), np.nan)
        self.oriented = np.zeros(self.n_images, dtype=bool)
        self.image_method: list[str | None] = [None] * self.n_images
        self.image_reason: dict[int, str] = {}
        self.X = np.full((self.n_points, 3), np.nan)
        self.known = np.zeros(self.n_points, dtype=bool)
        self.fixed = np.zeros(self.n_points, dtype=bool)
        self.point_method: list[str | None] = [None] * self.n_points
        self.point_reason: dict[int, str] = {}
        self.use = self.valid.copy()
        self.sigma_hat: float | None = None
        self.tried: dict[int, int] = {}  # image -> known points when its resection failed
        self.connect_tried: dict[int, int] = {}  # image -> oriented images when `connect` failed

    # -- helpers -------------------------------------------------------------------------

    def sigma_normalised(self, rows) -> np.ndarray | None:
        """σ (normalised units) of image points `rows`: given, or the running estimate."""
        if self.sigma_given is not None:
            return self.sigma_given[self.image[rows]] / self.scale[rows]
        if self.sigma_hat is None:
            return None
        return np.full(len(rows), max(self.sigma_hat, SIGMA_FLOOR))

    def threshold(self, rows):
        sigma = self.sigma_normalised(rows)
        return None if sigma is None else INLIER_K * sigma

    def in_units(self, rows, value) -> str:
        """A normalised length `value` at image points `rows` in their image units."""
        if len(rows) == 0 or not np.isfinite(value):
            return f"{value:.3g}"
        unit = self.units[self.image[rows[0]]]
        return f"{value * float(np.median(self.scale[rows])):.3g} {unit}"

    def orient(self, i, eop, method):
        self.eops[i] = eop
        self.matrices[i] = opk_to_matrix(eop[3:])
        self.oriented[i] = True
        self.image_method[i] = method
        self.image_reason.pop(i, None)

    def errors(self, rows) -> np.ndarray:
        """Reprojection errors |v| (normalised) of image points `rows` (oriented, known)."""
        out = np.empty(len(rows))
        for i in np.unique(self.image[rows]):
            here = self.image[rows] == i
            r = rows[here]
            computed, w = project(self.matrices[i], self.eops[i, :3], self.X[self.point[r]])
            e = np.linalg.norm(self.q[r] - computed, axis=1)
            out[here] = np.where(w < 0, e, np.inf)
        return out

    def control_by_rays(self) -> np.ndarray:
        """The points (n_points, 3): control points seen on 2 or more oriented rays
        intersected from them (robustly), the others as they are."""
        X = self.X.copy()
        for p in np.flatnonzero(self.fixed):
            rows = self.obs_of_point[p]
            rows = rows[self.oriented[self.image[rows]]]
            if len(rows) >= 2:
                threshold = self.threshold(rows)
                images = self.image[rows]
                found = intersect(self.q[rows], self.eops[images], self.matrices[images],
                                  np.inf if threshold is None else threshold, 0.0)
                if found.point is not None:
                    X[p] = found.point
        return X

    def residual_vectors(self, rows, points=None) -> np.ndarray:
        """v = q - projected (n, 2) (normalised) of image points `rows` (oriented, known) at
        `points` (n_points, 3; default the block's); NaN behind an image."""
        points = self.X if points is None else points
        out = np.empty((len(rows), 2))
        for i in np.unique(self.image[rows]):
            here = self.image[rows] == i
            r = rows[here]
            computed, w = project(self.matrices[i], self.eops[i, :3], points[self.point[r]])
            out[here] = np.where((w < 0)[:, None], self.q[r] - computed, np.nan)
        return out

    def redundancy(self, rows, by_rays=False) -> np.ndarray:
        """sqrt((2k - 3) / 2k) (n,) of image points `rows` of points with k used rays (1 for
        fixed control points, unless `by_rays`: `control_by_rays`): the share of an image
        coordinate's σ its residual keeps when the point is intersected from its k rays (the
        images taken as errorless)."""
        rays = np.zeros(self.n_points)
        used = np.flatnonzero(self.use & self.valid)
        used = used[self.oriented[self.image[used]]]
        np.add.at(rays, self.point[used], 1)
        k = np.maximum(rays[self.point[rows]], 2)
        fixed = self.fixed[self.point[rows]] & ~(by_rays & (rays[self.point[rows]] >= 2))
        return np.where(fixed, 1.0, np.sqrt((2 * k - 3) / (2 * k)))

    # -- seeds ---------------------------------------------------------------------------

    def seed_in_frame(self) -> bool:
        """Orient images by given EOPs and control resection; True when the block can grow
        in the object frame from them."""
        given = np.flatnonzero(np.all(np.isfinite(self.given), axis=1))
        for i in given:
            self.orient(i, self.given[i], "given")
        full = np.all(np.isfinite(self.control), axis=1)
        resected, pooled = [], []
        if np.any(full):
            counts = [(int(np.sum(full[self.point[rows]])), i)
                      for i, rows in enumerate(self.obs_of_image) if not self.oriented[i]]
            for count, i in sorted(counts, key=lambda t: (-t[0], t[1])):
                if count < 4:
                    break
                rows = self.obs_of_image[i][full[self.point[self.obs_of_image[i]]]]
                try:
                    fit = resect(self.q[rows], self.control[self.point[rows]], self.rng,
                                 threshold=self.threshold(rows), min_inliers=4)
                except ValueError as error:
                    self.log.append(f"image {i}: no resection on its {count} control points "
                                    f"({error})")
                    continue
                self.orient(i, fit.eop, "control resection")
                self.use[rows[~fit.inliers]] = False
                resected.append(i)
                # Residuals of a fit with 2n observations and 6 unknowns: σ sqrt(1 - 6 / 2n).
                inliers = int(np.sum(fit.inliers))
                pooled.append(fit.errors[fit.inliers]
                              * np.sqrt(2 * inliers / max(2 * inliers - 6, 1)))
                if self.sigma_given is None and sum(map(len, pooled)) >= 12:
                    self.sigma_hat = robust_sigma(np.concatenate(pooled))
                rms = np.sqrt(np.mean(fit.errors[fit.inliers] ** 2))
                self.log.append(f"image {i}: resection on {count} control points "
                                f"({int(np.sum(fit.inliers))} inliers, RMS "
                                f"{self.in_units(rows, rms)})")
        if np.sum(self.oriented) < 2:
            return False
        self.X[full] = self.control[full]
        self.known[full] = self.fixed[full] = True
        for p in np.flatnonzero(full):
            self.point_method[p] = "control"
        intersected = self.triangulate(np.flatnonzero(~self.known))
        if self.sigma_hat is None and self.sigma_given is None:
            # The first intersections took every ray: judge them again with σ̂.
            self.estimate_sigma()
            if self.sigma_hat is not None:
                for p in np.flatnonzero(self.known & ~self.fixed):
                    self.reintersect(p)
        growable = any(
            np.sum(self.known[self.point[rows]]) >= self.min_resection_points
            for i, rows in enumerate(self.obs_of_image) if not self.oriented[i])
        if intersected < 6 and not growable and not np.all(self.oriented):
            self.log.append(f"{len(given)} images with given EOPs and {len(resected)} resected "
                            f"on control intersect only {intersected} points: starting from a "
                            "relative orientation instead")
            return False
        self.log.append(f"frame: the object frame of the control and given EOPs "
                        f"({len(given)} images given, {len(resected)} resected on control); "
                        f"{intersected} points intersected")
        return True

    def common(self, i, j):
        """Image point rows (k,), (k,) of the points that images i and j both see."""
        a, b = self.obs_of_image[i], self.obs_of_image[j]
        shared, ia, jb = np.intersect1d(self.point[a], self.point[b], return_indices=True)
        return a[ia], b[jb]

    def seed_pair(self) -> bool:
        """Orient the best-conditioned pair relatively; True on success."""
        counts = self.shared.tocoo()
        pairs = [(int(c), int(i), int(j)) for i, j, c in zip(counts.row, counts.col, counts.data)
                 if i < j and c >= self.min_pair_points]
        if not pairs:
            self.log.append(f"no image pair has {self.min_pair_points} or more common points: "
                            "no relative orientation")
            return False
        pairs.sort(key=lambda t: (-t[0], t[1], t[2]))
        sigma = None
        best = None
        for count, i, j in pairs[:self.pair_candidates]:
            ri, rj = self.common(i, j)
            if self.sigma_given is not None:
                sigma = float(np.median(self.sigma_normalised(np.r_[ri, rj])))
            try:
                pair = orient_pair(self.q[ri], self.q[rj], self.rng, sigma=sigma)
            except (ValueError, np.linalg.LinAlgError) as error:
                self.log.append(f"pair {i}-{j}: no relative orientation ({error})")
                continue
            inliers, angle, score = int(np.sum(pair.inliers)), pair.median_angle, pair.score
            self.log.append(f"pair {i}-{j}: {inliers} of {count} common points fit its relative "
                            f"orientation, median intersection angle {np.degrees(angle):.1f}°, "
                            f"σ {self.in_units(ri, pair.sigma)}")
            if angle < self.min_angle:
                self.log.append(f"pair {i}-{j}: its rays meet at less than "
                                f"{np.degrees(self.min_angle):.1f}° (too short a base): not used")
                continue
            if best is None or score > best[0]:
                best = (score, i, j, pair, ri, rj)
        if best is None:
            return False
        _, i, j, pair, ri, rj = best
        self.pair = (i, j)
        self.orient(i, pair.eops[0], "relative orientation")
        self.orient(j, pair.eops[1], "relative orientation")
        if self.sigma_given is None:
            self.sigma_hat = pair.sigma
        intersected = self.triangulate(np.unique(self.point[ri[pair.inliers]]))
        self.log.append(f"frame: the model of pair {i}-{j} (image {i} at the origin, M = I, "
                        f"base 1); {intersected} points intersected")
        return True

    # -- growth --------------------------------------------------------------------------

    def triangulate(self, points) -> int:
        """Intersect `points` that are not known from the oriented images; how many."""
        done = 0
        for p in points:
            if self.known[p]:
                continue
            rows = self.obs_of_point[p]
            rows = rows[self.oriented[self.image[rows]]]
            if len(rows) < 2:
                continue
            if self.intersect_point(p, rows):
                done += 1
        return done

    def intersect_point(self, p, rows) -> bool:
        threshold = self.threshold(rows)
        if threshold is None:
            threshold = np.inf
        images = self.image[rows]
        result = intersect(self.q[rows], self.eops[images], self.matrices[images], threshold,
                           self.min_angle)
        if result.point is None:
            self.point_reason[p] = result.reason
            if np.isfinite(result.angle) and result.angle == 0.0:  # the rays do not meet
                miss = np.where(np.isfinite(result.errors), result.errors * self.scale[rows],
                                np.inf)
                worst = int(np.argmax(miss))
                self.point_reason[p] = (
                    f"its {len(rows)} rays do not meet: the ray of image {images[worst]} "
                    f"misses by {miss[worst]:.3g} {self.units[images[worst]]}")
            return False
        self.X[p] = result.point
        self.known[p] = True
        self.point_method[p] = "intersection"
        self.point_reason.pop(p, None)
        self.use[rows] = result.inliers
        return True

    def reintersect(self, p):
        """Intersect known point `p` again from all its oriented rays; forget it if that
        fails."""
        rows = self.obs_of_point[p]
        if not self.intersect_point(p, rows[self.oriented[self.image[rows]]]):
            self.X[p] = np.nan
            self.known[p] = False
            self.point_method[p] = None

    def grow(self):
        """Orient one image after the other (`step`) and intersect its new points until none
        is left; refine on the POLISH_GROWTH schedule, and once more when the growth stops
        (the refinement may let more points in)."""
        polished = int(np.sum(self.oriented))
        while True:
            if not self.step():
                if np.sum(self.oriented) > polished:
                    self.polish(1)
                    polished = int(np.sum(self.oriented))
                    continue
                break
            oriented = int(np.sum(self.oriented))
            if oriented >= max(POLISH_GROWTH * polished, polished + 3):
                self.polish(1)
                polished = oriented

    def step(self) -> bool:
        """Try to orient one more image; False when there is none to try.

        An image that sees STRONG_RESECTION times `min_resection_points` points of known
        coordinates is resected. Otherwise the image with most points in common with an
        oriented image (`min_pair_points` at least) is oriented relatively to it (`connect`):
        many common points fix its rotation and base direction, and the few points of known
        coordinates only the base's length. Failing that, an image with
        `min_resection_points` known points is resected.
        """
        unoriented = np.flatnonzero(~self.oriented)
        if len(unoriented) == 0:
            return False
        known = {int(i): int(np.sum(self.known[self.point[self.obs_of_image[i]]]))
                 for i in unoriented}
        fresh = [i for i in known if known[i] > self.tried.get(i, -1)]
        strong = [i for i in fresh
                  if known[i] >= STRONG_RESECTION * self.min_resection_points]
        if strong:
            self.resect_image(max(strong, key=known.get), known)
            return True
        oriented = np.flatnonzero(self.oriented)
        common = self.shared[unoriented][:, oriented].toarray()
        n_oriented = len(oriented)
        candidates = sorted(
            ((int(common[k].max()), int(i)) for k, i in enumerate(unoriented)
             if common[k].max() >= self.min_pair_points
             and self.connect_tried.get(int(i), -1) < n_oriented), reverse=True)
        for _, i in candidates:
            if self.connect(i):
                return True
            self.connect_tried[i] = n_oriented
        weak = [i for i in fresh if known[i] >= self.min_resection_points]
        if weak:
            self.resect_image(max(weak, key=known.get), known)
            return True
        return False

    def resect_image(self, i, known):
        """Robust resection of image `i` on its points of known coordinates."""
        count = known[i]
        rows = self.obs_of_image[i]
        rows = rows[self.known[self.point[rows]]]
        try:
            fit = resect(self.q[rows], self.X[self.point[rows]], self.rng,
                         threshold=self.threshold(rows), min_inliers=self.min_resection_points)
        except ValueError as error:
            self.tried[i] = count
            self.image_reason[i] = f"resection on {count} points failed: {error}"
            self.log.append(f"image {i}: {self.image_reason[i]}")
            return
        self.orient(i, fit.eop, "resection")
        self.use[rows] = fit.inliers
        rms = np.sqrt(np.mean(fit.errors[fit.inliers] ** 2))
        new = self.triangulate(self.point[self.obs_of_image[i]])
        self.log.append(f"image {i}: resection on {count} points ({int(np.sum(fit.inliers))}"
                        f" inliers, RMS {self.in_units(rows, rms)}); {new} new points "
                        "intersected")

    def connect(self, i) -> bool:
        """Orient image `i` relatively to an oriented neighbour j (`orient_pair`, in j's camera
        frame with base 1): M_i = R M_j, X0_i = X0_j + s M_jᵀ b, the base length s the median
        of |X - X0_j| / |X_model| over the common inlier points of known coordinates (2 at
        least, agreeing to 20 %). Accepted when half of i's points of known coordinates fit."""
        oriented = np.flatnonzero(self.oriented)
        common = self.shared[i][:, oriented].toarray()[0]
        for k in np.argsort(-common)[:2]:
            j = int(oriented[k])
            if common[k] < self.min_pair_points:
                break
            rj, ri = self.common(j, i)
            known = self.known[self.point[rj]]
            if np.sum(known) < 2:
                continue
            sigma = None if self.sigma_hat is None and self.sigma_given is None else float(
                np.median(self.sigma_normalised(np.r_[rj, ri])))
            try:
                pair = orient_pair(self.q[rj], self.q[ri], self.rng, sigma=sigma)
            except (ValueError, np.linalg.LinAlgError):
                continue
            both = pair.inliers & known
            if np.sum(both) < 2 or pair.median_angle < self.min_angle:
                continue
            m_rel, base = opk_to_matrix(pair.eops[1, 3:]), pair.eops[1, :3]
            model = pair_points(self.q[rj][both], self.q[ri][both], m_rel, base)
            world = self.X[self.point[rj][both]] - self.eops[j, :3]
            scales = np.linalg.norm(world, axis=1) / np.linalg.norm(model, axis=1)
            scale = float(np.median(scales))
            if not (scale > 0 and np.median(np.abs(scales - scale)) <= 0.2 * scale):
                continue
            m_j = self.matrices[j]
            eop = np.r_[self.eops[j, :3] + scale * m_j.T @ base, matrix_to_opk(m_rel @ m_j)]
            rows = self.obs_of_image[i]
            rows = rows[self.known[self.point[rows]]]
            errors = reprojection(m_rel @ m_j, eop[:3], self.X[self.point[rows]], self.q[rows])
            threshold = self.threshold(rows)
            cut = 3.5 * max(robust_sigma(errors), SIGMA_FLOOR)
            inliers = errors <= (cut if threshold is None else np.maximum(threshold, cut))
            if np.sum(inliers) < max(2, len(rows) / 2):
                continue
            self.orient(i, eop, "relative orientation")
            self.use[rows] = inliers
            new = self.triangulate(self.point[self.obs_of_image[i]])
            self.log.append(
                f"image {i}: relative orientation to image {j} on {int(np.sum(pair.inliers))} "
                f"of {len(ri)} common points, base from {int(np.sum(both))} points of known "
                f"coordinates ({int(np.sum(inliers))} of {len(rows)} fit); {new} new points "
                "intersected")
            return True
        return False

    def polish(self, rounds):
        """Resect every image (but given ones) on its used points, then intersect every point
        (but fixed control) again from all its rays, `rounds` times."""
        for _ in range(rounds):
            for i in np.flatnonzero(self.oriented):
                if self.image_method[i] == "given":
                    continue
                rows = self.obs_of_image[i]
                rows = rows[self.known[self.point[rows]] & self.use[rows]]
                if len(rows) < 4:
                    continue
                try:
                    fit = space_resection(self.q[rows], self.X[self.point[rows]], 1.0,
                                          start=self.eops[i], max_iterations=20)
                except (ValueError, np.linalg.LinAlgError):
                    continue
                if np.all(np.isfinite(fit.eop)):
                    self.orient(i, fit.eop, self.image_method[i])
            for p in np.flatnonzero(self.known & ~self.fixed):
                self.reintersect(p)
            self.triangulate(np.flatnonzero(~self.known))
            self.estimate_sigma()

    def estimate_sigma(self):
        """σ̂ of a normalised coordinate from the used image points' residuals (each scaled
        by its `redundancy`), unless σ was given."""
        if self.sigma_given is None:
            rows = self.used_rows()
            if len(rows) >= 10:
                self.sigma_hat = robust_sigma(self.errors(rows) / self.redundancy(rows))

    def used_rows(self) -> np.ndarray:
        """Used image points of oriented images and known points."""
        rows = np.flatnonzero(self.use & self.valid)
        return rows[self.oriented[self.image[rows]] & self.known[self.point[rows]]]

    # -- frame ---------------------------------------------------------------------------

    def normalise_model(self, first, second):
        """Move the model so that image `first` is at the origin with M = I and image `second`
        at distance 1 (the refinement moves them a little)."""
        base = np.linalg.norm(self.eops[second, :3] - self.eops[first, :3])
        m = self.matrices[first]
        self._apply(_similarity(-m @ self.eops[first, :3] / base, m, 1.0 / base))
        self.eops[first] = 0.0
        self.matrices[first] = np.eye(3)

    def to_object_frame(self) -> tuple[str, Similarity | None]:
        """Bring a model-frame block into the object frame (module docstring, step 4): by
        `absolute_orientation` onto 3 or more full control points and given stations, else
        onto one image's given EOPs (the scale from the distances or the control), else onto
        partial control (`partial_similarity`), else only scaled by the distances."""
        points = np.flatnonzero(self.known & np.any(np.isfinite(self.control), axis=1))
        stations = np.flatnonzero(self.oriented & np.all(np.isfinite(self.given[:, :3]), axis=1))
        model = np.r_[self.X[points], self.eops[stations, :3]]
        ground = np.r_[self.control[points], self.given[stations, :3]]
        labels = [f"point {p}" for p in points] + [f"image {i}" for i in stations]
        full = np.all(np.isfinite(ground), axis=1)
        similarity = None
        if np.sum(full) >= 3:
            similarity = self._absolute(model, ground, labels)
        given = np.flatnonzero(self.oriented & np.all(np.isfinite(self.given), axis=1))
        scale, source = self._scale(model[full], ground[full])
        from_distances = source.endswith("distances")
        if similarity is None and len(given):
            i = given[0]
            r = opk_to_matrix(self.given[i, 3:]).T @ self.matrices[i]  # M_G = M_M Rᵀ
            similarity = _similarity(self.given[i, :3] - scale * r @ self.eops[i, :3], r, scale)
            self.log.append(f"frame: rotated and shifted onto the given EOPs of image {i}, "
                            f"scale {scale:.6g} from {source}")
        if similarity is None and np.sum(np.isfinite(ground)) + from_distances >= 7:
            similarity = self._partial(model, ground, scale if from_distances else None,
                                       source)
        if similarity is not None:
            self._apply(similarity)
            return "control", similarity
        if source == "nothing":
            self.log.append("frame: no control, EOPs or distances: the model's (first image "
                            "at the origin, M = I, base 1)")
            return "model", None
        similarity = _similarity(np.zeros(3), np.eye(3), scale)
        self.log.append(f"frame: model scaled by {scale:.6g} from {source}; its origin and axes "
                        "stay the first image's")
        self._apply(similarity)
        return "model", similarity

    def _apply(self, similarity):
        self.eops[self.oriented] = similarity.transform_eops(self.eops[self.oriented])
        self.X[self.known] = similarity.transform(self.X[self.known])
        for i in np.flatnonzero(self.oriented):
            self.matrices[i] = opk_to_matrix(self.eops[i, 3:])

    def _partial(self, model, ground, fixed, source) -> Similarity | None:
        """`partial_similarity` onto fewer than 3 full control points (and the distances'
        scale `fixed`, or None); the log says when the control leaves several solutions."""
        solutions = partial_similarity(model, ground, fixed)
        if not solutions:
            return None
        t, r, s, rms = solutions[0]
        count = int(np.sum(np.isfinite(ground)))
        self.log.append(f"frame: similarity onto {count} control coordinates"
                        + (f" with the scale {s:.6g} from {source}" if fixed else
                           f", scale {s:.6g}") + f", RMS {rms:.3g} (object units)")
        if len(solutions) > 1:
            self.log.append(f"frame: WARNING the control fits {len(solutions)} distinct "
                            "rotations equally well (a minimal datum): the first was taken; "
                            "more control coordinates or given EOPs would decide")
        return _similarity(t, r, s)

    def _absolute(self, model, ground, labels) -> Similarity | None:
        """`absolute_orientation`, dropping the worst full point while it is off by more than
        5 robust σ (and more than 3 full points remain)."""
        keep = np.ones(len(model), dtype=bool)
        while True:
            try:
                similarity = absolute_orientation(model[keep], ground[keep])
            except (ValueError, np.linalg.LinAlgError) as error:
                self.log.append(f"no absolute orientation ({error})")
                return None
            misfit = np.sqrt(np.nansum(similarity.residuals**2, axis=1))
            full = np.all(np.isfinite(ground[keep]), axis=1)
            spread = 1.4826 * np.median(misfit[full]) + 1e-12 * np.max(np.abs(ground[keep][full]))
            worst = int(np.argmax(np.where(full, misfit, -np.inf)))
            if np.sum(full) > 3 and misfit[worst] > 5 * spread and misfit[worst] > 0:
                index = np.flatnonzero(keep)[worst]
                self.log.append(f"absolute orientation: {labels[index]} is off by "
                                f"{misfit[worst]:.3g} (object units): left out")
                keep[index] = False
                continue
            break
        rms = np.sqrt(np.nanmean(similarity.residuals**2))
        self.log.append(f"frame: absolute orientation onto {int(np.sum(full))} full and "
                        f"{int(np.sum(~full))} partial control points / camera stations, "
                        f"scale {similarity.scale:.6g}, RMS {rms:.3g} (object units)")
        return similarity

    def _scale(self, model, ground) -> tuple[float, str]:
        ratios = []
        for a, b, length in self.distances:
            a, b = int(a), int(b)
            if self.known[a] and self.known[b]:
                model_length = np.linalg.norm(self.X[a] - self.X[b])
                if model_length > 0:
                    ratios.append(length / model_length)
        if ratios:
            return float(np.median(ratios)), f"{len(ratios)} distances"
        if len(model) >= 2:
            i, j = np.triu_indices(len(model), 1)
            lengths = np.linalg.norm(model[i] - model[j], axis=1)
            usable = lengths > 0
            if np.any(usable):
                ratio = np.linalg.norm(ground[i] - ground[j], axis=1)[usable] / lengths[usable]
                return float(np.median(ratio)), f"{len(model)} control points / stations"
        return 1.0, "nothing"

    # -- results -------------------------------------------------------------------------

    def result(self, frame, similarity) -> BlockInitialisation:
        if frame != "model":
            given = np.all(np.isfinite(self.given), axis=1)
            for i in np.flatnonzero(given):
                if self.oriented[i] and self.image_method[i] != "given":
                    off = np.linalg.norm(self.eops[i, :3] - self.given[i, :3])
                    self.log.append(f"image {i}: its given EOPs replace the computed ones "
                                    f"(station off by {off:.3g} object units)")
                self.orient(i, self.given[i], "given")
            partial = np.isfinite(self.control)
            full = np.all(partial, axis=1)
            self.X[self.known] = np.where(partial[self.known], self.control[self.known],
                                          self.X[self.known])
            self.X[full] = self.control[full]
            for p in np.flatnonzero(full):
                self.known[p] = self.fixed[p] = True
                self.point_method[p] = "control"
                self.point_reason.pop(p, None)
        rays_X = self.control_by_rays()
        residuals = np.full((self.n, 2), np.nan)
        judged = np.full(self.n, np.nan)
        rows = np.flatnonzero(self.valid)
        rows = rows[self.oriented[self.image[rows]] & self.known[self.point[rows]]]
        sigma = np.full(self.n_images, np.nan)
        blunders = np.zeros(self.n, dtype=bool)
        for g, (camera, group) in enumerate(self.groups):
            here = np.intersect1d(group, rows)
            if len(here) == 0:
                continue
            residuals[here] = image_residuals(camera, self.eops[self.image[here]],
                                              self.X[self.point[here]], self.xy[here])
            # Image points are judged by how their rays agree: a control point by its
            # intersection (its misfit to the control is the frame's, `to_object_frame`).
            left = self.residual_vectors(here, rays_X) * self.scale[here][:, None]
            # Residuals of points with few rays are small: judge them as if redundant.
            norms = np.linalg.norm(left, axis=1) / self.redundancy(here, by_rays=True)
            estimate = float(np.median(norms) / RAYLEIGH_MEDIAN)
            images = self.camera_of_image == g
            floor = 0.0 if self.sigma_given is None else float(
                np.max(self.sigma_given[images]))
            sigma[images] = max(estimate, floor)
            judged[here] = norms / max(estimate, floor, np.finfo(float).tiny)
            # A point intersected from a bent ray is off by as much in its other images, more
            # so the fewer they are (1 + 1 / (k - 2) for k rays).
            allowed = distortion_allowance(self.q[here], self.unknown_distortion)
            worst = np.zeros(self.n_points)
            np.maximum.at(worst, self.point[here], allowed)
            rays = np.bincount(self.point[here], minlength=self.n_points)[self.point[here]]
            allowed = (worst[self.point[here]] * self.scale[here]
                       * (1 + 1 / np.maximum(rays - 2, 1)))
            blunders[here] = flag(norms, max(estimate, floor), allowed,
                                  self.blunder_threshold, self.point[here])
            unit = camera.image_units
            self.log.append(
                f"camera {self.camera_names[g]}: {len(here)} image points in "
                f"{int(np.sum(images))} images, RMS {np.sqrt(np.mean(norms**2)):.3g} {unit}, "
                f"robust σ {estimate:.3g} {unit}; "
                f"{int(np.sum(blunders[here]))} over "
                f"{familywise(len(here), self.blunder_threshold):.2g} σ (and what an unknown "
                "distortion may leave) flagged as blunders")
        failed_images = {}
        for i in np.flatnonzero(~self.oriented):
            reason = self.image_reason.get(i)
            if reason is None:
                rows_i = self.obs_of_image[i]
                count = int(np.sum(self.known[self.point[rows_i]]))
                reason = (f"{len(rows_i)} usable image points, {count} of them of points with "
                          f"coordinates; a resection needs {self.min_resection_points}")
            failed_images[int(i)] = reason
        failed_points = {}
        for p in np.flatnonzero(~self.known):
            rows_p = self.obs_of_point[p]
            images = len(rows_p)
            oriented = int(np.sum(self.oriented[self.image[rows_p]]))
            if images == 0:
                reason = "not observed (no usable image point)"
            elif images == 1:
                reason = f"seen in 1 image only (image {int(self.image[rows_p[0]])})"
            elif oriented < 2:
                reason = f"seen in {images} images, {oriented} of them initialised"
            else:
                reason = self.point_reason.get(p, "its rays do not meet")
            failed_points[int(p)] = reason
        self.log.append(f"initialised {int(np.sum(self.oriented))} of {self.n_images} images "
                        f"and {int(np.sum(self.known))} of {self.n_points} points; "
                        f"{int(np.sum(blunders))} blunders flagged")
        if failed_images:
            self.log.append(f"not initialised: images {sorted(failed_images)}")
        if failed_points:
            listed = sorted(failed_points)
            more = f" and {len(listed) - 20} more" if len(listed) > 20 else ""
            self.log.append(f"not initialised: points {listed[:20]}{more}")
        eops = np.where(self.oriented[:, None], self.eops, np.nan)
        points = np.where(self.known[:, None], self.X, np.nan)
        return BlockInitialisation(
            eops=eops, points=points, image_method=tuple(self.image_method),
            point_method=tuple(m if self.known[p] else None
                               for p, m in enumerate(self.point_method)),
            frame=frame, similarity=similarity, blunders=blunders, unusable=self.unusable,
            residuals=residuals, judged=judged, sigma=sigma, failed_images=failed_images,
            failed_points=failed_points, log=tuple(self.log))


def _similarity(translation, rotation_matrix, scale) -> Similarity:
    """A `Similarity` X_G = T + S R X_M set by hand (no covariance)."""
    return Similarity(parameters=np.r_[translation, matrix_to_opk(rotation_matrix.T), scale],
                      covariance=np.full((7, 7), np.nan), residuals=np.zeros((0, 3)),
                      variance_factor=float("nan"), redundancy=0, iterations=0,
                      converged=True)


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
      familywise bound of their camera's number of image points) are blunders, once the
      field an approximate camera leaves is taken out (`_blunders`);
    - `min_resection_points`: points of known coordinates an image needs for its resection;
    - `min_pair_points`, `pair_candidates`: common points a relative orientation needs (8 at
      least), and how many of the pairs with most of them are tried;
    - `polish_rounds`: rounds of resection and intersection of the whole block at the end;
    - `camera_names`: per image, the name of its camera for the log (default "of image k",
      k its camera's first image);
    - `unknown_distortion`: the misfit a camera's unknown distortion may leave at the edge of
      its image points, as a fraction of their radius (`distortion_allowance`), allowed
      before an image point is a blunder (0 for calibrated cameras).

    Returns a `BlockInitialisation`: EOPs, points, how each was found, flagged blunders and the
    log. Images and points that cannot be initialised are NaN and listed with the reason.
    Needs jax in float64. Raises ValueError for malformed input only.
    """
    require_float64("initialise_block")
    block = _Block(observations, cameras, eops, control, distances, n_points, sigma, seed,
                   min_angle, blunder_threshold, min_resection_points, min_pair_points,
                   pair_candidates, polish_rounds, camera_names, unknown_distortion)
    block.log.insert(0, f"{block.n_images} images, {block.n_points} points, {block.n} image "
                        f"points ({int(np.sum(block.valid))} usable)")
    if block.seed_in_frame():
        frame, similarity = "control", None
    else:
        block._reset()
        if not block.seed_pair():
            for i in range(block.n_images):
                block.image_reason[i] = ("no control or given EOPs to start from, and no image "
                                         "pair could be oriented relatively (see the log)")
            return block.result("model", None)
        frame = None
    block.grow()
    if block.polish_rounds:
        for _ in range(block.polish_rounds):
            block.polish(1)
            block.grow()  # when the refinement let more points in
        rows = block.used_rows()
        rms = np.sqrt(np.mean(block.errors(rows) ** 2)) if len(rows) else np.nan
        block.log.append(f"refinement: {block.polish_rounds} rounds of resection and "
                         f"intersection of the whole block; RMS {block.in_units(rows, rms)}")
    if frame is None:
        block.normalise_model(*block.pair)
        frame, similarity = block.to_object_frame()
    return block.result(frame, similarity)
