"""Tests of the BAL reader and camera model against published costs and a NumPy/SciPy model."""

import bz2
import gzip
import json
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_RTOL, assert_jacobian_matches_fd
from scipy.spatial.transform import Rotation

import jaxba
from jaxba._cli._bal import run_bal
from jaxba._io._bal import BalFormatError, bal_bundle, read_bal
from jaxba._models._cameras import NoRefraction
from jaxba._models._poses import rotate_point
from jaxba._statistics._datum import similarity_transform

DATA = pathlib.Path(__file__).parent / "data" / "bal"
TOY = DATA / "dubrovnik-3-7-pre.txt"
LADYBUG = DATA / "problem-49-7776-pre.txt.bz2"
DUBROVNIK = DATA / "problem-16-22106-pre.txt.bz2"

COST_RTOL = 1e-12  # initial costs against BundleAdjustmentModels.jl's 18-digit values
MODEL_RTOL = 1e-11  # jax vs NumPy/SciPy model relative to the image point (seen: 9e-13)
LADYBUG_COST = 8.50912460680839606e05
DUBROVNIK_COST = 4.18565951824972266e06
TOY_COST = 2764.22  # published rounded to 0.01
CERES_LADYBUG_FINAL = 13344.318  # Ceres (see benchmarks/README.md); ours must not be worse
SOLVE_RTOL = 1e-6
ROTATION_TOL = 1e-14  # rotate_point against jaxba.rodrigues_to_matrix, unit-sized vectors
SIMILARITY_RTOL = 1e-9  # residuals after a similarity, relative to the predicted image point
FD_ATOL_PIXELS = 1e-6  # central differences of pixel-sized outputs: rounding ~ 1e-16 * 500 / 1e-6


def numpy_residuals(bal, cameras=None, points=None) -> np.ndarray:
    """BAL residuals written out again in NumPy with SciPy's rotation vectors, (n_obs, 2)."""
    cameras = bal.cameras if cameras is None else np.asarray(cameras)
    points = bal.points if points is None else np.asarray(points)
    camera = cameras[bal.camera_index]
    rotated = Rotation.from_rotvec(camera[:, :3]).apply(points[bal.point_index])
    in_camera = rotated + camera[:, 3:6]
    p = -in_camera[:, :2] / in_camera[:, 2:3]
    r2 = np.sum(p**2, axis=1, keepdims=True)
    distortion = 1.0 + camera[:, 7:8] * r2 + camera[:, 8:9] * r2**2
    return camera[:, 6:7] * distortion * p - bal.observed


@jax.jit
def _residuals(problem, params):
    return problem.residuals(params)[0]


def jax_residuals(bal, params=None) -> np.ndarray:
    """The BundleProblem's whitened residuals e = observed - x (σ = 1 px), (n_obs, 2)."""
    problem = bal_bundle(bal)
    return np.asarray(_residuals(problem, problem.initial if params is None else params))


def jax_cost(bal) -> float:
    return 0.5 * float(np.sum(jax_residuals(bal) ** 2))


# --- reader -------------------------------------------------------------------------------


def test_toy_file_contents():
    bal = read_bal(TOY)
    assert (bal.n_cameras, bal.n_points, bal.n_observations) == (3, 7, 19)
    np.testing.assert_array_equal(bal.camera_index[:3], [0, 1, 2])
    np.testing.assert_array_equal(bal.point_index[:4], [0, 0, 0, 1])
    np.testing.assert_array_equal(bal.observed[0], [-3.859900e02, 3.871200e02])
    np.testing.assert_array_equal(bal.observed[-1], [-5.841998e01, 1.108300e02])
    np.testing.assert_array_equal(
        bal.cameras[0, :3],
        [-1.6943983532198115e-02, 1.1171804676513932e-02, 2.4643508831711991e-03],
    )
    assert bal.cameras.dtype == np.float64 and bal.camera_index.dtype == np.int64


def test_compressed_files_read_the_same(tmp_path):
    plain = read_bal(TOY)
    text = TOY.read_bytes()
    for suffix, compress in ((".bz2", bz2.compress), (".gz", gzip.compress)):
        path = tmp_path / f"toy.txt{suffix}"
        path.write_bytes(compress(text))
        other = read_bal(path)
        for name in ("cameras", "points", "camera_index", "point_index", "observed"):
            np.testing.assert_array_equal(getattr(other, name), getattr(plain, name))


def test_ladybug_sizes():
    bal = read_bal(LADYBUG)
    assert (bal.n_cameras, bal.n_points, bal.n_observations) == (49, 7776, 31843)
    assert bal.cameras.shape == (49, 9) and bal.points.shape == (7776, 3)


def _write(tmp_path, text, name="bad.txt") -> pathlib.Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _toy_lines() -> list[str]:
    return TOY.read_text().splitlines()


def test_truncated_parameters_are_reported(tmp_path):
    path = _write(tmp_path, "\n".join(_toy_lines()[:-5]) + "\n")
    with pytest.raises(
        BalFormatError,
        match=r"bad\.txt: truncated: expected 48 .* found 45 \(missing from point 6 X on\)",
    ):
        read_bal(path)


def test_truncated_observations_are_reported(tmp_path):
    path = _write(tmp_path, "\n".join(_toy_lines()[:10]) + "\n")
    with pytest.raises(BalFormatError, match="announces 19 observations, the file ends after 8"):
        read_bal(path)


def test_truncated_compressed_stream_is_reported(tmp_path):
    path = tmp_path / "cut.txt.bz2"
    path.write_bytes(bz2.compress(TOY.read_bytes())[:-40])
    with pytest.raises(BalFormatError, match=r"cut\.txt\.bz2: cannot be read"):
        read_bal(path)


def test_malformed_value_names_its_line(tmp_path):
    lines = _toy_lines()
    lines[30] = "1.0e-2x"  # a camera value
    path = _write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(
        BalFormatError, match=r"bad\.txt:31: camera 0 k2: '1.0e-2x' is not a number"
    ):
        read_bal(path)


def test_observation_with_wrong_field_count_names_its_line(tmp_path):
    lines = _toy_lines()
    lines[4] = "2 0 -6.679200e+02"
    path = _write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(
        BalFormatError, match=r"bad\.txt:5: observation 2 must be 'camera point x y'"
    ):
        read_bal(path)


def test_out_of_range_index_names_its_line(tmp_path):
    lines = _toy_lines()
    lines[5] = "1 7     -3.844000e+01 4.921200e+02"  # observation 3: point 7 of 0..6
    path = _write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(
        BalFormatError,
        match=r"observation 3 \(line 6\): point index 7 is not an integer in \[0, 7\)",
    ):
        read_bal(path)


def test_bad_header_and_extra_content(tmp_path):
    with pytest.raises(BalFormatError, match=r":1: the header must hold three integers"):
        read_bal(_write(tmp_path, "3 seven 19\n"))
    with pytest.raises(BalFormatError, match="unexpected content after the 3 cameras and 7 points"):
        read_bal(_write(tmp_path, TOY.read_text() + "1.0\n"))


def test_missing_file():
    with pytest.raises(FileNotFoundError):
        read_bal(DATA / "no-such-problem.txt")


# --- model and initial costs --------------------------------------------------------------


def test_toy_initial_cost():
    bal = read_bal(TOY)
    assert round(jax_cost(bal), 2) == TOY_COST
    assert round(0.5 * float(np.sum(numpy_residuals(bal) ** 2)), 2) == TOY_COST


def test_ladybug_initial_cost():
    bal = read_bal(LADYBUG)
    assert jax_cost(bal) == pytest.approx(LADYBUG_COST, rel=COST_RTOL)
    numpy_cost = 0.5 * float(np.sum(numpy_residuals(bal) ** 2))
    assert numpy_cost == pytest.approx(LADYBUG_COST, rel=COST_RTOL)


def test_dubrovnik_initial_cost():
    bal = read_bal(DUBROVNIK)
    assert jax_cost(bal) == pytest.approx(DUBROVNIK_COST, rel=COST_RTOL)
    numpy_cost = 0.5 * float(np.sum(numpy_residuals(bal) ** 2))
    assert numpy_cost == pytest.approx(DUBROVNIK_COST, rel=COST_RTOL)


def test_bal_problem_is_a_bundle_of_bal_cameras_and_rodrigues_poses():
    bal = read_bal(TOY)
    problem = bal_bundle(bal)
    (group,) = problem.groups
    assert (group.model, group.pose, problem.pose) == ("bal", "rodrigues", "rodrigues")
    np.testing.assert_array_equal(problem.initial.images, bal.cameras[:, :6])
    np.testing.assert_array_equal(problem.initial.cameras["bal"], bal.cameras[:, 6:])
    np.testing.assert_array_equal(group.camera, group.image)
    assert np.all(np.asarray(group.stddev) == 1.0)
    assert problem.n_unknowns() == 9 * bal.n_cameras + 3 * bal.n_points


def test_residuals_match_numpy_model_per_observation():
    """e = observed - x: Ceres' residual x - observed with the opposite sign."""
    bal = read_bal(LADYBUG)
    residuals = -jax_residuals(bal)
    expected = numpy_residuals(bal)
    scale = np.maximum(np.abs(bal.observed + expected), 1.0)  # the predicted image point
    assert np.max(np.abs(residuals - expected) / scale) < MODEL_RTOL


def test_residual_jacobian_matches_finite_differences():
    """`collinearity_residual` with the "bal" camera and the "rodrigues" pose."""
    bal = read_bal(TOY)
    camera, point, observed = bal.cameras[1], bal.points[4], bal.observed[4]
    joint = np.concatenate([camera, point])

    def residual(x):
        return jaxba.advanced.collinearity_residual(
            "bal", x[6:9], x[:6], x[9:], jnp.asarray(observed), jnp.ones(2), NoRefraction(),
            pose="rodrigues")

    assert_jacobian_matches_fd(residual, joint, rtol=FD_RTOL, atol=FD_ATOL_PIXELS)


def test_row_jacobians_of_the_rodrigues_pose_match_forward_mode():
    """The dense path's row Jacobians (`ImagePoints.row_jacobians`) of the Rodrigues pose
    against forward mode through the residual function."""
    bal = read_bal(TOY)
    problem = bal_bundle(bal)
    (group,) = problem.groups
    # Each side compiled as one program (op by op they compiled ~200 small ones).
    residuals, blocks = eqx.filter_jit(group.row_jacobians)(problem.initial, problem.refraction)
    values = eqx.filter_jit(group.local_values)(problem.initial)

    def row(v, i):
        return jaxba.advanced.collinearity_residual(
            "bal", v[:3], v[3:9], v[9:], group.measured[i], group.stddev[i], NoRefraction(),
            pose="rodrigues")

    @jax.jit
    def forward_mode(values, rows):
        return jax.vmap(row)(values, rows), jax.vmap(jax.jacfwd(row))(values, rows)

    forward_residuals, expected = forward_mode(values, jnp.arange(values.shape[0]))
    np.testing.assert_allclose(residuals, forward_residuals, rtol=1e-14)
    np.testing.assert_allclose(blocks, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def test_similarity_of_the_network_leaves_the_residuals():
    """`similarity_transform` moves Rodrigues poses with the points (rotation, translation,
    scale): a perspective camera sees the same image."""
    bal = read_bal(TOY)
    problem = bal_bundle(bal)
    theta = jnp.array([0.3, -0.2, 0.5, 0.1, -0.05, 0.2, 0.02])
    centre = jnp.asarray(np.mean(bal.points, axis=0))
    moved = similarity_transform(problem.initial, theta, centre, pose=problem.pose)
    assert not np.allclose(moved.images, problem.initial.images)
    before, after = jax_residuals(bal), jax_residuals(bal, moved)
    scale = np.maximum(np.abs(bal.observed - before), 1.0)  # the predicted image point
    assert np.max(np.abs(after - before) / scale) < SIMILARITY_RTOL


@pytest.mark.parametrize("scale", [1.0, 1e-9, 1e-14, 0.0])
def test_rotate_point_matches_rodrigues_matrix(scale):
    r = jnp.array([0.3, -1.1, 0.7]) * scale
    x = jnp.array([0.2, -0.5, 0.9])
    expected = jaxba.rodrigues_to_matrix(r) @ x
    np.testing.assert_allclose(rotate_point(r, x), expected, rtol=0, atol=ROTATION_TOL)


def test_rotate_point_derivative_at_zero_is_minus_skew():
    x = jnp.array([0.2, -0.5, 0.9])
    skew = np.array([[0.0, -0.9, -0.5], [0.9, 0.0, -0.2], [0.5, 0.2, 0.0]])  # [x]_x
    jacobian = jax.jacfwd(rotate_point)(jnp.zeros(3), x)
    np.testing.assert_allclose(jacobian, -skew, rtol=0, atol=ROTATION_TOL)


# --- run_bal ------------------------------------------------------------------------------


def test_run_bal_writes_results(tmp_path, capsys):
    jax.clear_caches()  # so that this run compiles (and says so) whatever ran before
    results = run_bal(TOY, tmp_path, max_steps=5)
    written = json.loads((tmp_path / "results.json").read_text())
    assert written == results
    assert round(results["initial_cost"], 2) == TOY_COST
    assert results["final_cost"] < results["initial_cost"]
    assert results["iterations"] <= 5 and results["compile_seconds"] > 0
    assert results["compilations"] > 0
    assert results["cost_history"][0] == pytest.approx(results["initial_cost"], rel=1e-14)
    assert "iteration   0" in capsys.readouterr().out


@pytest.mark.slow
def test_ladybug_solve_reaches_ceres_cost(tmp_path):
    results = run_bal(LADYBUG, tmp_path, on_iteration=None)
    assert results["converged"]
    assert results["final_cost"] <= CERES_LADYBUG_FINAL * (1 + SOLVE_RTOL)
