"""The state of one block initialisation (`Block`): the image points and their rays, the
oriented images, the known points and which image points are used, with the helpers that read
them. `_seed`, `_growth`, `_placement` and `_outcome` work on it; `initialise_block` runs them.
"""

import numpy as np

from ..._models._cameras import AbstractCamera
from ..._models._rotation_numpy import opk_to_matrix
from ._ideal import ideal_coordinates
from ._robust import SIGMA_FLOOR, intersect, project, robust_sigma

INLIER_K = 3.5
"""Inlier cut of a 2D reprojection error during the growth, in σ (chi² with 2 dof, 99.8 %)."""


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


class Block:
    """The state of one initialisation: oriented images, known points, used image points."""

    def __init__(self, observations, cameras, eops, control, distances, n_points, sigma,
                 seed, min_angle, blunder_threshold, min_resection_points, min_pair_points,
                 pair_candidates, polish_rounds, camera_names, unknown_distortion,
                 inlier_k):
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
        self.inlier_k = float(inlier_k)
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
        return None if sigma is None else self.inlier_k * sigma

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

    def common(self, i, j):
        """Image point rows (k,), (k,) of the points that images i and j both see."""
        a, b = self.obs_of_image[i], self.obs_of_image[j]
        shared, ia, jb = np.intersect1d(self.point[a], self.point[b], return_indices=True)
        return a[ia], b[jb]

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
