"""Initial approximations (jaxba._approximations) against independent computations: scenes made
with jaxba's own projection (OpkPose + SmacCamera), OpenCV's implementations, Monte Carlo for
the covariances, scipy, and the seeds' worked parallax examples."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from helpers import central_difference
from scipy.spatial.transform import Rotation

import jaxba
from jaxba._approximations._relative_orientation import _coplanarity
from jaxba._approximations._resection import collinearity
from jaxba._models._cameras import SmacCamera
from jaxba._models._poses import OpkPose

EXACT_TOL = 1e-9  # relative: noise-free recovery (float64 closed forms + a few LM steps)
IMAGE_TOL = 1e-10  # mm: noise-free image residuals / reprojection by jaxba's model
OPENCV_STATION_TOL = 1e-6  # relative to the camera distance: the same minimum, OpenCV's LM stop
OPENCV_ANGLE_TOL = 1e-7  # rad
JACOBIAN_RTOL = 1e-6  # analytic Jacobians against central differences (step 1e-6)
MC_STD_RTOL = 0.15  # Monte Carlo std against the predicted σ (300 replicates: ~4 sampling σ)
MC_MEAN_SIGMAS = 4.0  # |mean error| / (σ / sqrt(replicates)): no bias beyond sampling
NOISE_MM = 0.002  # image noise σ, mm (about half a 3.69 µm pixel)

C, XP, YP = 8.52, 0.012, -0.008  # mm: the BASC lab's camera (CONVENTIONS.md)
D_CV = np.diag([1.0, -1.0, -1.0])  # jaxba camera frame (y up, looks along -z) -> OpenCV's


def smac_camera(*, c=C, xp=XP, yp=YP, K1=0.0, P1=0.0, A1=0.0, A2=0.0):
    values = np.zeros(12)
    values[[0, 1, 2, 4, 7, 10, 11]] = xp, yp, c, K1, P1, A1, A2
    return SmacCamera.from_parameters(jnp.asarray(values))


@jax.jit
def _project(camera, eop, points):
    """jaxba's model: x = camera.image_point(M (X - X0), x, 0), the measured point solved by
    fixed-point iteration (the SMAC corrections are evaluated at the measurement)."""
    pose = OpkPose.from_parameters(eop)
    p_camera = jax.vmap(pose.to_camera)(points)
    image_point = jax.vmap(lambda p, x: camera.image_point(p, x, jnp.zeros(())))
    return jax.lax.fori_loop(0, 60, lambda _, x: image_point(p_camera, x),
                             jnp.zeros((points.shape[0], 2)))


def project(camera, eop, points):
    return np.asarray(_project(camera, jnp.asarray(eop), jnp.asarray(points)))


def smac_correction(camera):
    """Measured -> distortion-free coordinates of a SMAC camera: x - dist(x - xp)."""
    principal_point = jnp.stack([camera.xp, camera.yp])

    def distortion(x):
        reduced = x - principal_point
        return (camera.radial.correction(reduced) + camera.decentering.correction(reduced)
                + camera.affine.correction(reduced))

    return lambda xy: np.asarray(xy - jax.vmap(distortion)(jnp.asarray(xy)))


def field(rng, n, *, relief=2.0):
    """n object points on a 10 m x 8 m area with `relief` m of height, metres."""
    return rng.uniform([-5.0, -4.0, -relief / 2], [5.0, 4.0, relief / 2], (n, 3))


# An oblique image over the field, 20 m above it (X0 m, angles rad).
EOP = np.array([1.2, -2.5, 20.0, 0.12, -0.08, 0.6])


def angle_error(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


def assert_eop_close(found, truth, rtol, atol_angle):
    np.testing.assert_allclose(found[:3], truth[:3], rtol=0, atol=rtol * np.linalg.norm(truth[:3]))
    assert np.all(angle_error(found[3:], truth[3:]) <= atol_angle)


def to_opencv(eop):
    """OpenCV's (R, t) of a jaxba images row: p_cv = D M (X - X0) = R X + t."""
    r = D_CV @ np.asarray(jaxba.opk_to_matrix(jnp.asarray(eop[3:])))
    return r, -r @ eop[:3]


def opencv_image(xy, *, xp=XP, yp=YP):
    """jaxba image mm (y up, from the principal point) -> OpenCV's image plane with K =
    diag(c, c, 1): (x - xp, -(y - yp))."""
    return np.c_[xy[:, 0] - xp, -(xy[:, 1] - yp)]


# --- DLT ---------------------------------------------------------------------------------------


def test_dlt_recovers_interior_orientation_with_affinity_and_eops():
    """Noise-free points of jaxba's SMAC camera with affinity (A1, A2, evaluated at the
    measured point): the decomposition returns c, xp, yp, A1, A2 and the EOPs."""
    rng = np.random.default_rng(1)
    points = field(rng, 14)
    camera = smac_camera(A1=1.5e-3, A2=-2e-3)
    xy = project(camera, EOP, points)
    fitted = jaxba.dlt(xy, points)
    orientation = jaxba.decompose_dlt(fitted.matrix)
    np.testing.assert_allclose([orientation.c, orientation.xp, orientation.yp],
                               [C, XP, YP], rtol=EXACT_TOL, atol=EXACT_TOL * C)
    np.testing.assert_allclose([orientation.A1, orientation.A2], [1.5e-3, -2e-3], atol=EXACT_TOL)
    assert_eop_close(orientation.eop, EOP, EXACT_TOL, EXACT_TOL)
    assert np.max(np.abs(fitted.residuals)) < IMAGE_TOL
    # The L1..L11 written out as the seed's DLT equations reproduce the image points.
    L = fitted.parameters
    h = points @ L[8:11] + 1
    np.testing.assert_allclose(np.c_[(points @ L[0:3] + L[3]) / h, (points @ L[4:7] + L[7]) / h],
                               xy, atol=IMAGE_TOL)


def test_dlt_decomposition_agrees_with_opencv():
    """cv2.decomposeProjectionMatrix of the same P: K_cv = K diag(-1, -1, 1) (positive
    diagonal), R_cv = diag(-1, -1, 1) M, and the same perspective centre."""
    rng = np.random.default_rng(2)
    points = field(rng, 10)
    xy = project(smac_camera(A1=-1e-3, A2=5e-4), EOP, points)
    p = jaxba.dlt(xy, points).matrix
    orientation = jaxba.decompose_dlt(p)
    k_cv, r_cv, centre = cv2.decomposeProjectionMatrix(p)[:3]
    flip = np.diag([-1.0, -1.0, 1.0])
    m = np.asarray(jaxba.opk_to_matrix(jnp.asarray(orientation.eop[3:])))
    np.testing.assert_allclose(r_cv, flip @ m, atol=EXACT_TOL)
    np.testing.assert_allclose(centre[:3, 0] / centre[3, 0], orientation.eop[:3],
                               rtol=EXACT_TOL)
    cx = orientation.c / (1 + orientation.A1)
    cy = orientation.c / (1 - orientation.A1)
    skew = -orientation.A2 * cx * cy / orientation.c
    k = np.array([[-cx, skew, orientation.xp], [0, -cy, orientation.yp], [0, 0, 1]])
    np.testing.assert_allclose(k_cv / k_cv[2, 2], k @ flip, atol=EXACT_TOL * C)


def test_dlt_refuses_too_few_and_coplanar_points():
    rng = np.random.default_rng(3)
    points = field(rng, 8)
    xy = project(smac_camera(), EOP, points)
    with pytest.raises(ValueError, match="at least 6"):
        jaxba.dlt(xy[:5], points[:5])
    flat = points.copy()
    flat[:, 2] = 0.3
    with pytest.raises(ValueError, match="coplanar"):
        jaxba.dlt(project(smac_camera(), EOP, flat), flat)
    with pytest.raises(ValueError, match="mirrors"):
        jaxba.decompose_dlt(-jaxba.dlt(xy, points).matrix)


# --- space resection ----------------------------------------------------------------------------


@pytest.mark.parametrize("relief", [2.0, 0.0], ids=["non-planar", "planar"])
def test_resection_noise_free_reproduces_the_image_points(relief):
    """The EOPs found make jaxba's own projection (OpkPose + SmacCamera) give the image points
    back; they are the true ones, from the closed-form start alone nearly so."""
    rng = np.random.default_rng(4)
    points = field(rng, 12, relief=relief)
    camera = smac_camera()
    xy = project(camera, EOP, points)
    found = jaxba.space_resection(xy, points, C, principal_point=(XP, YP))
    assert found.converged
    assert_eop_close(found.eop, EOP, EXACT_TOL, EXACT_TOL)
    assert_eop_close(found.start, EOP, 1e-6, 1e-6)  # the closed form itself, noise-free
    np.testing.assert_allclose(project(camera, found.eop, points), xy, atol=IMAGE_TOL)
    assert np.max(np.abs(found.residuals)) < IMAGE_TOL


def test_resection_with_a_distortion_correction_callable():
    """SMAC distortion (K1, P1) evaluated at the measured point: with the camera's correction
    the EOPs are exact; ignoring it they are off by far more than the tolerance."""
    rng = np.random.default_rng(5)
    points = field(rng, 12)
    camera = smac_camera(K1=-8e-3, P1=2e-4)
    xy = project(camera, EOP, points)
    found = jaxba.space_resection(xy, points, C, principal_point=(XP, YP),
                                  correction=smac_correction(camera))
    assert_eop_close(found.eop, EOP, EXACT_TOL, EXACT_TOL)
    ignored = jaxba.space_resection(xy, points, C, principal_point=(XP, YP))
    assert np.max(angle_error(ignored.eop[3:], EOP[3:])) > 1e3 * EXACT_TOL
    # Coordinates corrected beforehand give the same EOPs.
    corrected = jaxba.space_resection(smac_correction(camera)(xy), points, C,
                                      principal_point=(XP, YP))
    np.testing.assert_allclose(corrected.eop, found.eop, rtol=0, atol=1e-12 * 20)


@pytest.mark.parametrize("relief", [2.0, 0.0], ids=["non-planar", "planar"])
def test_resection_agrees_with_opencv_solvepnp(relief):
    """Noisy image points: cv2.solvePnP (iterative, refined by solvePnPRefineLM) minimises the
    same sum of squared image residuals; converted to jaxba's frame, the same EOPs."""
    rng = np.random.default_rng(6)
    points = field(rng, 15, relief=relief)
    xy = project(smac_camera(), EOP, points) + rng.normal(0, NOISE_MM, (15, 2))
    found = jaxba.space_resection(xy, points, C, principal_point=(XP, YP))
    k = np.diag([C, C, 1.0])
    image = opencv_image(xy)
    ok, rvec, tvec = cv2.solvePnP(points, image, k, None, flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok
    rvec, tvec = cv2.solvePnPRefineLM(points, image, k, None, rvec, tvec)
    r_cv = cv2.Rodrigues(rvec)[0]
    m = D_CV @ r_cv
    station = -r_cv.T @ tvec[:, 0]
    distance = np.linalg.norm(EOP[:3])
    np.testing.assert_allclose(found.eop[:3], station, rtol=0, atol=OPENCV_STATION_TOL * distance)
    assert np.all(angle_error(found.eop[3:], np.asarray(jaxba.matrix_to_opk(jnp.asarray(m))))
                  < OPENCV_ANGLE_TOL)


def test_resection_covariance_by_monte_carlo():
    """300 noisy replicates: the spread of the EOPs matches the predicted σ (a priori σ²
    (AᵀA)⁻¹), the estimates are unbiased, and σ̂0² averages 1."""
    rng = np.random.default_rng(7)
    points = field(rng, 10)
    xy = project(smac_camera(), EOP, points)
    replicates = 300
    errors, factors = [], []
    for _ in range(replicates):
        found = jaxba.space_resection(xy + rng.normal(0, NOISE_MM, xy.shape), points, C,
                                      principal_point=(XP, YP), sigma=NOISE_MM,
                                      a_posteriori=False)
        errors.append(np.r_[found.eop[:3] - EOP[:3],
                            (found.eop[3:] - EOP[3:] + np.pi) % (2 * np.pi) - np.pi])
        factors.append(found.variance_factor)
    errors = np.array(errors)
    predicted = found.sigma  # the design hardly changes between replicates
    np.testing.assert_allclose(errors.std(axis=0), predicted, rtol=MC_STD_RTOL)
    assert np.all(np.abs(errors.mean(axis=0)) < MC_MEAN_SIGMAS * predicted / np.sqrt(replicates))
    assert abs(np.mean(factors) - 1) < 0.1  # r = 14: σ(mean) = sqrt(2/14/300) = 0.02


def test_resection_refuses_degenerate_input():
    rng = np.random.default_rng(8)
    points = field(rng, 6)
    xy = project(smac_camera(), EOP, points)
    with pytest.raises(ValueError, match="at least 4"):
        jaxba.space_resection(xy[:3], points[:3], C)
    line = np.c_[np.linspace(-4, 4, 6), np.zeros(6), np.zeros(6)]
    with pytest.raises(ValueError, match="collinear"):
        jaxba.space_resection(project(smac_camera(), EOP, line), line, C)
    with pytest.raises(ValueError, match="principal distance"):
        jaxba.space_resection(xy, points, -C)
    with pytest.raises(ValueError, match="differ in length"):
        jaxba.space_resection(xy, points[:5], C)


# --- forward intersection -----------------------------------------------------------------------

STATIONS = np.array([
    [-3.0, -1.0, 20.0, 0.05, -0.10, 0.02],
    [4.0, -0.5, 20.5, -0.03, 0.12, -0.05],
    [0.5, 5.0, 19.0, -0.15, 0.02, 0.10],
])


def test_intersection_noise_free_and_against_opencv_triangulation():
    """Two and three images, noise-free: the true point; cv2.triangulatePoints (linear, in
    OpenCV's frame) finds the same point from two images."""
    rng = np.random.default_rng(9)
    point = field(rng, 1)
    camera = smac_camera()
    xy = np.concatenate([project(camera, eop, point) for eop in STATIONS])
    for count in (2, 3):
        found = jaxba.forward_intersection(xy[:count], STATIONS[:count], C,
                                           principal_point=(XP, YP))
        np.testing.assert_allclose(found.point, point[0], rtol=0, atol=EXACT_TOL * 20)
        np.testing.assert_allclose(found.closest, point[0], rtol=0, atol=EXACT_TOL * 20)
        assert np.max(np.abs(found.residuals)) < IMAGE_TOL
    projections = [np.diag([C, C, 1.0]) @ np.c_[r, t] for r, t in map(to_opencv, STATIONS[:2])]
    homogeneous = cv2.triangulatePoints(*projections, opencv_image(xy[:1]).T,
                                        opencv_image(xy[1:2]).T)
    np.testing.assert_allclose(homogeneous[:3, 0] / homogeneous[3, 0], point[0], rtol=0,
                               atol=EXACT_TOL * 20)


def test_intersection_matches_scipy_least_squares_and_monte_carlo():
    """Noisy rays: the refined point is the minimum scipy.optimize.least_squares finds on
    jaxba's projection; 300 replicates spread as the predicted covariance says."""
    rng = np.random.default_rng(10)
    point = field(rng, 1)
    camera = smac_camera()
    xy = np.concatenate([project(camera, eop, point) for eop in STATIONS])
    noisy = xy + rng.normal(0, NOISE_MM, xy.shape)
    found = jaxba.forward_intersection(noisy, STATIONS, C, principal_point=(XP, YP))

    def residuals(x):
        return np.concatenate([project(camera, eop, x[None]) for eop in STATIONS]).ravel() \
            - noisy.ravel()

    reference = scipy.optimize.least_squares(residuals, found.closest, xtol=1e-15, ftol=1e-15,
                                             gtol=1e-15).x
    np.testing.assert_allclose(found.point, reference, rtol=0, atol=1e-9)
    replicates = 300
    errors = np.array([
        jaxba.forward_intersection(xy + rng.normal(0, NOISE_MM, xy.shape), STATIONS, C,
                                   principal_point=(XP, YP)).point - point[0]
        for _ in range(replicates)
    ])
    predicted = jaxba.forward_intersection(xy, STATIONS, C, principal_point=(XP, YP),
                                           sigma=NOISE_MM, a_posteriori=False).covariance
    np.testing.assert_allclose(errors.std(axis=0), np.sqrt(np.diag(predicted)),
                               rtol=MC_STD_RTOL)
    empirical = np.cov(errors.T)
    correlation = empirical[0, 2] / np.sqrt(empirical[0, 0] * empirical[2, 2])
    assert abs(correlation - predicted[0, 2] / np.sqrt(predicted[0, 0] * predicted[2, 2])) < 0.2


def test_intersection_refuses_degenerate_rays():
    camera = smac_camera()
    point = np.array([[0.5, 0.5, 0.0]])
    xy = np.concatenate([project(camera, eop, point) for eop in STATIONS])
    with pytest.raises(ValueError, match="at least 2"):
        jaxba.forward_intersection(xy[:1], STATIONS[:1], C)
    # Two vertical images, both measuring their principal point: parallel (vertical) rays.
    vertical = np.array([[0.0, 0.0, 20.0, 0.0, 0.0, 0.0], [5.0, 0.0, 20.0, 0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="parallel"):
        jaxba.forward_intersection(np.zeros((2, 2)), vertical, C)
    # Rays that diverge downwards meet above the cameras: behind them.
    with pytest.raises(ValueError, match="behind"):
        jaxba.forward_intersection(np.array([[-1.0, 0.0], [1.0, 0.0]]), vertical, C)


# --- relative orientation -----------------------------------------------------------------------

PAIR = np.array([
    [0.0, 0.0, 20.0, 0.03, -0.02, 0.05],
    [6.0, 0.4, 20.6, -0.04, 0.05, -0.03],
])  # a near-vertical pair, base mostly along X


def pair_scene(seed, n, *, noise=0.0):
    rng = np.random.default_rng(seed)
    points = field(rng, n)
    points[:, 0] += 3.0  # under the overlap
    camera = smac_camera()
    xy = [project(camera, eop, points) + rng.normal(0, noise, (n, 2)) if noise
          else project(camera, eop, points) for eop in PAIR]
    return points, xy[0], xy[1]


def dependent_truth(bx):
    """(by, bz, omega2, phi2, kappa2) of PAIR, written out: model frame = image 1's frame."""
    m1, m2 = (np.asarray(jaxba.opk_to_matrix(jnp.asarray(e[3:]))) for e in PAIR)
    base = m1 @ (PAIR[1, :3] - PAIR[0, :3])
    return np.r_[(base * bx / base[0])[1:], np.asarray(jaxba.matrix_to_opk(jnp.asarray(m2 @ m1.T)))]


@pytest.mark.parametrize("parameterisation", ["dependent", "independent"])
def test_relative_orientation_noise_free(parameterisation):
    """Both parameterisations: the model points projected by jaxba's model with the returned
    EOPs give the image points back, and the model is a similarity of the truth (absolute
    orientation to the true points leaves no residual and returns the true EOPs)."""
    points, xy1, xy2 = pair_scene(11, 12)
    bx = 2.5
    found = jaxba.relative_orientation(xy1, xy2, C, principal_point=(XP, YP), bx=bx,
                                       parameterisation=parameterisation)
    assert found.converged and found.redundancy == 7
    assert np.max(np.abs(found.residuals)) < IMAGE_TOL
    camera = smac_camera()
    for eop, xy in zip(found.eops, (xy1, xy2)):
        np.testing.assert_allclose(project(camera, eop, found.points), xy, atol=IMAGE_TOL)
    if parameterisation == "dependent":
        np.testing.assert_allclose(found.parameters, dependent_truth(bx), rtol=0,
                                   atol=EXACT_TOL)
        np.testing.assert_allclose(found.eops[0], 0.0)
        np.testing.assert_allclose(found.eops[1, :3], [bx, *found.parameters[:2]])
    else:
        np.testing.assert_allclose(found.eops[1, :3], [bx, 0.0, 0.0])
        assert found.eops[0, 3] == 0.0  # omega1 fixed
    similarity = jaxba.absolute_orientation(found.points, points)
    assert np.nanmax(np.abs(similarity.residuals)) < EXACT_TOL * 10
    ground = similarity.transform_eops(found.eops)
    for eop, truth in zip(ground, PAIR):
        assert_eop_close(eop, truth, EXACT_TOL, EXACT_TOL)


def test_relative_orientation_from_zero_start_matches_essential_start():
    """The classical start for a near-vertical pair (all five parameters 0) converges to the
    solution started from the essential matrix (noisy points: the same least-squares minimum)."""
    _, xy1, xy2 = pair_scene(12, 15, noise=NOISE_MM)
    for parameterisation in ("dependent", "independent"):
        from_e = jaxba.relative_orientation(xy1, xy2, C, principal_point=(XP, YP),
                                            parameterisation=parameterisation)
        from_zero = jaxba.relative_orientation(xy1, xy2, C, principal_point=(XP, YP),
                                               parameterisation=parameterisation,
                                               start=np.zeros(5))
        np.testing.assert_allclose(from_zero.parameters, from_e.parameters, rtol=0, atol=1e-9)


def test_essential_matrix_agrees_with_opencv():
    """cv2.findEssentialMat + cv2.recoverPose on the same points (OpenCV's frame: x right,
    y down, looking along +z): the same rotation and base direction; the coplanarity
    r2ᵀ E r1 vanishes for every point."""
    _, xy1, xy2 = pair_scene(13, 20)
    essential = jaxba.essential_matrix(xy1, xy2, C, principal_point=(XP, YP))
    assert essential.in_front == 20
    r1, r2 = (np.c_[xy - [XP, YP], np.full(len(xy), -C)] for xy in (xy1, xy2))
    e = essential.matrix / np.linalg.norm(essential.matrix)
    assert np.max(np.abs(np.einsum("ni,ij,nj->n", r2, e, r1))) < IMAGE_TOL
    cv1, cv2_points = opencv_image(xy1), opencv_image(xy2)
    k = np.diag([C, C, 1.0])
    e_cv, _ = cv2.findEssentialMat(cv1, cv2_points, k, method=cv2.RANSAC, prob=0.999999,
                                   threshold=1e-6)
    _, r_cv, t_cv, _ = cv2.recoverPose(e_cv[:3], cv1, cv2_points, k)
    # p2 = R (p1 - b) in jaxba's frames; p_cv = D p: R_cv = D R D, t_cv = -D R b.
    np.testing.assert_allclose(r_cv, D_CV @ essential.rotation @ D_CV, atol=1e-8)
    np.testing.assert_allclose(t_cv[:, 0], -D_CV @ essential.rotation @ essential.base,
                               atol=1e-8)


def test_essential_matrix_from_exactly_eight_points():
    """The minimal set of the 8-point method: the 8 x 9 system's null vector is unique (its
    missing ninth singular value is 0, not a degeneracy), and it equals the 20-point E."""
    _, xy1, xy2 = pair_scene(13, 20)
    full = jaxba.essential_matrix(xy1, xy2, C, principal_point=(XP, YP))
    eight = jaxba.essential_matrix(xy1[:8], xy2[:8], C, principal_point=(XP, YP))
    np.testing.assert_allclose(eight.rotation, full.rotation, atol=1e-8)
    np.testing.assert_allclose(eight.base, full.base, atol=1e-8)


def test_relative_orientation_covariance_by_monte_carlo():
    """300 noisy replicates of the dependent orientation: the spread of the five parameters
    matches the predicted σ (a priori), without bias."""
    points, xy1, xy2 = pair_scene(14, 12)
    bx = 6.0
    truth = dependent_truth(bx)
    rng = np.random.default_rng(15)
    replicates = 300
    errors = np.array([
        jaxba.relative_orientation(xy1 + rng.normal(0, NOISE_MM, xy1.shape),
                                   xy2 + rng.normal(0, NOISE_MM, xy2.shape), C,
                                   principal_point=(XP, YP), bx=bx, start=truth).parameters
        - truth
        for _ in range(replicates)
    ])
    predicted = jaxba.relative_orientation(xy1, xy2, C, principal_point=(XP, YP), bx=bx,
                                           sigma=NOISE_MM, a_posteriori=False).sigma
    np.testing.assert_allclose(errors.std(axis=0), predicted, rtol=MC_STD_RTOL)
    assert np.all(np.abs(errors.mean(axis=0)) < MC_MEAN_SIGMAS * predicted / np.sqrt(replicates))


def test_relative_orientation_refuses_degenerate_input():
    points, xy1, xy2 = pair_scene(16, 10)
    with pytest.raises(ValueError, match="at least 5"):
        jaxba.relative_orientation(xy1[:4], xy2[:4], C, start=np.zeros(5))
    with pytest.raises(ValueError, match="needs 8"):
        jaxba.relative_orientation(xy1[:6], xy2[:6], C)
    with pytest.raises(ValueError, match="bx"):
        jaxba.relative_orientation(xy1, xy2, C, bx=0.0)
    with pytest.raises(ValueError, match="fix bx = -1.0"):
        jaxba.relative_orientation(xy2, xy1, C)  # image 2 to the left of image 1
    # Zero base: both images from one station, turned.
    turned = np.r_[PAIR[0, :3], 0.1, -0.05, 0.3]
    xy_turned = project(smac_camera(), turned, points)
    with pytest.raises(ValueError, match="no parallax"):
        jaxba.relative_orientation(xy1, xy_turned, C, principal_point=(XP, YP))
    with pytest.raises(ValueError, match="no parallax"):
        jaxba.essential_matrix(xy1, xy_turned, C, principal_point=(XP, YP))
    flat = points.copy()
    flat[:, 2] = 0.0
    camera = smac_camera()
    with pytest.raises(ValueError, match="plane"):
        jaxba.essential_matrix(project(camera, PAIR[0], flat), project(camera, PAIR[1], flat), C)


# --- absolute orientation -----------------------------------------------------------------------


def similarity_scene(seed, n, *, noise=0.0):
    rng = np.random.default_rng(seed)
    model = rng.uniform(-1, 1, (n, 3)) * [3.0, 2.0, 0.5]
    rotation = np.asarray(jaxba.opk_to_matrix(jnp.array([0.2, -0.3, 2.0]))).T
    truth = np.r_[4.5e5, 5.2e6, 310.0, 0.2, -0.3, 2.0, 85.0]
    ground = truth[:3] + truth[6] * model @ rotation.T + rng.normal(0, noise, (n, 3))
    return model, ground, truth


def test_absolute_orientation_noise_free_with_partial_control():
    """Exact recovery of the seven parameters; a point with only Z given (NaN for X, Y) is used
    and its missing residuals stay NaN."""
    model, ground, truth = similarity_scene(17, 6)
    ground[4, :2] = np.nan  # a vertical control point
    found = jaxba.absolute_orientation(model, ground)
    np.testing.assert_allclose(found.parameters[:3], truth[:3], rtol=EXACT_TOL)
    np.testing.assert_allclose(found.parameters[3:6], truth[3:6], atol=EXACT_TOL)
    np.testing.assert_allclose(found.scale, truth[6], rtol=EXACT_TOL)
    assert found.redundancy == 16 - 7
    assert np.all(np.isnan(found.residuals[4, :2]))
    assert np.nanmax(np.abs(found.residuals)) < EXACT_TOL * 1e3  # m, at 5e6 m coordinates
    np.testing.assert_allclose(found.transform(model)[:, 2], ground[:, 2], rtol=EXACT_TOL)


def test_absolute_orientation_closed_form_is_the_least_squares_minimum():
    """Noisy full points, equal weights: Umeyama's closed form is already the least-squares
    minimum (the refinement does not move it), and its rotation is scipy's
    Rotation.align_vectors of the centred points."""
    model, ground, _ = similarity_scene(18, 8, noise=0.05)
    refined = jaxba.absolute_orientation(model, ground)
    closed = jaxba.absolute_orientation(model, ground, refine=False)
    np.testing.assert_allclose(refined.parameters[3:], closed.parameters[3:], atol=1e-10)
    np.testing.assert_allclose(refined.parameters[:3], closed.parameters[:3], rtol=0, atol=1e-7)
    rotation, _ = Rotation.align_vectors(ground - ground.mean(0), model - model.mean(0))
    np.testing.assert_allclose(closed.rotation, rotation.as_matrix(), atol=1e-12)


def test_absolute_orientation_covariance_by_monte_carlo():
    model, ground, truth = similarity_scene(19, 5)
    rng = np.random.default_rng(20)
    noise = 0.02
    replicates = 300
    errors = np.array([
        jaxba.absolute_orientation(model, ground + rng.normal(0, noise, ground.shape)).parameters
        - truth
        for _ in range(replicates)
    ])
    predicted = jaxba.absolute_orientation(model, ground, sigma=noise, a_posteriori=False).sigma
    np.testing.assert_allclose(errors.std(axis=0), predicted, rtol=MC_STD_RTOL)
    assert np.all(np.abs(errors.mean(axis=0)) < MC_MEAN_SIGMAS * predicted / np.sqrt(replicates))


def test_absolute_orientation_refuses_degenerate_input():
    model, ground, _ = similarity_scene(21, 5)
    with pytest.raises(ValueError, match="collinear"):
        line = np.c_[np.arange(5.0), 2 * np.arange(5.0), np.zeros(5)]
        jaxba.absolute_orientation(line, ground)
    partial = ground.copy()
    partial[2:, 0] = np.nan
    with pytest.raises(ValueError, match="2 points with all three"):
        jaxba.absolute_orientation(model, partial)


# --- stereo parallax ----------------------------------------------------------------------------


def test_parallax_seed_example_1():
    """Seed 003, Example (1): H = 1233 m, f = 152.4 mm, B = 390 m, flight-line coordinates of
    a and b. The seed prints no answer; the values below are worked by hand from its data
    (p_a = 91.7 mm, p_b = 96.0 mm, h = H - B f / p, X = B x / p, Y = B y / p), to the metre
    (0.1 m for AB, whose rounded-coordinate value is 428 m)."""
    p_a = jaxba.stereo_parallax(53.4, -38.3)
    p_b = jaxba.stereo_parallax(88.9, -7.1)
    np.testing.assert_allclose([p_a, p_b], [91.7, 96.0], rtol=1e-12)
    a = jaxba.ground_from_parallax(53.4, 50.8, p_a, 390.0, 152.4, 1233.0)
    b = jaxba.ground_from_parallax(88.9, -46.7, p_b, 390.0, 152.4, 1233.0)
    np.testing.assert_allclose(np.round([a[2], b[2]]), [585.0, 614.0])
    np.testing.assert_allclose(np.round(a[:2]), [227.0, 216.0])
    np.testing.assert_allclose(np.round(b[:2]), [361.0, -190.0])
    assert round(float(np.hypot(*(a[:2] - b[:2]))), 1) == 427.3
    assert jaxba.elevation_from_parallax(p_a, 390.0, 152.4, 1233.0) == a[2]


def test_parallax_seed_example_2():
    """Seed 003, Example (2): the printed arithmetic (1622 - 263) 86.3 / 152.4 = 770 m is
    B = (H - h) p / f; the example's own data (B = 548 m, h = 283 m, p = 86.3 mm) give
    H = h + B f / p, and back."""
    assert round(float(jaxba.air_base_from_parallax(86.3, 152.4, 1622.0, 263.0))) == 770
    height = jaxba.flying_height_from_parallax(86.3, 548.0, 152.4, 283.0)
    np.testing.assert_allclose(height, 283.0 + 548.0 * 152.4 / 86.3, rtol=1e-15)
    np.testing.assert_allclose(jaxba.elevation_from_parallax(86.3, 548.0, 152.4, height), 283.0)


def test_parallax_relations_on_a_vertical_pair_by_jaxba_projection():
    """A truly vertical pair (omega = phi = kappa = 0, base along X) projected by jaxba's
    model: elevations, ground coordinates and the parallax-difference formula are exact."""
    rng = np.random.default_rng(22)
    points = field(rng, 8, relief=30.0)
    height, base = 1000.0, 300.0
    camera = smac_camera(c=152.4, xp=0.0, yp=0.0)
    left = project(camera, [0.0, 0.0, height, 0.0, 0.0, 0.0], points)
    right = project(camera, [base, 0.0, height, 0.0, 0.0, 0.0], points)
    p = jaxba.stereo_parallax(left[:, 0], right[:, 0])
    ground = jaxba.ground_from_parallax(left[:, 0], left[:, 1], p, base, 152.4, height)
    np.testing.assert_allclose(ground, points, rtol=0, atol=EXACT_TOL * height)
    np.testing.assert_allclose(
        jaxba.elevation_from_parallax_difference(p, p[0], points[0, 2], height), points[:, 2],
        rtol=0, atol=EXACT_TOL * height)
    with pytest.raises(ValueError, match="zero parallax"):
        jaxba.elevation_from_parallax(0.0, base, 152.4, height)


def test_refinement_jacobians_match_central_differences():
    """The hand-written Jacobians of the refinements: collinearity by the six EOPs, and the
    Sampson distance of coplanarity by the five parameters of both parameterisations."""
    rng = np.random.default_rng(23)
    points = field(rng, 5)
    eop = EOP + rng.normal(0, 0.01, 6)
    _, jacobian = collinearity(eop, points, C)
    numeric = central_difference(lambda e: collinearity(e, points, C)[0], eop, 1e-6)
    np.testing.assert_allclose(jacobian, numeric, rtol=JACOBIAN_RTOL, atol=JACOBIAN_RTOL)
    r1, r2 = (np.c_[rng.normal(0, 3, (6, 2)), np.full(6, -C)] for _ in range(2))
    for parameterisation in ("dependent", "independent"):
        parameters = rng.normal(0, 0.1, 5)
        _, jacobian = _coplanarity(parameters, r1, r2, parameterisation, 2.0)
        numeric = central_difference(
            lambda p: _coplanarity(p, r1, r2, parameterisation, 2.0)[0], parameters, 1e-6)
        np.testing.assert_allclose(jacobian, numeric, rtol=JACOBIAN_RTOL, atol=JACOBIAN_RTOL)


def test_refuses_float32_jax_but_parallax_needs_no_jax():
    rng = np.random.default_rng(24)
    points = field(rng, 6)
    xy = project(smac_camera(), EOP, points)
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="float64"):
            jaxba.space_resection(xy, points, C)
        assert jaxba.elevation_from_parallax(91.7, 390.0, 152.4, 1233.0).dtype == np.float64


def test_public_names():
    names = ("dlt", "decompose_dlt", "space_resection", "forward_intersection",
             "essential_matrix", "relative_orientation", "absolute_orientation",
             "stereo_parallax", "ground_from_parallax", "Similarity", "Resection")
    assert set(names) <= set(jaxba.__all__)
    assert all(callable(getattr(jaxba, name)) for name in names)
