"""Tests of the pure-NumPy synthetic block generator `jaxba._io._synthetic` (no jax)."""

import math
import tomllib

import numpy as np
import pytest

from jaxba._io import _synthetic as syn

ROTATION_TOL = 1e-14
IMPLICIT_TOL_MM = 1e-12
FILE_TOL_MM = 1e-7  # image coordinates are written with 8 decimals, in mm or pixels


def element_matrix(omega, phi, kappa):
    """M from the element formulas of CONVENTIONS.md (radians)."""
    so, co, sp, cp, sk, ck = (f(a) for a in (omega, phi, kappa) for f in (math.sin, math.cos))
    return np.array(
        [
            [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
            [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
            [sp, -so * cp, co * cp],
        ]
    )


def read_table(path):
    """Data rows of a text table as lists of strings."""
    lines = (line.split("#", 1)[0].split() for line in path.read_text().splitlines())
    return [fields for fields in lines if fields]


def image_points(directory):
    """{(image_id, point_id): (x, y)} from image_coordinates.txt."""
    return {
        (r[0], r[1]): np.array([float(r[2]), float(r[3])])
        for r in read_table(directory / "image_coordinates.txt")
    }


@pytest.fixture(scope="module")
def noise_free(tmp_path_factory):
    directory = tmp_path_factory.mktemp("noise_free")
    truth = syn.write_synthetic_project(
        directory, seed=3, noise_px=0.0, distance_sigma=0.0, approx_error=(0.0, 0.0, 0.0)
    )
    return directory, truth


def test_rotation_matches_conventions_and_is_a_rotation():
    rng = np.random.default_rng(0)
    for omega, phi, kappa in rng.uniform(-1.5, 1.5, (20, 3)) * [2.0, 1.0, 2.0]:
        m = syn.rotation_matrix(omega, phi, kappa)
        np.testing.assert_allclose(m, element_matrix(omega, phi, kappa), atol=ROTATION_TOL)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=ROTATION_TOL)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=ROTATION_TOL)
        np.testing.assert_allclose(syn.opk_from_rotation(m), (omega, phi, kappa), atol=1e-12)


def test_look_at_points_minus_z_at_the_target():
    station, target = np.array([0.5, 1.0, 3.5]), np.array([2.0, 1.5, 0.3])
    kappa0 = syn.opk_from_rotation(syn.look_at(station, target, 0.0))[2]
    for roll in np.radians([0.0, 90.0, 180.0, 270.0]):
        m = syn.look_at(station, target, roll)
        uvw = m @ (target - station)
        np.testing.assert_allclose(uvw[:2], 0.0, atol=1e-12)
        assert uvw[2] < 0
        # a roll adds to kappa
        assert math.remainder(
            syn.opk_from_rotation(m)[2] - kappa0 - roll, 2 * math.pi
        ) == pytest.approx(0, abs=1e-12)
    # roll 0: the object Y axis (up) maps to image +y
    assert (syn.look_at(station, target, 0.0) @ [0.0, 1.0, 0.0])[1] > 0.9


@pytest.mark.parametrize(
    "camera",
    [syn.DEFAULT_CAMERA, syn.DEFAULT_CAMERA | {"K0": 1e-4, "P3": 2e-3, "A1": 3e-4, "A2": -2e-4}],
)
def test_measured_coordinates_solve_the_implicit_equation(camera):
    # Over the whole format, corners included (there |d dist/dx| > 1 for the default lens).
    half = np.array(syn.SENSOR) / 2 * np.array(syn.PIXEL_SIZE)
    grid = np.stack(np.meshgrid(*(np.linspace(-h, h, 15) for h in half)), axis=-1).reshape(-1, 2)
    dist = np.stack(syn.smac_correction(grid[:, 0], grid[:, 1], camera), axis=-1)
    ideal = grid - dist  # the ideal points that the grid points are the measurements of
    solved = syn.solve_measured(ideal, camera)
    residual = (
        solved - ideal - np.stack(syn.smac_correction(solved[:, 0], solved[:, 1], camera), axis=-1)
    )
    assert np.abs(residual).max() < IMPLICIT_TOL_MM
    np.testing.assert_allclose(solved, grid, atol=1e-9)


def test_written_measurements_follow_the_collinearity_equations(noise_free):
    directory, truth = noise_free
    camera = truth.cameras["C1"]
    for (iid, pid), (x, y) in image_points(directory).items():
        x0, y0, z0, omega, phi, kappa = truth.images[iid]
        u, v, w = element_matrix(*np.radians([omega, phi, kappa])) @ (
            np.array(truth.points[pid]) - [x0, y0, z0]
        )
        dx, dy = syn.smac_correction(x - camera["xp"], y - camera["yp"], camera)
        assert w < 0
        assert x == pytest.approx(camera["xp"] - camera["c"] * u / w + dx, abs=FILE_TOL_MM)
        assert y == pytest.approx(camera["yp"] - camera["c"] * v / w + dy, abs=FILE_TOL_MM)


def test_coverage(noise_free):
    directory, truth = noise_free
    observations = image_points(directory)
    per_image = {iid: sum(key[0] == iid for key in observations) for iid in truth.images}
    per_point = {pid: sum(key[1] == pid for key in observations) for pid in truth.points}
    assert len(per_image) == 18 and min(per_image.values()) >= 25
    assert len(per_point) == 80 and min(per_point.values()) >= 3
    half = (np.array(syn.SENSOR) / 2 - syn.MARGIN_PX) * np.array(syn.PIXEL_SIZE)
    assert np.all(np.abs(np.array(list(observations.values()))) <= half + FILE_TOL_MM)
    kappas = {round(truth.images[iid][5] / 90.0) % 4 for iid in truth.images}
    assert kappas == {0, 1, 2, 3}
    depths = np.array(list(truth.points.values()))[:, 2]
    assert depths.min() >= 0.0 and depths.max() > 0.5


def test_project_files(noise_free):
    directory, truth = noise_free
    project = tomllib.loads(truth.project_file.read_text())
    assert project["project"] == {"name": "lab", "image_units": "mm"}
    assert project["adjustment"]["image_sigma"] == pytest.approx(0.25 * syn.PIXEL_SIZE[0])
    assert all((directory / path).exists() for path in project["files"].values())
    cameras = tomllib.loads((directory / "cameras.toml").read_text())
    assert cameras["C1"]["c"] == 8.5 and cameras["C1"]["K1"] == 0.0
    assert cameras["C1"]["free"] == ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]
    # Datum: six coordinates of three points fixed at their true values.
    points = read_table(directory / "ground_points.txt")
    fixed = [(r[0], k) for r in points for k in range(3) if r[4 + k] == "0"]
    assert len(fixed) == 6 and sorted(k for _, k in fixed) == [0, 1, 1, 2, 2, 2]
    rows = {r[0]: r for r in points}
    for pid, k in fixed:
        assert float(rows[pid][1 + k]) == pytest.approx(truth.points[pid][k], abs=1e-9)
    # Noise-free distances equal the true ones; written sigma 0.
    for a, b, length, sigma in read_table(directory / "distances.txt"):
        true_length = np.linalg.norm(np.subtract(truth.points[a], truth.points[b]))
        assert float(length) == pytest.approx(true_length, abs=1e-9) and sigma == "0"
    # Zero approximation error: the approximate EOPs are the truth.
    for iid, cid, *eop in read_table(directory / "orientation.txt"):
        assert cid == "C1" and np.allclose(np.array(eop, dtype=float), truth.images[iid], atol=1e-8)


def test_pixel_units_round_trip(tmp_path, noise_free):
    directory, _ = noise_free
    truth = syn.write_synthetic_project(
        tmp_path,
        seed=3,
        noise_px=0.0,
        distance_sigma=0.0,
        approx_error=(0.0, 0.0, 0.0),
        image_units="pixel",
    )
    project = tomllib.loads(truth.project_file.read_text())
    assert (
        project["project"]["image_units"] == "pixel"
        and project["adjustment"]["image_sigma"] == 0.25
    )
    (ps_x, ps_y), (ncols, nrows) = syn.PIXEL_SIZE, syn.SENSOR
    in_mm = image_points(directory)
    for key, (col, row) in image_points(tmp_path).items():
        xy = ((col - (ncols - 1) / 2) * ps_x, ((nrows - 1) / 2 - row) * ps_y)  # CONVENTIONS.md
        np.testing.assert_allclose(xy, in_mm[key], atol=FILE_TOL_MM)
    xy = np.array([[0.0, 0.0], [1.0, -2.0]])
    expected = [[2999.5, 1999.5], [2999.5 + 1.0 / ps_x, 1999.5 + 2.0 / ps_y]]
    np.testing.assert_allclose(syn.image_to_pixel(xy, syn.PIXEL_SIZE, syn.SENSOR), expected)


def test_options(tmp_path):
    kwargs = dict(seed=5, n_images=12, n_targets=40, n_distances=0, datum="none")
    truth = syn.write_synthetic_project(
        tmp_path / "options",
        **kwargs,
        n_cameras=2,
        camera_noise_px=[0.25, 1.0],
        blunders=[("img03", "7", 1, 0.05)],
        gnss_sigma=(0.01, 0.05),
    )
    assert sorted(truth.cameras) == ["C1", "C2"] and truth.cameras["C1"] != truth.cameras["C2"]
    assert all(len(iop) == 12 for iop in truth.cameras.values())
    assert "distances" not in tomllib.loads(truth.project_file.read_text())["files"]
    images = read_table(tmp_path / "options" / "orientation.txt")
    assert [r[1] for r in images[:4]] == ["C1", "C2", "C1", "C2"]
    assert all(len(r) == 14 and r[8:] == ["0.01"] * 3 + ["0.05"] * 3 for r in images)
    assert all(
        r[4:] == ["-", "-", "-"] for r in read_table(tmp_path / "options" / "ground_points.txt")
    )
    # Same seed, one camera noise the same: the blunder shows as the exact difference in y.
    with_blunder = image_points(tmp_path / "options")
    syn.write_synthetic_project(
        tmp_path / "no_blunder", **kwargs, n_cameras=2, camera_noise_px=[0.25, 1.0]
    )
    difference = (
        with_blunder[("img03", "7")] - image_points(tmp_path / "no_blunder")[("img03", "7")]
    )
    np.testing.assert_allclose(difference, [0.0, 0.05], atol=FILE_TOL_MM)
    with pytest.raises(ValueError, match="does not observe"):
        syn.write_synthetic_project(tmp_path / "bad", **kwargs, blunders=[("img01", "999", 0, 0.1)])
    with pytest.raises(ValueError, match="unknown IOPs"):
        syn.write_synthetic_project(tmp_path / "bad", **kwargs, camera={"c": 8.5, "K9": 1.0})


def test_close_range_block_is_as_unkind_as_a_real_one(tmp_path):
    """3-5 % of the points under 2° or on 2 rays, 20-40 px of radial distortion at the
    corner, two images with few points, rolled images; the truth reprojects to the file."""
    from jaxba._io import _close_range as cr

    truth = cr.write_close_range_project(tmp_path, seed=1, n_images=12, n_points=400)
    rows = read_table(tmp_path / "image_coordinates.txt")
    image_ids = list(truth.images)
    views: dict[str, list[int]] = {}
    for image_id, point_id, *_ in rows:
        views.setdefault(point_id, []).append(image_ids.index(image_id))
    stations = np.array([truth.images[i][:3] for i in image_ids])
    points = np.array([truth.points[p] for p in views])
    angles = cr.intersection_angles(points, stations, [np.array(v) for v in views.values()])
    rays = np.array([len(v) for v in views.values()])
    weak = np.mean((angles < 2.0) | (rays == 2))
    assert 0.03 <= weak <= 0.05
    assert 20 <= abs(cr.corner_distortion_px(cr.CAMERA)) <= 40
    per_image = np.bincount([image_ids.index(r[0]) for r in rows], minlength=len(image_ids))
    assert np.sort(per_image)[:2].max() <= 15 and np.sort(per_image)[2] > 100
    kappas = np.array([truth.images[i][5] for i in image_ids])
    assert np.ptp(np.round(kappas / 90.0) % 4) > 0  # rolled by multiples of 90°
    image_id, point_id, x, y = rows[0]
    k = image_ids.index(image_id)
    m = syn.rotation_matrix(*np.radians(truth.images[image_id][3:]))
    _, xy = syn.observe(np.array([truth.points[point_id]]), stations[k], m, cr.CAMERA)
    assert np.abs(xy[0] - [float(x), float(y)]).max() < 5 * cr.NOISE_PX * syn.PIXEL_SIZE[0]
