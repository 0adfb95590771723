"""Approximations of a camera and its images from planar views: Zhang's closed form.

Per image the homography board plane -> pixels (normalised DLT), from three views or more
Zhang's intrinsics (`jaxba._io._zhang`), then each image's pose. Where Zhang's intrinsics are
not usable (fewer than three views, views nearly parallel: not finite, the principal point off
the image, an aspect ratio beyond 2), the principal point is put at the image centre, the
skew at 0 and one focal length f found from the same constraints, h1ᵀ B h2 = 0 and
h1ᵀ B h1 = h2ᵀ B h2 with B ∝ diag(1, 1, f²) once the centre is moved to the origin; where
even that fails (every view fronto-parallel), f is the image's larger side. Distortion starts
at 0. Plain NumPy.
"""

import dataclasses

import numpy as np

from .._zhang import eop_from_pose, homography, intrinsics, pose

MAX_ASPECT = 2.0  # fx / fy beyond this (or below its inverse): Zhang's intrinsics rejected
MIN_SPREAD = 1e-3  # smallest / largest singular value of a view's centred board points


@dataclasses.dataclass(frozen=True)
class CameraStart:
    """A camera's approximations: `fx fy cx cy` (pixels), how they were found (`method`), and
    each image's EOPs (6,) as X0 (board units) and omega, phi, kappa (degrees)."""

    fx: float
    fy: float
    cx: float
    cy: float
    method: str
    eops: list[np.ndarray]


def spread_enough(plane: np.ndarray) -> bool:
    """Whether the board points (n, 2) seen in a view span a plane (not a line or a point)."""
    if len(plane) < 4:
        return False
    s = np.linalg.svd(plane - plane.mean(axis=0), compute_uv=False)
    return bool(s[-1] > MIN_SPREAD * s[0])


def _plausible(k: np.ndarray, size: tuple[int, int]) -> bool:
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    return bool(np.all(np.isfinite(k)) and fx > 0 and fy > 0
                and 1 / MAX_ASPECT < fx / fy < MAX_ASPECT
                and 0 < cx < size[0] and 0 < cy < size[1])


def focal_from_homographies(homographies: list[np.ndarray], centre: np.ndarray) -> float | None:
    """f (pixels) of a camera with square pixels, no skew and its principal point at
    `centre` (2,), by least squares over the views' two constraints (module docstring); None
    where they do not determine a positive f²."""
    a, b = [], []
    for h in homographies:
        h = np.array([[1, 0, -centre[0]], [0, 1, -centre[1]], [0, 0, 1]]) @ h
        h = h / np.linalg.norm(h)
        (h11, h12, _), (h21, h22, _), (h31, h32, _) = h
        a += [h31 * h32, h31**2 - h32**2]
        b += [-(h11 * h12 + h21 * h22), h12**2 + h22**2 - h11**2 - h21**2]
    a, b = np.array(a), np.array(b)
    denominator = a @ a
    if denominator < 1e-300:
        return None
    f2 = (a @ b) / denominator
    return float(np.sqrt(f2)) if f2 > 0 else None


def camera_start(plane: list[np.ndarray], pixels: list[np.ndarray],
                 size: tuple[int, int]) -> CameraStart:
    """The approximations of one camera from its views: `plane` the board points (n_i, 2)
    seen in each image (board units), `pixels` (n_i, 2) where (pixels), `size` (columns,
    rows). Every view must be `spread_enough`."""
    homographies = [homography(xy, uv) for xy, uv in zip(plane, pixels)]
    k, method = None, "Zhang's closed form"
    if len(homographies) >= 3:
        with np.errstate(invalid="ignore", divide="ignore"):
            k = intrinsics(homographies)
        k[0, 1] = 0.0  # the default free set has no skew
        if not _plausible(k, size):
            k = None
    if k is None:
        centre = (np.asarray(size, dtype=float) - 1) / 2
        f = focal_from_homographies(homographies, centre)
        method = "one focal length, principal point at the centre"
        if f is None or not _plausible(np.array([[f, 0, centre[0]], [0, f, centre[1]],
                                                 [0, 0, 1]]), size):
            f, method = float(max(size)), "a guess: focal length the image's larger side"
        k = np.array([[f, 0.0, centre[0]], [0.0, f, centre[1]], [0.0, 0.0, 1.0]])
    eops = []
    for h in homographies:
        x0, opk = eop_from_pose(*pose(k, h))
        eops.append(np.r_[x0, np.degrees(opk)])
    return CameraStart(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                       method, eops)
