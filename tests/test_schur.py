"""Tests of the Schur-complement Levenberg-Marquardt against dense computations.

A small synthetic BAL-style scene (5 cameras x 60 points, every point seen by every camera,
0.5 px noise) is small enough for a dense Jacobian, so every Schur quantity has a dense
twin: the normal equations, the damped step (JᵀJ + λD)⁻¹Jᵀr and the final cost of stock
`optx.LevenbergMarquardt` (dense QR).
"""

import ctypes
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from jaxba._bal import bal_residual
from jaxba._cholesky import cholesky_solve
from jaxba._schur import (
    SchurDampedNewtonDescent,
    TwoBlockProblem,
    marquardt_diagonal,
    normal_equations,
    solve_two_block,
    two_block_residuals,
)
from jaxba._schur._problem import _same_point_pairs

N_CAMERAS, N_POINTS = 5, 60
NOISE_PX = 0.5
NORMAL_RTOL = 1e-12  # U, V, W, g from segment sums vs the dense JᵀJ, Jᵀr
STEP_RTOL = 1e-8  # Schur step vs dense solve of (JᵀJ + λD) x = Jᵀr (brief: 1e-8)
COST_RTOL = 1e-10  # final cost, Schur LM vs dense optx.LevenbergMarquardt (brief: ~1e-10)
SOLVE_RTOL = 1e-13  # cholesky_solve vs numpy.linalg.solve, well-conditioned SPD matrices


def synthetic_scene(seed=0, n_cameras=N_CAMERAS, n_points=N_POINTS, drop=0.0):
    """(problem, truth y, perturbed y0): BAL cameras ~8 units from points in a unit cube.

    BAL cameras look down -z: P = R X + t with P_z < 0 in front. `drop` removes that
    fraction of the observations at random (each point keeps at least two).
    """
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (n_points, 3))
    rotations = rng.normal(scale=0.1, size=(n_cameras, 3))
    translations = np.column_stack(
        [rng.normal(scale=0.5, size=(n_cameras, 2)), -8.0 + rng.normal(scale=0.3, size=n_cameras)]
    )
    intrinsics = np.column_stack(
        [
            500.0 + rng.normal(scale=5.0, size=n_cameras),
            np.full(n_cameras, 0.05),
            np.full(n_cameras, -0.01),
        ]
    )
    cameras = np.column_stack([rotations, translations, intrinsics])
    camera_index, point_index = (
        a.ravel() for a in np.meshgrid(np.arange(n_cameras), np.arange(n_points))
    )
    keep = rng.uniform(size=camera_index.size) >= drop
    keep |= camera_index < 2  # every point keeps cameras 0 and 1
    camera_index, point_index = camera_index[keep], point_index[keep]
    truth = (jnp.asarray(cameras), jnp.asarray(points))
    clean = jax.vmap(bal_residual)(
        truth[0][camera_index], truth[1][point_index], jnp.zeros((camera_index.size, 2))
    )
    observed = np.asarray(clean) + rng.normal(scale=NOISE_PX, size=clean.shape)
    problem = TwoBlockProblem(
        bal_residual,
        camera_index,
        point_index,
        jnp.asarray(observed),
        n_cameras=n_cameras,
        n_points=n_points,
        chunk_size=64,
    )
    camera_perturbation = np.array([1e-2] * 3 + [5e-2] * 3 + [2.0, 1e-3, 1e-4])
    y0 = (
        truth[0] + jnp.asarray(rng.normal(size=cameras.shape) * camera_perturbation),
        truth[1] + jnp.asarray(rng.normal(scale=0.02, size=points.shape)),
    )
    return problem, truth, y0


def dense_jacobian(problem, y):
    """Dense J (n_obs·k, n_cameras·n_c + n_points·n_p) and r, camera-major then point-major."""
    jacobian, residual = _dense_jacobian(problem, y)
    return np.asarray(jacobian), np.asarray(residual)


@jax.jit
def _dense_jacobian(problem, y):
    cameras, points = y

    def residual_vector(x):
        c = x[: cameras.size].reshape(cameras.shape)
        p = x[cameras.size :].reshape(points.shape)
        return jnp.ravel(two_block_residuals((c, p), problem))

    x = jnp.concatenate([jnp.ravel(cameras), jnp.ravel(points)])
    return jax.jacfwd(residual_vector)(x), residual_vector(x)


def dense_damped_step(jacobian, residual, damping):
    """x = (JᵀJ + λD)⁻¹ Jᵀr with D = marquardt_diagonal(diag(JᵀJ)), NumPy float64."""
    normal = jacobian.T @ jacobian
    d = np.asarray(marquardt_diagonal(jnp.asarray(np.diag(normal)), 1e-6, 1e32))
    return np.linalg.solve(normal + damping * np.diag(d), jacobian.T @ residual)


def cost(problem, y) -> float:
    return float(0.5 * jnp.sum(two_block_residuals(y, problem) ** 2))


@pytest.fixture(scope="module", autouse=True)
def single_threaded_openblas():
    """One OpenBLAS thread while these tests run (restored after), as OPENBLAS_NUM_THREADS=1.

    Only the dense references call LAPACK (QR in optx.LevenbergMarquardt). Called from XLA,
    OpenBLAS's threads and XLA's oversubscribe a small machine: on 2 cores each 600 x 225
    QR then takes ~1.7 s instead of ~50 ms (OpenMathLib/OpenBLAS#5517). The Schur solver
    itself calls no LAPACK (jaxba/_schur/_cholesky.py).
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
def dense(scene):
    """Dense J and r at the scene's starting point."""
    problem, _, y0 = scene
    return dense_jacobian(problem, y0)


@pytest.fixture(scope="module")
def tight_solution(scene):
    problem, _, y0 = scene
    return solve_two_block(problem, y0, rtol=1e-13, atol=1e-13, max_steps=200)


# --- structure ----------------------------------------------------------------------------


def test_pairs_are_all_same_point_pairs_of_the_lower_block_triangle():
    problem, _, _ = synthetic_scene(seed=1, n_cameras=4, n_points=9, drop=0.4)
    camera, point = np.asarray(problem.camera_index), np.asarray(problem.point_index)
    n_obs, row_size = camera.size, problem.pair_row_size
    row_block = np.asarray(problem.pair_block).ravel()
    first = np.asarray(problem.pair_first).reshape(-1, row_size)
    second = np.asarray(problem.pair_second).reshape(-1, row_size)
    real = first < n_obs  # padding pairs hold observation n_obs (gathered as zeros)
    assert np.array_equal(real, second < n_obs)
    expected = {
        (i, j)
        for i in range(n_obs)
        for j in range(n_obs)
        if point[i] == point[j] and camera[i] >= camera[j]
    }
    assert sorted(zip(first[real], second[real])) == sorted(expected)
    # Every real pair sits in a row of its own block; rows ascend, padding rows last.
    pair_block = np.broadcast_to(row_block[:, None], first.shape)[real]
    np.testing.assert_array_equal(pair_block, camera[first[real]] * 4 + camera[second[real]])
    assert np.all(np.diff(row_block) >= 0) and np.all(row_block <= 4 * 4)
    assert not np.any(real[row_block == 4 * 4])


def test_same_point_pairs_small_case():
    first, second = _same_point_pairs(np.array([1, 0, 1, 1]), 2)
    assert sorted(zip(first, second)) == sorted(
        [(1, 1)] + [(i, j) for i in (0, 2, 3) for j in (0, 2, 3)]
    )


def test_bad_indices_are_rejected_at_construction():
    with pytest.raises(ValueError, match="point_index has entries outside"):
        TwoBlockProblem(bal_residual, [0, 1], [0, 5], jnp.zeros((2, 2)), n_cameras=2, n_points=5)
    with pytest.raises(ValueError, match="leading axis"):
        TwoBlockProblem(bal_residual, [0, 1], [0, 1], jnp.zeros((3, 2)), n_cameras=2, n_points=2)


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


# --- normal equations and the damped step -------------------------------------------------


def test_normal_equations_match_dense(scene, dense):
    """Chunks of 64 observations: 300 = 4 x 64 + 44, so the padding is exercised too."""
    problem, _, y0 = scene
    assert problem.camera_index.size % problem.chunk_size != 0
    residual = two_block_residuals(y0, problem)
    normal = jax.jit(normal_equations, static_argnums=(3, 4))(problem, y0, residual, 1e-6, 1e32)
    jacobian, r = dense
    n_c = 9 * N_CAMERAS
    dense = jacobian.T @ jacobian
    gradient = jacobian.T @ r
    for a in range(N_CAMERAS):
        block = dense[9 * a : 9 * a + 9, 9 * a : 9 * a + 9]
        np.testing.assert_allclose(
            normal.camera_hessian[a],
            block,
            rtol=NORMAL_RTOL,
            atol=NORMAL_RTOL * np.abs(block).max(),
        )
    for p in range(N_POINTS):
        rows = slice(n_c + 3 * p, n_c + 3 * p + 3)
        np.testing.assert_allclose(normal.point_hessian[p], dense[rows, rows], rtol=NORMAL_RTOL)
    camera, point = np.asarray(problem.camera_index), np.asarray(problem.point_index)
    for i in range(0, camera.size, 17):
        block = dense[
            9 * camera[i] : 9 * camera[i] + 9, n_c + 3 * point[i] : n_c + 3 * point[i] + 3
        ]
        np.testing.assert_allclose(
            normal.coupling[i], block.T, rtol=NORMAL_RTOL, atol=NORMAL_RTOL * np.abs(block).max()
        )
    np.testing.assert_allclose(normal.camera_gradient.ravel(), gradient[:n_c], rtol=1e-10)
    np.testing.assert_allclose(
        normal.point_gradient.ravel(),
        gradient[n_c:],
        rtol=1e-10,
        atol=1e-9 * np.abs(gradient).max(),
    )


@eqx.filter_jit
def _descent_step(descent, y, residual, radius):
    """init, query at y, then step(radius) and the step's predicted reduction: what
    SchurLevenbergMarquardt does."""
    state = descent.init(y, jnp.zeros_like(residual))
    state = descent.query(y, residual, state)
    step = descent.step(radius, state)[0]
    return step, descent.predicted_reduction(step, state)


@pytest.mark.parametrize("damping", [1e-6, 1e-2, 1.0, 1e3])
def test_schur_step_equals_dense_damped_step(scene, dense, damping):
    """The descent's step(1/λ) is -(JᵀJ + λD)⁻¹Jᵀr of the dense normal equations, and its
    predicted reduction is the dense model's ½|r + Jδ|² - ½|r|²."""
    problem, _, y0 = scene
    residual = two_block_residuals(y0, problem)
    descent = SchurDampedNewtonDescent(problem)
    step, predicted = _descent_step(descent, y0, residual, jnp.asarray(1.0 / damping))
    schur = -np.concatenate([np.ravel(step[0]), np.ravel(step[1])])
    expected = dense_damped_step(*dense, damping)
    assert np.linalg.norm(schur - expected) <= STEP_RTOL * np.linalg.norm(expected)
    jacobian, dense_residual = dense
    model = 0.5 * np.sum((dense_residual - jacobian @ expected) ** 2) - 0.5 * np.sum(
        dense_residual**2)
    assert model < 0
    assert float(predicted) == pytest.approx(model, rel=STEP_RTOL)


# --- whole solves -------------------------------------------------------------------------


def _dense_lm_cost(problem, y0, jacobian) -> float:
    """Stock optx.LevenbergMarquardt (dense QR) in Jacobi-scaled unknowns, tight tolerances."""
    scale = 1.0 / np.linalg.norm(jacobian, axis=0)
    n_c = y0[0].size
    scale_c = jnp.asarray(scale[:n_c].reshape(y0[0].shape))
    scale_p = jnp.asarray(scale[n_c:].reshape(y0[1].shape))

    def fn(z, args):
        return two_block_residuals((y0[0] + scale_c * z[0], y0[1] + scale_p * z[1]), problem)

    solver = optx.LevenbergMarquardt(rtol=1e-13, atol=1e-13)
    z0 = (jnp.zeros_like(y0[0]), jnp.zeros_like(y0[1]))
    solution = optx.least_squares(fn, solver, z0, max_steps=500, throw=False)
    return float(0.5 * jnp.sum(fn(solution.value, None) ** 2))


def test_final_cost_matches_dense_levenberg_marquardt(scene, dense, tight_solution):
    problem, truth, y0 = scene
    assert tight_solution.result == optx.RESULTS.successful
    schur_cost = cost(problem, tight_solution.value)
    assert schur_cost < cost(problem, y0)
    dense_cost = _dense_lm_cost(problem, y0, dense[0])
    assert schur_cost == pytest.approx(dense_cost, rel=COST_RTOL)
    # Noise only: ½Σr² ≈ ½ (n_residuals - n_unknowns + 7) σ², far below the start.
    assert schur_cost < cost(problem, truth)


def test_function_tolerance_stops_as_converged(scene, tight_solution):
    problem, _, y0 = scene
    loose = solve_two_block(
        problem, y0, rtol=0.0, atol=1e-12, function_tolerance=1e-6, max_steps=200
    )
    assert loose.result == optx.RESULTS.successful
    assert loose.stats["num_steps"] < tight_solution.stats["num_steps"]
    tight_cost = cost(problem, tight_solution.value)
    assert cost(problem, loose.value) == pytest.approx(tight_cost, rel=1e-6)

