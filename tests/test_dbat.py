"""DBAT's camera-calibration demo: the importer, `PhotoModelerCamera`, DBAT's published result.

Reference: DBAT 0.9.2.0's own run of data/script/camcaldemo (tests/data/dbat_camcal/result/:
report.txt, c4040z.xml, camera_stations.txt, top_residuals.txt; SOURCES.md there).
"""

import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_ATOL, FD_RTOL, FORMULA_RTOL, assert_jacobian_matches_fd

import jaxba
from jaxba._io import write_dbat_project
from jaxba._io._dbat import (
    jaxba_pixels,
    read_cameras,
    read_control_points,
    read_mark_points,
)
from jaxba._models._cameras import PhotoModelerCamera

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "dbat_camcal"
SCRIPT = DATA / "camcaldemo.xml"
CONFIG = ROOT / "configs" / "dbat_camcal.toml"
CONFIG_TABLES = ("cameras.toml", "orientation.txt", "image_coordinates.txt", "points.txt")

# DBAT's result: values from result/c4040z.xml (full precision), σ from result/report.txt.
# DBAT's camera file writes the aspect as 1 - as; its principal point is measured from the
# top-left image corner, y down (mapped with DbatCamera.principal_point_from_dbat).
DBAT_ASPECT_FILE = 0.999610402322309577
DBAT = {
    "xp": (3.61546239970888994, 0.00082),
    "yp": (2.61329279848268081, 0.00098),
    "c": (7.45699532273933752, 0.00105),
    "K1": (0.00458860662755811253, 2.21e-5),
    "K2": (-4.51350997187018702e-05, 2.65e-6),
    "K3": (-2.05253370760761127e-06, 1.01e-7),
    "P1": (-6.12803065099492536e-05, 3.52e-6),
    "P2": (-4.41170561685059337e-05, 3.94e-6),
    "aspect": (1 - DBAT_ASPECT_FILE, 2.08e-5),
}
DBAT_SIGMA0 = 1.6148
DBAT_REDUNDANCY = 3725
DBAT_K2_K3_CORRELATION = -0.979
DBAT_POINT_RMS_PX = 0.216  # "Overall point RMS", pixels

# Tolerances (the "done when" and the printed precision of DBAT's report).
SIGMA0_RTOL = 0.003
C_ATOL = 0.0002  # mm
STD_RTOL = 0.05  # every σ against DBAT's three printed digits
WITHIN_SIGMAS = 0.2  # estimates against DBAT's, in units of DBAT's σ
CORRELATION_ATOL = 0.001  # report prints -97.9 %
POINT_RMS_ATOL = 0.0005  # px, report prints 0.216
RESIDUAL_ATOL_PX = 2e-6  # top_residuals.txt prints six significant digits (≤ 1)
START_POSITION_ATOL = 0.1  # m: resection without distortion against DBAT's adjusted stations
START_ANGLE_ATOL = 5.0  # degrees, rotation between starting and adjusted attitude

N_IMAGES, N_IMAGE_POINTS, N_POINTS, N_CONTROL = 21, 2074, 100, 4
N_OBSERVATIONS, N_UNKNOWNS = 4148, 423  # DBAT's report: 9 IO, 126 EO, 288 OP

PM_PARAMETER_NAMES = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect", "skew")
# Every term nonzero and larger than DBAT's estimates, so each one matters in the checks.
PM_IOP = np.array([-0.0096, 0.1055, 7.457, 4.6e-3, -4.5e-5, -2.1e-6, -6.1e-5, -4.4e-5,
                   3.9e-4, 2.0e-4])
PM_EOP = np.array([0.455, 1.794, 1.468, -0.6879, -0.0207, -3.1388])  # DBAT's photo 1
PM_POINT = np.array([0.3, 0.6, 0.0])
PM_MEASURED = np.array([-1.23, 2.17])  # mm
PM_SIGMA = np.array([0.00032, 0.00032])  # mm


def _rows(path):
    lines = (line.split("#", 1)[0].split() for line in path.read_text().splitlines())
    return [fields for fields in lines if fields]


def _camera():
    return read_cameras(DATA / "c4040z.xml")[0]


def _dbat_stations():
    """DBAT's adjusted EOPs: image id -> (X0, Y0, Z0 m, omega, phi, kappa rad, then 6 σ).

    camera_stations.txt writes all six σ converted "to degrees": the σ of X0, Y0, Z0 are
    metres × 180/π there (report.txt prints them in metres: photo 1 σX0 0.000155).
    """
    table = np.loadtxt(DATA / "result" / "camera_stations.txt", delimiter=",",
                       usecols=range(14), comments="#")
    labels = [line.rsplit(",", 1)[1].strip()
              for line in (DATA / "result" / "camera_stations.txt").read_text().splitlines()
              if line and not line.startswith("#")]
    return {label.rsplit(".", 1)[0]: row[2:] for label, row in zip(labels, table)}


def _dbat_iop():
    """DBAT's adjusted camera as a PhotoModelerCamera parameter vector (jaxba frame)."""
    xp, yp = _camera().principal_point_from_dbat(DBAT["xp"][0], DBAT["yp"][0])
    values = {name: value for name, (value, _) in DBAT.items()} | {"xp": xp, "yp": yp}
    return np.array([values.get(name, 0.0) for name in PM_PARAMETER_NAMES])


@functools.partial(jax.jit, static_argnums=0)
def _residual(model, iop, eop, point, measured, sigma, refraction):
    return jaxba.advanced.collinearity_residual(model, iop, eop, point, measured, sigma, refraction)


# --------------------------------------------------------------------------- importer


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The project written from tests/data into a temporary copy of configs/'s layout."""
    base = tmp_path_factory.mktemp("configs")
    result = write_dbat_project(SCRIPT, base / "dbat_camcal",
                                project_file=base / "dbat_camcal.toml")
    return base, result


def test_importer_counts(written):
    base, result = written
    directory = base / "dbat_camcal"
    assert len(_rows(directory / "orientation.txt")) == N_IMAGES == len(result.images)
    assert len(_rows(directory / "image_coordinates.txt")) == N_IMAGE_POINTS
    assert 2 * result.n_image_points == N_OBSERVATIONS
    points = _rows(directory / "points.txt")
    assert len(points) == N_POINTS == result.n_points
    assert sum(row[4:7] == ["0", "0", "0"] for row in points) == N_CONTROL
    assert sum(row[4:7] == ["-", "-", "-"] for row in points) == N_POINTS - N_CONTROL


def test_importer_problem_size(written):
    base, _ = written
    spec = jaxba.read_project(base / "dbat_camcal.toml")
    problem = jaxba.build_project(spec).problem
    assert len(spec.images) == N_IMAGES and len(spec.points) == N_POINTS
    assert problem.n_observations() == N_OBSERVATIONS
    assert problem.n_unknowns() == N_UNKNOWNS
    assert problem.n_observations() - problem.n_unknowns() == DBAT_REDUNDANCY


def test_importer_camera(written):
    base, _ = written
    spec = jaxba.read_project(base / "dbat_camcal.toml")
    (camera,) = spec.cameras.values()
    assert camera.model == "photomodeler"
    assert camera.pixel_size == (5.43764 / 1704, 5.43764 / 1704)
    assert camera.sensor == (2272, 1704)
    assert camera.values["c"] == 7.5 and camera.values["xp"] == camera.values["yp"] == 0.0
    assert camera.free == frozenset(PM_PARAMETER_NAMES) - {"skew"}


def test_importer_pixels_shifted_to_jaxba_origin(written):
    """Image points = DBAT's mark points - 0.5 px (corner origin -> pixel-centre origin)."""
    base, _ = written
    rows = _rows(base / "dbat_camcal" / "image_coordinates.txt")
    marks = read_mark_points(DATA / "measurements" / "markpts.txt")
    names = {f"{n}": f"P82500{20 + n}" for n in range(1, N_IMAGES + 1)}
    assert [(r[0], r[1]) for r in rows] == [(names[m.image], m.point) for m in marks]
    got = np.array([[float(v) for v in r[2:6]] for r in rows])
    expected = np.array([[m.col - 0.5, m.row - 0.5, *m.sigma] for m in marks])
    np.testing.assert_array_equal(got, expected)


def test_importer_weighted_control(tmp_path):
    write_dbat_project(SCRIPT, tmp_path, control_file="reference/camcal-weighted.txt")
    points = {row[0]: row for row in _rows(tmp_path / "points.txt")}
    for pid in ("1001", "1002", "1003", "1004"):
        assert points[pid][4:7] == ["0.001", "0.001", "0.001"]
    problem = jaxba.build_project(jaxba.read_project(tmp_path / "dbat_camcal.toml")).problem
    assert problem.n_observations() == N_OBSERVATIONS + 3 * N_CONTROL
    assert problem.n_unknowns() == N_UNKNOWNS + 3 * N_CONTROL


def test_configs_match_a_fresh_import(written):
    """configs/dbat_camcal* is what configs/make_dbat_camcal.py writes from tests/data."""
    base, _ = written
    assert (base / "dbat_camcal.toml").read_text() == CONFIG.read_text()
    for name in CONFIG_TABLES:
        fresh = (base / "dbat_camcal" / name).read_text()
        assert fresh == (CONFIG.parent / "dbat_camcal" / name).read_text(), name


def test_control_points_read():
    fixed = read_control_points(DATA / "reference" / "camcal-fixed.txt", "id,label,x,y,z")
    assert {p.label: p.xyz for p in fixed.values()} == {
        "CP1": (0.0, 1.0, 0.0), "CP2": (1.0, 1.0, 0.0),
        "CP3": (0.0, 0.0, 0.0), "CP4": (1.0, 0.0, 0.0)}
    assert all(p.sigma == (0.0, 0.0, 0.0) for p in fixed.values())
    weighted = read_control_points(DATA / "reference" / "camcal-weighted.txt",
                                   "id, label, x, y, z, sxyz")
    assert all(p.sigma == (0.001, 0.001, 0.001) for p in weighted.values())


def test_principal_point_mapping():
    camera = _camera()
    ps = 5.43764 / 1704
    # DBAT's default principal point, the sensor centre, is jaxba's origin.
    np.testing.assert_allclose(camera.principal_point_from_dbat(2272 / 2 * ps, 1704 / 2 * ps),
                               (0.0, 0.0), atol=1e-15)
    xp, yp = camera.principal_point_from_dbat(3.6, 2.6)
    np.testing.assert_allclose((xp, yp), (3.6 - 1136 * ps, 852 * ps - 2.6), rtol=1e-15)
    np.testing.assert_allclose(camera.principal_point_to_dbat(xp, yp), (3.6, 2.6), rtol=1e-15)


def test_pixel_mapping_is_dbat_mm_shifted():
    """jaxba mm of a shifted mark point = DBAT's mm (pixel × size, y down) moved to the centre."""
    camera = _camera()
    grid = jaxba.PixelGrid(camera.pixel_size, camera.image_size)
    col, row = 1813.4284, 1266.2367
    x, y = np.asarray(grid.pixel_to_image(jnp.asarray(jaxba_pixels(col, row))))
    ps = camera.pixel_size[0]
    np.testing.assert_allclose((x, y), (col * ps - 1136 * ps, 852 * ps - row * ps), rtol=1e-13)


def test_starting_eops_near_dbat(written):
    """Planar resection (no distortion) lands near DBAT's adjusted stations."""
    _, result = written
    stations = _dbat_stations()
    for image_id, eop in result.images.items():
        dbat = stations[image_id]
        np.testing.assert_allclose(eop[:3], dbat[:3], atol=START_POSITION_ATOL)
        start = np.asarray(jaxba.opk_to_matrix(jnp.radians(jnp.asarray(eop[3:]))))
        final = np.asarray(jaxba.opk_to_matrix(jnp.asarray(dbat[3:6])))
        cos_angle = (np.trace(start @ final.T) - 1) / 2
        assert np.degrees(np.arccos(min(1.0, cos_angle))) < START_ANGLE_ATOL, image_id


# --------------------------------------------------------------------------- PhotoModelerCamera


def pm_image_point_np(iop, p_camera, measured, k):
    """The model of PhotoModelerCamera's docstring, written out again in NumPy."""
    xp, yp, c, k1, k2, k3, p1, p2, aspect, skew = iop
    xr, yr = measured[0] - xp, measured[1] - yp
    ax, ay = (1 + aspect) * xr + skew * yr, yr
    r2 = ax**2 + ay**2
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    lx = ax * radial + p1 * (r2 + 2 * ax**2) + 2 * p2 * ax * ay - k * ax * (1 + r2 / c**2)
    ly = ay * radial + 2 * p1 * ax * ay + p2 * (r2 + 2 * ay**2) - k * ay * (1 + r2 / c**2)
    projected = -c * p_camera[:2] / p_camera[2]
    return measured - np.array([lx, ly]) + projected


def test_pm_parameter_names_and_round_trip():
    assert PhotoModelerCamera.parameter_names == PM_PARAMETER_NAMES
    assert PhotoModelerCamera.image_units == "mm"
    assert jaxba.CAMERA_MODELS["photomodeler"] is PhotoModelerCamera
    camera = PhotoModelerCamera.from_parameters(jnp.asarray(PM_IOP))
    np.testing.assert_array_equal(camera.parameters(), PM_IOP)
    assert [float(getattr(camera, n)) for n in PM_PARAMETER_NAMES] == PM_IOP.tolist()


@pytest.mark.parametrize("k", [0.0, 3e-5])
@pytest.mark.parametrize("measured", [[-1.23, 2.17], [3.3, -2.4], [0.0, 0.0], [-3.5, -2.6]])
def test_pm_image_point_formula(measured, k):
    camera = PhotoModelerCamera.from_parameters(jnp.asarray(PM_IOP))
    p_camera = np.array([0.21, -0.13, -1.62])
    measured = np.asarray(measured)
    got = camera.image_point(jnp.asarray(p_camera), jnp.asarray(measured), jnp.asarray(k))
    expected = pm_image_point_np(PM_IOP, p_camera, measured, k)
    np.testing.assert_allclose(got, expected, rtol=FORMULA_RTOL, atol=1e-15)


def test_pm_residual_lives_in_the_corrected_frame():
    """measured - image_point = l(measured) - (-c (U, V)/W), and vanishes where they agree."""
    camera = PhotoModelerCamera.from_parameters(jnp.asarray(PM_IOP))
    p_camera = jnp.array([0.21, -0.13, -1.62])
    measured = jnp.asarray(PM_MEASURED)
    k = jnp.asarray(0.0)
    residual = measured - camera.image_point(p_camera, measured, k)
    expected = camera.corrected(measured, k) - (-PM_IOP[2] * p_camera[:2] / p_camera[2])
    np.testing.assert_allclose(residual, expected, rtol=FORMULA_RTOL, atol=1e-15)
    # Without distortion, aspect and skew it is plain collinearity.
    plain = np.r_[PM_IOP[:3], np.zeros(7)]
    camera = PhotoModelerCamera.from_parameters(jnp.asarray(plain))
    smac = jaxba.SmacCamera.from_parameters(jnp.asarray(np.r_[PM_IOP[:3], np.zeros(9)]))
    np.testing.assert_allclose(camera.image_point(p_camera, measured, k),
                               smac.image_point(p_camera, measured, k), rtol=FORMULA_RTOL)


@pytest.mark.parametrize("refraction", [jaxba.NoRefraction(), jaxba.AtmosphericRefraction()])
@pytest.mark.parametrize("wrt", ["iop", "eop", "point"])
def test_pm_collinearity_jacobian_matches_fd(wrt, refraction):
    values = {"iop": PM_IOP, "eop": PM_EOP, "point": PM_POINT}

    def f(x):
        args = values | {wrt: x}
        return _residual("photomodeler", args["iop"], args["eop"], args["point"],
                         PM_MEASURED, PM_SIGMA, refraction)

    assert_jacobian_matches_fd(f, values[wrt], FD_RTOL, FD_ATOL)


def test_pm_reproduces_dbat_residuals():
    """DBAT's adjusted camera and stations give DBAT's listed residuals of the control points.

    DBAT's residual is projected - corrected, in pixels of the y-up frame; jaxba's is
    measured - computed = corrected - projected, in mm.
    """
    camera = _camera()
    grid = jaxba.PixelGrid(camera.pixel_size, camera.image_size)
    ps = camera.pixel_size[0]
    control = read_control_points(DATA / "reference" / "camcal-fixed.txt", "id,label,x,y,z")
    marks = {(m.image, m.point): m for m in read_mark_points(DATA / "measurements" / "markpts.txt")}
    stations = np.loadtxt(DATA / "result" / "camera_stations.txt", delimiter=",",
                          usecols=range(8), comments="#")
    top = np.loadtxt(DATA / "result" / "top_residuals.txt", delimiter=",", comments="#")
    top = top[np.isin(top[:, 0].astype(int).astype(str), list(control))]
    assert len(top) > 10
    iop = jnp.asarray(_dbat_iop())
    for point, image, *_, res_x, res_y, _ in top:
        point, image = str(int(point)), str(int(image))
        mark = marks[image, point]
        measured = grid.pixel_to_image(jnp.asarray(jaxba_pixels(mark.col, mark.row)))
        eop = jnp.asarray(stations[int(image) - 1, 2:8])
        v = _residual("photomodeler", iop, eop, jnp.asarray(control[point].xyz), measured,
                      jnp.ones(2), jaxba.NoRefraction())
        np.testing.assert_allclose(-np.asarray(v) / ps, (res_x, res_y), atol=RESIDUAL_ATOL_PX)


# --------------------------------------------------------------------------- the adjustment


@pytest.fixture(scope="module")
def adjusted():
    """configs/dbat_camcal.toml adjusted (about 2-3 minutes of dense LM on a CPU)."""
    project = jaxba.build_project(jaxba.read_project(CONFIG))
    return project, jaxba.adjust_project(project)


def _camera_result(project, result):
    model, row = project.camera_rows["C1"]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    values = np.asarray(result.parameters.cameras[model][row])
    stds = np.asarray(result.precision.std.cameras[model][row])
    got = dict(zip(names, zip(values, stds)))
    grid_camera = _camera()
    xp, yp = grid_camera.principal_point_to_dbat(got["xp"][0], got["yp"][0])
    return got | {"xp": (xp, got["xp"][1]), "yp": (yp, got["yp"][1])}  # DBAT's frame


@pytest.mark.slow
def test_adjustment_size_and_sigma0(adjusted):
    project, result = adjusted
    assert result.converged, result.message
    assert result.precision.n_observations == N_OBSERVATIONS
    assert result.precision.n_unknowns == N_UNKNOWNS
    assert result.precision.redundancy == DBAT_REDUNDANCY
    assert abs(result.sigma0 - DBAT_SIGMA0) < SIGMA0_RTOL * DBAT_SIGMA0


@pytest.mark.slow
def test_camera_constant(adjusted):
    c, std_c = _camera_result(*adjusted)["c"]
    assert abs(c - DBAT["c"][0]) < C_ATOL
    assert abs(std_c - DBAT["c"][1]) < STD_RTOL * DBAT["c"][1]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["xp", "yp", "K1", "K2", "K3", "P1", "P2", "aspect"])
def test_camera_parameters_within_dbat_sigma(adjusted, name):
    value, std = _camera_result(*adjusted)[name]
    dbat, dbat_std = DBAT[name]
    assert abs(value - dbat) < WITHIN_SIGMAS * dbat_std
    assert abs(std - dbat_std) < STD_RTOL * dbat_std


@pytest.mark.slow
def test_k2_k3_correlation(adjusted):
    project, result = adjusted
    labels = [project.labels[i] for i in result.precision.free_index]
    k2, k3 = labels.index("camera C1 K2"), labels.index("camera C1 K3")
    cov = result.precision.covariance
    correlation = cov[k2, k3] / np.sqrt(cov[k2, k2] * cov[k3, k3])
    assert abs(correlation - DBAT_K2_K3_CORRELATION) < CORRELATION_ATOL


@pytest.mark.slow
def test_stations_within_dbat_sigma(adjusted):
    project, result = adjusted
    stations = _dbat_stations()
    eops = np.asarray(result.parameters.images)
    stds = np.asarray(result.precision.std.images)
    for image_id, eop, std in zip(project.image_ids, eops, stds):
        dbat = stations[image_id]
        sigma = np.radians(dbat[6:12])
        difference = eop - dbat[:6]
        difference[3:] = (difference[3:] + np.pi) % (2 * np.pi) - np.pi
        assert np.all(np.abs(difference) < WITHIN_SIGMAS * sigma), image_id
        np.testing.assert_allclose(std, sigma, rtol=STD_RTOL, err_msg=image_id)


@pytest.mark.slow
def test_point_rms_in_pixels(adjusted):
    project, result = adjusted
    (index,) = [i for i, g in enumerate(project.problem.groups) if g.name.startswith("image")]
    v_mm = result.residuals[index]
    rms_px = np.sqrt(np.mean(np.sum(v_mm**2, axis=1))) / _camera().pixel_size[0]
    assert abs(rms_px - DBAT_POINT_RMS_PX) < POINT_RMS_ATOL
