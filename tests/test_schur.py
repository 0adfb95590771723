"""The Schur backend on a BAL-style bundle (Rodrigues poses, "bal" cameras) against dense
computations.

A small synthetic scene (5 images x 60 points, every point seen by every image, 0.5 px
noise), read as BAL files are (`bal_bundle`), is small enough for a dense Jacobian, so every
Schur quantity has a dense twin: the damped step (JᵀJ + λD)⁻¹Jᵀe, its predicted reduction
and the final cost of stock `optx.LevenbergMarquardt` (dense QR).
"""

import ctypes
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from helpers import jacfwd_jacobian, schur_damped_step

from jaxba import solve
from jaxba._io._bal import BalProblem, bal_bundle
from jaxba._models._cameras import BalCamera
from jaxba._models._poses import RodriguesPose
from jaxba._problem._bundle import free_indices, params_from_free
from jaxba._problem._parameters import flatten
from jaxba._problem._unique_rows import unique_rows
from jaxba._solvers._cholesky import cholesky_solve
from jaxba._solvers._schur._normal import marquardt_diagonal
from jaxba._solvers._schur._pairs import same_point_pairs
from jaxba._solvers._schur._structure import bundle_structure
from jaxba.advanced import Schur

N_CAMERAS, N_POINTS = 5, 60
NOISE_PX = 0.5
STEP_RTOL = 1e-8  # Schur step vs dense solve of (JᵀJ + λD) x = Jᵀe (brief: 1e-8)
COST_RTOL = 1e-10  # final cost, Schur LM vs dense optx.LevenbergMarquardt (brief: ~1e-10)
SOLVE_RTOL = 1e-13  # cholesky_solve vs numpy.linalg.solve, well-conditioned SPD matrices


def _project(camera, point):
    """BAL's projection of one point by one 9-value camera row, through jaxba's models."""
    pose = RodriguesPose.from_parameters(camera[:6])
    return BalCamera.from_parameters(camera[6:]).image_point(
        pose.to_camera(point), jnp.zeros(2), 0.0)


def synthetic_scene(seed=0, n_cameras=N_CAMERAS, n_points=N_POINTS, drop=0.0):
    """(problem, truth, perturbed start) as BalProblems: BAL cameras ~8 units from points in
    a unit cube (P = R X + t, P_z < 0 in front). `drop` removes that fraction of the
    observations at random (each point keeps cameras 0 and 1)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (n_points, 3))
    rotations = rng.normal(scale=0.1, size=(n_cameras, 3))
    translations = np.column_stack(
        [rng.normal(scale=0.5, size=(n_cameras, 2)), -8.0 + rng.normal(scale=0.3, size=n_cameras)]
    )
    intrinsics = np.column_stack(
        [500.0 + rng.normal(scale=5.0, size=n_cameras), np.full(n_cameras, 0.05),
         np.full(n_cameras, -0.01)]
    )
    cameras = np.column_stack([rotations, translations, intrinsics])
    camera_index, point_index = (
        a.ravel() for a in np.meshgrid(np.arange(n_cameras), np.arange(n_points))
    )
    keep = (rng.uniform(size=camera_index.size) >= drop) | (camera_index < 2)
    camera_index, point_index = camera_index[keep], point_index[keep]
    clean = np.asarray(jax.jit(jax.vmap(_project))(jnp.asarray(cameras[camera_index]),
                                                   jnp.asarray(points[point_index])))
    observed = clean + rng.normal(scale=NOISE_PX, size=clean.shape)
    truth = BalProblem(cameras, points, camera_index, point_index, observed)
    camera_perturbation = np.array([1e-2] * 3 + [5e-2] * 3 + [2.0, 1e-3, 1e-4])
    start = BalProblem(
        cameras + rng.normal(size=cameras.shape) * camera_perturbation,
        points + rng.normal(scale=0.02, size=points.shape),
        camera_index, point_index, observed,
    )
    return bal_bundle(start), bal_bundle(truth)


def cost(problem, params) -> float:
    return float(_cost(problem, params))


@eqx.filter_jit  # one program for every call (op by op: dozens of small ones each)
def _cost(problem, params):
    return 0.5 * sum(jnp.sum(e**2) for e in problem.residuals(params))


@pytest.fixture(scope="module", autouse=True)
def single_threaded_openblas():
    """One OpenBLAS thread while these tests run (restored after), as OPENBLAS_NUM_THREADS=1.

    Only the dense references call LAPACK (QR in optx.LevenbergMarquardt). Called from XLA,
    OpenBLAS's threads and XLA's oversubscribe a small machine: on 2 cores each 600 x 225
    QR then takes ~1.7 s instead of ~50 ms (OpenMathLib/OpenBLAS#5517). The Schur solver
    itself calls no LAPACK (jaxba/_cholesky.py).
    """
    maps = pathlib.Path("/proc/self/maps")
    lines = maps.read_text().splitlines() if maps.exists() else []
    libraries = sorted({line.split()[-1] for line in lines if "openblas" in line})
    restore = []
    for path in libraries:
        library = ctypes.CDLL(path)
        for suffix in ("", "64_"):
            get = getattr(library, f"scipy_openblas_get_num_threads{suffix}", None)
            set_ = getattr(library, f"scipy_openblas_set_num_threads{suffix}", None)
            if get is not None and set_ is not None:
                restore.append((set_, get()))
                set_(1)
    yield
    for set_, threads in restore:
        set_(threads)


@pytest.fixture(scope="module")
def scene():
    return synthetic_scene()


@pytest.fixture(scope="module")
def tight_solution(scene):
    problem, _ = scene
    return solve(problem, Schur(), rtol=1e-13, atol=1e-13, function_tolerance=0.0,
                 max_steps=200)


# --- structure ----------------------------------------------------------------------------


def test_pairs_are_all_same_point_pairs_of_the_lower_key_triangle():
    problem, _ = synthetic_scene(seed=1, n_cameras=4, n_points=9, drop=0.4)
    structure = bundle_structure(problem)
    group = problem.groups[0]
    # The structure's rows: the group's observations by key (every one once), padding last.
    order = np.asarray(structure.image_order)
    assert sorted(order) == list(range(group.point.shape[0]))
    camera, point = np.asarray(group.camera)[order], np.asarray(group.point)[order]
    key = np.asarray(structure.key)[: camera.size]
    assert np.all(np.diff(key) >= 0) and structure.key[-1] == structure.key_columns.shape[0] - 1
    # One key per image here: every observation of an image has the same reduced columns.
    assert len({(c, k) for c, k in zip(camera, key)}) == len(set(camera))
    n_obs, row_size = camera.size, structure.pair_first.shape[-1]
    row_block = np.asarray(structure.pair_block).ravel()
    first = np.asarray(structure.pair_first).reshape(-1, row_size)
    second = np.asarray(structure.pair_second).reshape(-1, row_size)
    real = first < n_obs  # padding pairs hold observation n_obs (gathered as zeros)
    assert np.array_equal(real, second < n_obs)
    expected = {
        (i, j) for i in range(n_obs) for j in range(n_obs)
        if point[i] == point[j] and key[i] >= key[j]
    }
    assert sorted(zip(first[real], second[real])) == sorted(expected)
    # Every real pair sits in a row of its own key pair; rows ascend, padding rows last.
    key_pairs = np.asarray(structure.key_pairs)
    n_blocks = key_pairs.shape[0]
    pair_block = np.broadcast_to(row_block[:, None], first.shape)[real]
    np.testing.assert_array_equal(key_pairs[pair_block, 0], key[first[real]])
    np.testing.assert_array_equal(key_pairs[pair_block, 1], key[second[real]])
    assert np.all(np.diff(row_block) >= 0) and np.all(row_block <= n_blocks)
    assert not np.any(real[row_block == n_blocks])


@pytest.mark.parametrize("shape", [(0, 3), (1, 4), (5, 0), (200, 6)])
def test_unique_rows_is_numpys_unique_of_rows(shape):
    table = np.random.default_rng(shape[0]).integers(-2, 3, shape)
    table[:, :1] = 7  # a constant leading column: the later columns decide the order
    expected, inverse = np.unique(table, axis=0, return_inverse=True)
    rows, index = unique_rows(table)
    np.testing.assert_array_equal(rows, expected)
    np.testing.assert_array_equal(index, np.ravel(inverse))
    np.testing.assert_array_equal(rows[index], table)


def test_same_point_pairs_small_case():
    first, second = same_point_pairs(np.array([1, 0, 1, 1]), 2)
    assert sorted(zip(first, second)) == sorted(
        [(1, 1)] + [(i, j) for i in (0, 2, 3) for j in (0, 2, 3)]
    )


# --- Cholesky -------------------------------------------------------------------------------


@pytest.mark.parametrize("n, block_size", [(1, 4), (5, 2), (23, 8), (24, 8)])
def test_cholesky_solve_matches_numpy(n, block_size):
    rng = np.random.default_rng(n)
    b = rng.normal(size=(n, n))
    matrix = b @ b.T + n * np.eye(n)
    vector = rng.normal(size=n)
    upper_garbage = np.triu(rng.normal(size=(n, n)), 1)  # only the lower triangle is read
    solve = jax.jit(cholesky_solve, static_argnums=2)
    x = solve(jnp.asarray(matrix + upper_garbage), jnp.asarray(vector), block_size)
    expected = np.linalg.solve(matrix, vector)
    assert np.linalg.norm(x - expected) <= SOLVE_RTOL * np.linalg.norm(expected)


def test_cholesky_solve_of_indefinite_matrix_is_nan():
    x = jax.jit(cholesky_solve)(jnp.diag(jnp.array([1.0, -1.0, 2.0])), jnp.ones(3))
    assert np.all(np.isnan(x))


# --- the damped step ----------------------------------------------------------------------


@pytest.mark.parametrize("damping", [1e-6, 1e-2, 1.0, 1e3])
def test_schur_step_equals_dense_damped_step(scene, damping):
    """The Schur step is (JᵀJ + λD)⁻¹Jᵀe of the dense normal equations over all 9 camera
    and 3 point unknowns (chunks of 64 observations: 300 = 4 x 64 + 44, padding
    exercised), and its predicted reduction is the dense model's ½|e + Jδ|² - ½|e|²."""
    problem, _ = scene
    params = problem.initial
    structure = bundle_structure(problem, jacobian_batch=64)
    step, predicted = schur_damped_step(problem, structure, params, jnp.asarray(damping))
    schur = flatten(step)[free_indices(problem)]

    jacobian, residual = (np.asarray(a) for a in jacfwd_jacobian(problem, params))
    hessian = jacobian.T @ jacobian
    diagonal = np.asarray(marquardt_diagonal(jnp.asarray(np.diag(hessian)), 1e-6, 1e32))
    expected = np.linalg.solve(hessian + damping * np.diag(diagonal), jacobian.T @ residual)
    assert np.linalg.norm(schur - expected) <= STEP_RTOL * np.linalg.norm(expected)
    model = 0.5 * np.sum((residual - jacobian @ expected) ** 2) - 0.5 * np.sum(residual**2)
    assert model < 0
    assert float(predicted) == pytest.approx(model, rel=STEP_RTOL)


# --- whole solves -------------------------------------------------------------------------


def _dense_lm_cost(problem) -> float:
    """Stock optx.LevenbergMarquardt (dense QR) in Jacobi-scaled unknowns, tight tolerances."""
    jacobian, _ = jacfwd_jacobian(problem, problem.initial)
    scale = jnp.asarray(1.0 / np.linalg.norm(np.asarray(jacobian), axis=0))
    index = free_indices(problem)
    x0 = flatten(problem.initial)[index]
    return float(_dense_lm(problem, scale, jnp.asarray(index), jnp.asarray(x0)))


@eqx.filter_jit  # the solve and the final cost as one program
def _dense_lm(problem, scale, index, x0):
    def fn(z, args):
        params = params_from_free(problem, x0 + scale * z, index)
        return jnp.concatenate([jnp.ravel(e) for e in problem.residuals(params)])

    solver = optx.LevenbergMarquardt(rtol=1e-13, atol=1e-13)
    solution = optx.least_squares(fn, solver, jnp.zeros_like(x0), max_steps=500, throw=False)
    return 0.5 * jnp.sum(fn(solution.value, None) ** 2)


def test_final_cost_matches_dense_levenberg_marquardt(scene, tight_solution):
    problem, truth = scene
    assert tight_solution.result == optx.RESULTS.successful
    schur_cost = float(tight_solution.cost)
    assert schur_cost == pytest.approx(cost(problem, tight_solution.parameters), rel=1e-12)
    assert schur_cost < cost(problem, problem.initial)
    assert schur_cost == pytest.approx(_dense_lm_cost(problem), rel=COST_RTOL)
    # Noise only: ½Σe² ≈ ½ (n_residuals - n_unknowns + 7) σ², below the truth's cost.
    assert schur_cost < cost(truth, truth.initial)


def test_function_tolerance_stops_as_converged(scene, tight_solution):
    problem, _ = scene
    loose = solve(problem, Schur(), rtol=0.0, atol=1e-12, function_tolerance=1e-6,
                  max_steps=200)
    assert bool(loose.converged)
    assert int(loose.steps) < int(tight_solution.steps)
    assert float(loose.cost) == pytest.approx(float(tight_solution.cost), rel=1e-6)
