"""Projection uncertainty (`jaxba._statistics._projection`) against Monte Carlo re-adjustments
and an independent propagation through OpenCV's projection."""

import math

import jax
import numpy as np
import pytest
import scipy.optimize
from board_scene import SENSOR, adjusted, write_project
from scipy.spatial.transform import Rotation

import jaxba
from jaxba._statistics._derived import camera_covariance
from jaxba._statistics._projection import sensor_grid, unproject

REPLICATES = 300
# The empirical σ of 300 replicates has a relative standard error of 1/sqrt(600) ≈ 4 %;
# 15 % allows for that (3.5 of it) and for the linearisation.
MC_RTOL = 0.15
PIXELS = np.array([[0.0, 0.0], [639.0, 0.0], [0.0, 479.0], [639.0, 479.0], [320.0, 240.0],
                   [160.0, 120.0], [480.0, 360.0], [320.0, 20.0], [20.0, 240.0]])


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    return adjusted(write_project(tmp_path_factory.mktemp("board"), seed=3))


def _images(iop, points) -> np.ndarray:
    """OpenCV's projection (n, 2) of camera-frame points (n, 3) (x right, y up, looking
    along -z), in NumPy: fx fy cx cy skew k1 k2 p1 p2 k3 = `iop`."""
    fx, fy, cx, cy, skew, k1, k2, p1, p2, k3 = iop
    x, y = points[:, 0] / -points[:, 2], points[:, 1] / points[:, 2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([fx * xd + skew * yd + cx, fy * yd + cy])


def _rays(result, pixels) -> np.ndarray:
    iop = np.asarray(result.parameters.cameras["opencv"][0])
    return np.stack([np.asarray(unproject("opencv", (), iop, q)) for q in pixels])


def _camera_points(problem, params) -> tuple[np.ndarray, np.ndarray]:
    """The camera-frame points p_ij = M_i (X_j - X0_i) (n, 3) of the image points and their
    σ (n, 2), by an independent OPK rotation (scipy)."""
    group = problem.groups[0]
    eop = np.asarray(params.images)[np.asarray(group.image)]
    x = np.asarray(params.points)[np.asarray(group.point)]
    # M = R3(kappa) R2(phi) R1(omega) rotates object vectors into the camera frame.
    m = Rotation.from_euler("XYZ", eop[:, 3:6]).inv().as_matrix()
    return np.einsum("nij,nj->ni", m, x - eop[:, :3]), np.asarray(group.stddev)


def _aligned(iop, p0, p_plus, sigma) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) minimising Σ |(u(iop, R p0 + t) - u(iop, p_plus)) / σ|² (nonlinear)."""
    target = _images(iop, p_plus)

    def residual(x):
        moved = Rotation.from_rotvec(x[:3]).apply(p0) + x[3:]
        return ((_images(iop, moved) - target) / sigma).ravel()

    x = scipy.optimize.least_squares(residual, np.zeros(6), xtol=1e-12, ftol=1e-12).x
    return Rotation.from_rotvec(x[:3]).as_matrix(), x[3:]


@pytest.mark.slow
def test_monte_carlo_matches_both_frames(calibration):
    """Fresh noise, a batch of re-adjustments: the spread of each replicate's projection of
    a fixed ray matches Σ_q, the ray held in the camera frame (intrinsics only) and in the
    world the camera saw (its frame re-aligned to each replicate by a nonlinear fit)."""
    _, result = calibration
    problem, params = result.problem, result.parameters
    replicates = jaxba.monte_carlo(problem, REPLICATES, jax.random.key(11), at=params)
    assert bool(np.all(np.asarray(replicates.solutions.converged)))
    iops = np.asarray(replicates.solutions.parameters.cameras["opencv"][:, 0])
    rays = _rays(result, PIXELS)
    p0, sigma = _camera_points(problem, params)
    solutions = jax.device_get(replicates.solutions.parameters)
    alignments = [
        _aligned(iops[r], p0, _camera_points(
            problem, jax.tree.map(lambda leaf, r=r: leaf[r], solutions))[0], sigma)
        for r in range(REPLICATES)
    ]
    for distance in (math.inf, 400.0):
        points = rays if math.isinf(distance) else rays * distance
        camera = [_images(iop, points) for iop in iops]
        world = [_images(iop, points @ rotation.T + (0.0 if math.isinf(distance) else t))
                 for iop, (rotation, t) in zip(iops, alignments)]
        for frame, spread in (("camera", camera), ("object", world)):
            predicted = result.projection_uncertainty("C1", PIXELS, distance, frame=frame)
            spread = np.asarray(spread)  # (replicates, pixels, 2)
            empirical = np.sqrt(spread.var(axis=0, ddof=1).sum(axis=1) / 2)
            # σ̂0 ≈ 1 here; the replicates' noise is the a priori σ.
            formal = predicted.sigma_rms / result.sigma0
            np.testing.assert_allclose(empirical, formal, rtol=MC_RTOL,
                                       err_msg=f"{frame} at {distance}")


def test_camera_frame_matches_opencv(calibration):
    """Intrinsics only: Σ_q = J C Jᵀ with J from cv2.projectPoints' own Jacobian with
    respect to the intrinsics, C the adjustment's covariance of fx fy cx cy k1 k2 p1 p2 k3."""
    cv2 = pytest.importorskip("cv2")
    _, result = calibration
    pixels = sensor_grid(SENSOR, 7)
    predicted = result.projection_uncertainty("C1", pixels, frame="camera")
    iop = dict(zip(jaxba.OpenCVCamera.parameter_names,
                   np.asarray(result.parameters.cameras["opencv"][0])))
    assert iop["skew"] == 0.0
    rays = _rays(result, pixels)
    cv_points = rays * np.array([1.0, -1.0, -1.0])  # OpenCV's frame: y down, z forward
    k = np.array([[iop["fx"], 0, iop["cx"]], [0, iop["fy"], iop["cy"]], [0, 0, 1.0]])
    distortion = np.array([iop[n] for n in ("k1", "k2", "p1", "p2", "k3")])
    q, jacobian = cv2.projectPoints(cv_points, np.zeros(3), np.zeros(3), k, distortion)
    np.testing.assert_allclose(q[:, 0], pixels, atol=1e-6)
    # Columns of OpenCV's Jacobian: rvec(3), tvec(3), fx, fy, cx, cy, k1, k2, p1, p2, k3.
    names = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    order = [jaxba.OpenCVCamera.parameter_names.index(n) for n in names]
    covariance = camera_covariance(result, "opencv", 0)[np.ix_(order, order)]
    j = jacobian[:, 6:15].reshape(-1, 2, 9)
    expected = np.einsum("nij,jk,nlk->nil", j, covariance, j)
    np.testing.assert_allclose(predicted.covariance, expected, rtol=1e-6,
                               atol=1e-9 * np.abs(expected).max())


def test_distance_and_frame_checked(calibration):
    _, result = calibration
    with pytest.raises(ValueError, match="frame"):
        result.projection_uncertainty("C1", PIXELS, frame="board")
    with pytest.raises(ValueError, match="distance"):
        result.projection_uncertainty("C1", PIXELS, 0.0)
    with pytest.raises(KeyError, match="cameras"):
        result.projection_uncertainty("C9", PIXELS)
