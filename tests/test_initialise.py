"""Tests of block initialisation (`jaxba.initialise_block`) and of the rays of
measured points for any camera model (`jaxba.ideal_coordinates`), on synthetic blocks made with
jaxba itself: the BASC lab replica (`jaxba.write_synthetic_project`), a convergent block of an
OpenCV pixel camera, and a vertical aerial block over flat terrain.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._io._synthetic import (
    IOP_NAMES,
    datum_targets,
    distance_pairs,
    make_stations,
    make_targets,
)
from jaxba._problem._observations import ImagePoints

ANGLE = 1e-12


def wrap(angles):
    return (np.asarray(angles) + np.pi) % (2 * np.pi) - np.pi


@eqx.filter_jit
def _camera_points(camera, eops, points):
    def one(eop, point):
        p = jaxba.opk_to_matrix(eop[3:]) @ (point - eop[:3])
        g = lambda m: m - camera.image_point(p, m, 0.0)  # noqa: E731
        m = camera.image_point(p, jnp.zeros(2), 0.0)
        return jax.lax.fori_loop(
            0, 8, lambda _, m: m - jnp.linalg.solve(jax.jacfwd(g)(m), g(m)), m)

    return jax.vmap(one)(eops, points)


def camera_points(camera, eops, points):
    """Measured image points (n, 2) of `points` (n, 3) in images `eops` (n, 6) through the
    camera model: m = image_point(M (X - X0), m, 0), solved by Newton's method (the
    photogrammetric models evaluate their corrections at m)."""
    camera = jax.tree.map(jnp.asarray, camera)
    return np.asarray(_camera_points(camera, jnp.asarray(eops), jnp.asarray(points)))


# One program each (op by op, a rotation per image and point compiled and ran ~4,000 times).
_opk_to_matrices = jax.jit(jax.vmap(jaxba.opk_to_matrix))
_matrices_to_opk = jax.jit(jax.vmap(jaxba.matrix_to_opk))


def camera_frame(eops, points):
    """p = M (X - X0) (n, 3) of points (n, 3) in images (n, 6)."""
    m = np.asarray(_opk_to_matrices(jnp.asarray(eops[:, 3:])))
    return np.einsum("nij,nj->ni", m, points - eops[:, :3])


def observe(camera, eops, points, inside, rng, noise):
    """Observation rows (image, point, x, y) of every point in front of every image whose
    measurement `inside(xy)` accepts, with N(0, noise²) added."""
    rows = []
    for i, eop in enumerate(eops):
        front = np.flatnonzero(camera_frame(np.repeat(eop[None], len(points), 0), points)[:, 2]
                               < 0)
        xy = camera_points(camera, np.repeat(eop[None], len(front), 0), points[front])
        keep = inside(xy)
        xy = xy[keep] + rng.normal(0.0, noise, (int(np.sum(keep)), 2))
        rows.append(np.c_[np.full(len(xy), i), front[keep], xy])
    return np.concatenate(rows)


def similarity_misfit(result, eops, points):
    """RMS point misfit and largest station / angle misfit of `result` after the best 3D
    similarity onto the truth."""
    ok = result.initialised_points
    similarity = jaxba.absolute_orientation(result.points[ok], points[ok])
    moved = similarity.transform_eops(result.eops[result.initialised_images])
    truth = eops[result.initialised_images]
    return (np.sqrt(np.mean(similarity.residuals**2)),
            np.max(np.abs(moved[:, :3] - truth[:, :3])),
            np.max(np.abs(wrap(moved[:, 3:] - truth[:, 3:]))))


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The lab replica (18 convergent images, 80 targets, 0.3 px noise), its project, image
    points as rows, true EOPs (radians) and points, and the true camera per image."""
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("lab"), seed=21,
                                          noise_px=0.3)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    rows = [np.c_[np.asarray(g.image), np.asarray(g.point), np.asarray(g.measured)]
            for g in project.problem.groups if isinstance(g, ImagePoints)]
    eops = np.array([np.r_[truth.images[i][:3], np.radians(truth.images[i][3:])]
                     for i in project.image_ids])
    points = np.array([truth.points[p] for p in project.point_ids])
    cameras = {cid: jaxba.SmacCamera.from_parameters(
        jnp.array([iop[name] for name in IOP_NAMES])) for cid, iop in truth.cameras.items()}
    per_image = [cameras[project.spec.images[i].camera] for i in project.image_ids]
    return project, np.concatenate(rows), eops, points, per_image


@pytest.fixture(scope="module")
def lab_free(lab):
    _, observations, _, _, cameras = lab
    return jaxba.initialise_block(observations, cameras, seed=1)


# -- rays -----------------------------------------------------------------------------------


CAMERAS = {
    "smac": jaxba.SmacCamera.from_parameters(jnp.array(
        [0.012, -0.008, 8.52, 0.0, -8.0e-4, 3.0e-6, -1.0e-8, 2.0e-5, -1.5e-5, 0.0, 1e-4, -2e-4])),
    "opencv": jaxba.OpenCVCamera(2300.0, 2310.0, 2999.5, 1999.5, 0.4, -0.12, 0.05, 1e-3, -5e-4,
                                 0.01),
    "fisheye": jaxba.FisheyeCamera(800.0, 805.0, 1000.0, 800.0, 0.02, -0.01, 0.003, -0.001),
    "bal": jaxba.BalCamera(1500.0, -0.05, 0.01),
    "photomodeler": jaxba.PhotoModelerCamera(0.01, -0.02, 8.5, 1e-3, -2e-6, 0.0, 1e-5, -1e-5,
                                             1e-4, 2e-4),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_ideal_coordinates_are_the_rays_of_every_camera_model(name):
    camera = CAMERAS[name]
    rng = np.random.default_rng(4)
    rays = rng.uniform(-0.6, 0.6, (200, 2))
    p = np.c_[rays, -np.ones(200)] * rng.uniform(1.0, 5.0, (200, 1))
    measured = camera_points(camera, np.c_[np.zeros((200, 6))], p)
    ideal = jaxba.ideal_coordinates(camera, measured)
    assert np.all(ideal.converged)
    np.testing.assert_allclose(ideal.normalised, rays, atol=1e-11)
    focal = {"smac": 8.52, "opencv": 2305.0, "fisheye": 802.0, "bal": 1500.0,
             "photomodeler": 8.5}[name]
    assert np.median(ideal.scale) == pytest.approx(focal, rel=0.25)
    # ... and the residuals of those rays through the camera vanish.
    points = np.c_[rays, -np.ones(200)]
    v = jaxba.image_residuals(camera, np.zeros((200, 6)), points, measured)
    np.testing.assert_allclose(v, 0.0, atol=1e-9 * focal)


# -- blocks ---------------------------------------------------------------------------------


def test_free_block_equals_the_truth_up_to_a_similarity(lab, lab_free):
    _, observations, eops, points, _ = lab
    result = lab_free
    print("\n".join(result.log))
    assert result.frame == "model" and result.similarity is None
    assert np.all(result.initialised_images) and np.all(result.initialised_points)
    assert not result.failed_images and not result.failed_points
    assert sorted(set(result.image_method)) == ["relative orientation", "resection"]
    assert result.image_method.count("relative orientation") == 2
    assert set(result.point_method) == {"intersection"}
    # The first image of the pair defines the model: at the origin, M = I.
    first = result.image_method.index("relative orientation")
    np.testing.assert_allclose(result.eops[first], 0.0, atol=1e-12)
    rms, station, angle = similarity_misfit(result, eops, points)
    # 0.3 px noise: about 0.1 mm in object space at 2.3 m.
    assert rms < 3e-4 and station < 3e-3 and angle < 1e-3, (rms, station, angle)
    assert np.mean(result.blunders) < 0.005
    assert np.nanmedian(result.sigma) == pytest.approx(0.3 * 0.00369, rel=0.3)


def test_an_adjustment_from_the_initialisation_reaches_the_truths_optimum(lab, lab_free):
    project, _, eops, points, _ = lab
    problem = project.problem
    similarity = jaxba.absolute_orientation(lab_free.points, points)

    def started(images, xyz):
        initial = eqx.tree_at(lambda p: (p.images, p.points), problem.initial,
                              (jnp.asarray(images), jnp.asarray(xyz)))
        return eqx.tree_at(lambda p: p.initial, problem, problem.with_free(initial))

    from_truth = jaxba.adjust(started(eops, points))
    from_init = jaxba.adjust(started(similarity.transform_eops(lab_free.eops),
                                     similarity.transform(lab_free.points)))
    assert from_truth.converged and from_init.converged
    assert from_init.sigma0 == pytest.approx(from_truth.sigma0, rel=1e-8)
    for a, b in zip(jax.tree.leaves(from_init.parameters), jax.tree.leaves(from_truth.parameters)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-8)


def test_control_points_put_the_block_in_their_frame(lab):
    _, observations, eops, points, cameras = lab
    control = np.full(points.shape, np.nan)
    chosen = [3, 17, 30, 44, 58, 71]
    control[chosen] = points[chosen]
    control[5, 2] = points[5, 2]  # a height point
    result = jaxba.initialise_block(observations, cameras, control=control, seed=2)
    print("\n".join(result.log))
    assert result.frame == "control"
    assert "control resection" in result.image_method
    assert all(result.point_method[p] == "control" for p in chosen)
    np.testing.assert_allclose(result.points[chosen], points[chosen])
    assert result.points[5, 2] == points[5, 2]
    np.testing.assert_allclose(result.points, points, atol=1.5e-3)
    np.testing.assert_allclose(result.eops[:, :3], eops[:, :3], atol=5e-3)
    np.testing.assert_allclose(wrap(result.eops[:, 3:] - eops[:, 3:]), 0.0, atol=2e-3)


def test_given_eops_and_distances_set_frame_and_scale(lab):
    _, observations, eops, points, cameras = lab
    given = np.full(eops.shape, np.nan)
    given[[0, 7, 12]] = eops[[0, 7, 12]]
    result = jaxba.initialise_block(observations, cameras, eops=given, seed=3)
    assert result.frame == "control"
    assert [result.image_method[i] for i in (0, 7, 12)] == ["given"] * 3
    np.testing.assert_array_equal(result.eops[[0, 7, 12]], eops[[0, 7, 12]])
    np.testing.assert_allclose(result.points, points, atol=2e-3)
    # No control, no EOPs: distances give the scale, the first image the rest of the datum.
    distances = np.array([[0, 79, np.linalg.norm(points[0] - points[79])],
                          [10, 60, np.linalg.norm(points[10] - points[60])]])
    scaled = jaxba.initialise_block(observations, cameras, distances=distances, seed=3)
    assert scaled.frame == "model" and scaled.similarity is not None
    similarity = jaxba.absolute_orientation(scaled.points, points)
    assert similarity.scale == pytest.approx(1.0, abs=1e-3)


def test_an_opencv_pixel_camera_block():
    """A convergent block measured in pixels with OpenCV's forward distortion."""
    rng = np.random.default_rng(7)
    points = make_targets(rng, 60)
    stations, matrices = make_stations(rng, 10, 1)
    eops = np.c_[stations, np.asarray(_matrices_to_opk(jnp.asarray(matrices)))]
    camera = jaxba.OpenCVCamera(2300.0, 2300.0, 2999.5, 1999.5, 0.0, -0.1, 0.05, 2e-4, -1e-4,
                                0.0)
    inside = lambda xy: np.all((xy >= 20) & (xy <= [5979, 3979]), axis=1)  # noqa: E731
    observations = observe(camera, eops, points, inside, rng, 0.3)
    result = jaxba.initialise_block(observations, [camera] * 10, seed=4)
    print("\n".join(result.log))
    assert np.all(result.initialised_images) and np.all(result.initialised_points)
    rms, station, angle = similarity_misfit(result, eops, points)
    assert rms < 3e-4 and station < 3e-3 and angle < 1e-3, (rms, station, angle)
    assert np.nanmedian(result.sigma) == pytest.approx(0.3, rel=0.3)  # pixels


def test_blunders_are_flagged_and_do_not_spoil_the_block(lab):
    _, observations, eops, points, cameras = lab
    rng = np.random.default_rng(5)
    bad = rng.choice(len(observations), len(observations) // 20, replace=False)
    direction = rng.normal(size=(len(bad), 2))
    size = rng.uniform(10.0, 60.0, len(bad)) * 0.00369  # 10 to 60 px, in mm
    spoilt = observations.copy()
    spoilt[bad, 2:] += direction / np.linalg.norm(direction, axis=1, keepdims=True) * size[:, None]
    # The true cameras: no distortion is unknown, every misfit beyond the noise is evidence.
    result = jaxba.initialise_block(spoilt, cameras, seed=6, unknown_distortion=0.0)
    print("\n".join(result.log))
    assert np.all(result.initialised_images) and np.all(result.initialised_points)
    rms, station, angle = similarity_misfit(result, eops, points)
    assert rms < 5e-4 and station < 5e-3 and angle < 2e-3, (rms, station, angle)
    flagged = np.flatnonzero(result.blunders)
    assert len(np.intersect1d(flagged, bad)) >= 0.9 * len(bad)
    assert len(np.setdiff1d(flagged, bad)) <= 0.01 * len(observations)
    # Cameras taken as approximate (the default): what an unknown distortion may leave is
    # allowed (up to 54 px at the corner), so fewer are flagged, and no clean one.
    allowing = np.flatnonzero(jaxba.initialise_block(spoilt, cameras, seed=6).blunders)
    assert 0 < len(allowing) < len(flagged) and np.all(np.isin(allowing, bad))


def aerial_block(rng):
    """Two strips of six vertical images (1:10,000, c = 100 mm, 60 % forward and 30 % side
    overlap, the second strip flown back) over flat terrain (relief ±15 m at 1,000 m)."""
    camera = jaxba.SmacCamera.from_parameters(jnp.array(
        [0.01, -0.02, 100.0, 0.0, -2e-7, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.0]))
    stations, attitudes = [], []
    for strip, (y, kappa) in enumerate([(0.0, 0.0), (420.0, np.pi)]):
        for k in range(6):
            x = 240.0 * (k if strip == 0 else 5 - k)
            stations.append([x, y, 1000.0] + rng.normal(0.0, 5.0, 3))
            attitudes.append(np.r_[rng.normal(0.0, np.radians(1.5), 2), kappa])
    eops = np.c_[np.array(stations), np.array(attitudes)]
    xy = rng.uniform([-250.0, -250.0], [1450.0, 670.0], (300, 2))
    z = 10.0 * np.sin(xy[:, 0] / 300.0) + 5.0 * np.cos(xy[:, 1] / 200.0)
    points = np.c_[xy, z]
    inside = lambda m: np.all(np.abs(m) <= 29.0, axis=1)  # noqa: E731
    return camera, eops, points, observe(camera, eops, points, inside, rng, 0.003)


def test_a_vertical_aerial_block_over_flat_terrain():
    rng = np.random.default_rng(8)
    camera, eops, points, observations = aerial_block(rng)
    seen = np.bincount(observations[:, 1].astype(int), minlength=len(points))
    # Five control points (corners and centre) put the block in their frame.
    control = np.full(points.shape, np.nan)
    corners = [(-100, -150), (1300, -150), (-100, 570), (1300, 570), (600, 200)]
    chosen = [int(np.argmin(np.where(seen >= 2, np.linalg.norm(points[:, :2] - c, axis=1),
                                     np.inf))) for c in corners]
    control[chosen] = points[chosen]
    result = jaxba.initialise_block(observations, [camera] * len(eops), control=control,
                                    seed=7)
    print("\n".join(result.log))
    assert result.frame == "control" and result.similarity is not None
    assert np.all(result.initialised_images)
    assert not np.any(result.initialised_points[seen < 2])
    assert np.mean(result.initialised_points[seen >= 2]) > 0.95
    assert all("1 image" in result.failed_points[p] for p in np.flatnonzero(seen == 1))
    # A weak block (2.4 rays a point, 0.3 px noise): the sequence of orientations and
    # intersections leaves decimetres at 1,000 m (a bundle adjustment takes it from there).
    ok = result.initialised_points
    errors = np.linalg.norm(result.points[ok] - points[ok], axis=1)
    assert np.sqrt(np.mean(errors**2)) < 0.6 and np.max(errors) < 2.5
    assert np.max(np.abs(result.eops[:, :3] - eops[:, :3])) < 3.0
    assert np.max(np.abs(wrap(result.eops[:, 3:] - eops[:, 3:]))) < 3e-3


def test_what_cannot_be_initialised_is_reported(lab):
    _, observations, _, points, cameras = lab
    n_points = len(points)
    rows = observations[observations[:, 0] == 3][:3].copy()
    rows[:, 0] = 18  # a new image with 3 points only
    lonely = np.array([[5, n_points, 1.0, 2.0]])  # a new point seen once
    extra = np.r_[observations, rows, lonely]
    result = jaxba.initialise_block(extra, [*cameras, cameras[0]], seed=8)
    print("\n".join(result.log))
    assert set(result.failed_images) == {18}
    assert "3 usable image points" in result.failed_images[18]
    assert np.all(np.isnan(result.eops[18])) and result.image_method[18] is None
    assert set(result.failed_points) == {n_points}
    assert "1 image" in result.failed_points[n_points]
    assert np.all(np.isnan(result.points[n_points]))
    assert np.all(result.initialised_images[:18]) and np.all(result.initialised_points[:-1])
    assert any("not initialised" in line for line in result.log)


def test_nothing_to_orient_is_reported_not_raised():
    camera = CAMERAS["smac"]
    observations = np.array([[0, 0, 0.1, 0.2], [1, 0, 0.3, 0.1], [1, 1, 0.0, 0.0]])
    result = jaxba.initialise_block(observations, [camera, camera], seed=0)
    assert not np.any(result.initialised_images) and not np.any(result.initialised_points)
    assert set(result.failed_images) == {0, 1} and set(result.failed_points) == {0, 1}
    # Two images from one station: no base, nothing to intersect.
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (30, 3)) + [0.0, 0.0, -10.0]
    xy = camera_points(camera, np.zeros((30, 6)), points)
    rows = np.r_[np.c_[np.zeros(30), np.arange(30), xy],
                 np.c_[np.ones(30), np.arange(30), xy + rng.normal(0.0, 1e-3, xy.shape)]]
    result = jaxba.initialise_block(rows, [camera, camera], seed=0)
    assert not np.any(result.initialised_images) and len(result.failed_points) == 30
    assert any("too short a base" in line for line in result.log)
    with pytest.raises(ValueError, match="shape"):
        jaxba.initialise_block(observations[:, :3], [camera, camera])
    with pytest.raises(ValueError, match="eops"):
        jaxba.initialise_block(observations, [camera, camera], eops=np.zeros((3, 6)))
    with pytest.raises(ValueError, match="distances"):
        jaxba.initialise_block(observations, [camera, camera], distances=[[0, 5, 1.0]])
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="float64"):
            jaxba.initialise_block(observations, [camera, camera])
    assert {"initialise_block", "BlockInitialisation", "ideal_coordinates"} <= set(jaxba.__all__)


def test_partial_control_and_the_lab_datum(lab):
    """Fewer than 3 full control points: heights and single coordinates still set the frame
    (`absolute_orientation` cannot start there); the lab's minimal datum (6 coordinates and
    distances) fits several rotations, which the log says."""
    _, observations, _, points, cameras = lab
    control = np.full(points.shape, np.nan)
    control[[0, 79]] = points[[0, 79]]
    control[[5, 40, 60], 2] = points[[5, 40, 60], 2]
    result = jaxba.initialise_block(observations, cameras, control=control, seed=9)
    assert result.frame == "control"
    assert any("similarity onto 9 control coordinates" in line for line in result.log)
    np.testing.assert_allclose(result.points, points, atol=2e-3)
    a, b, c = datum_targets(points)
    lab_datum = np.full(points.shape, np.nan)
    lab_datum[a], lab_datum[b, 1:], lab_datum[c, 2] = points[a], points[b, 1:], points[c, 2]
    distances = np.array([[i, j, np.linalg.norm(points[i] - points[j])]
                          for i, j in distance_pairs(points, 4)])
    minimal = jaxba.initialise_block(observations, cameras, control=lab_datum,
                                     distances=distances, seed=9)
    assert minimal.frame == "control"
    assert any("4 distinct rotations" in line for line in minimal.log)
    np.testing.assert_allclose(minimal.points[[a, b, c]][[0, 1, 1, 2], [0, 1, 2, 2]],
                               points[[a, b, c]][[0, 1, 1, 2], [0, 1, 2, 2]])
