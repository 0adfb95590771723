"""`normal_equations` (per-row Jacobian blocks gathered by key) against JᵀJ and Jᵀẽ of a dense
forward-mode Jacobian of all residuals: two SMAC cameras with GNSS/INS and distances, weighted
control under a Huber loss, a free network (inner constraints: a group that is not row-local),
Zhang's OpenCV-camera calibration, the same with fy tied to fx, and a block whose points are
all fixed (its distances depend on no free unknown)."""

import pathlib
import shutil

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import jacfwd_jacobian, with_control_and_huber

import jaxba
from jaxba._problem._bundle import free_indices
from jaxba._problem._linearisation import _add_key_products, dense_jacobian, normal_equations
from jaxba.advanced import flatten, unflatten

CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"
NORMAL_RTOL = 1e-10  # in units of the columns' norms: the same float64 sums in another order
RESIDUAL_RTOL = 1e-12  # the same residual formula evaluated along another path


def _synthetic(directory, datum_line=None, **kwargs):
    truth = jaxba.write_synthetic_project(directory, **kwargs)
    if datum_line is not None:
        text = truth.project_file.read_text().replace("[adjustment]", "[adjustment]\n" + datum_line)
        truth.project_file.write_text(text)
    return jaxba.build_project(jaxba.read_project(truth.project_file)).problem


@pytest.fixture(scope="module", params=["two_cameras_gnss", "control_huber", "free_network",
                                        "zhang_opencv", "zhang_fy_tied_to_fx",
                                        "fixed_points"])
def problem(request, tmp_path_factory):
    directory = tmp_path_factory.mktemp(request.param)
    if request.param == "two_cameras_gnss":
        return _synthetic(directory, seed=3, n_images=6, n_targets=25, n_cameras=2,
                          gnss_sigma=(0.05, 0.01))
    if request.param == "control_huber":
        return with_control_and_huber(
            _synthetic(directory, seed=5, n_images=6, n_targets=25), [2, 5, 9])
    if request.param == "free_network":
        return _synthetic(directory, 'datum = "free"', seed=4, n_images=6, n_targets=25)
    if request.param == "fixed_points":
        problem = _synthetic(directory, seed=6, n_images=6, n_targets=25, n_distances=3)
        assert any(isinstance(group, jaxba.Distances) for group in problem.groups)
        return eqx.tree_at(lambda p: p.free.points, problem,
                           jnp.zeros_like(problem.free.points))
    if request.param == "zhang_fy_tied_to_fx":
        shutil.copytree(CONFIGS / "zhang", directory, dirs_exist_ok=True)
        cameras = directory / "cameras.toml"
        free = 'free = ["fx", "fy", "cx", "cy", "skew", "k1", "k2"]'
        assert free in cameras.read_text()
        cameras.write_text(cameras.read_text().replace(
            free, 'free = ["fx", "cx", "cy", "skew", "k1", "k2"]\nties = { fy = "fx" }'))
        problem = jaxba.build_project(jaxba.read_project(directory / "zhang.toml")).problem
        assert problem.ties
        return problem
    return jaxba.build_project(jaxba.read_project(CONFIGS / "zhang" / "zhang.toml")).problem


def _dense_normal_equations(problem, params):
    """JᵀJ, Jᵀẽ and |ẽ| (NumPy) with J, ẽ = `jacfwd_jacobian` (jax.jacfwd of all residuals
    w.r.t. the free unknowns; rows of masked entries, which are zero, left out)."""
    jacobian, residuals = (np.asarray(a) for a in jacfwd_jacobian(problem, params))
    return jacobian.T @ jacobian, jacobian.T @ residuals, np.linalg.norm(residuals)


def test_normal_equations_match_a_dense_jacobian(problem):
    index = free_indices(problem)
    # Away from the optimum, so that the residuals (and the Huber loss's clipping) matter; a
    # point the solver can reach (`with_free`): tied entries at their sources' values.
    flat = flatten(problem.initial)
    scale = np.where(np.abs(flat[index]) > 1, 1e-4, 1e-3)
    flat[index] += np.random.default_rng(0).normal(size=index.size) * scale
    params = problem.with_free(unflatten(problem.initial, flat))
    plan = jaxba.advanced.linearisation_plan(problem)
    normal, gradient = (np.asarray(a) for a in jax.jit(normal_equations)(problem, params, plan))
    dense_normal, dense_gradient, residual_norm = _dense_normal_equations(problem, params)
    # Each entry in units of its columns' norms |J_i| |J_j| (and |J_i| |ẽ| for Jᵀẽ): a
    # correlation-like scale in which every unknown counts, whatever its units.
    column_norm = np.sqrt(np.diag(dense_normal))
    assert np.all(column_norm > 0)
    normal_error = np.abs(normal - dense_normal) / np.outer(column_norm, column_norm)
    gradient_error = np.abs(gradient - dense_gradient) / (column_norm * residual_norm)
    assert normal_error.max() < NORMAL_RTOL
    assert gradient_error.max() < NORMAL_RTOL


def test_dense_jacobian_from_row_blocks_matches_forward_mode(problem):
    """The statistics' dense J (per-row reverse-mode blocks scattered into free columns)
    equals forward mode over all residuals, entry by entry, and so do the residuals."""
    params = problem.initial
    jacobian, residuals = dense_jacobian(problem, params)
    reference, reference_residuals = jacfwd_jacobian(problem, params)
    assert jacobian.shape == reference.shape
    scale = np.linalg.norm(np.asarray(reference), axis=0)
    np.testing.assert_allclose(np.asarray(jacobian) / scale, np.asarray(reference) / scale,
                               rtol=0, atol=NORMAL_RTOL)
    np.testing.assert_allclose(residuals, reference_residuals, rtol=RESIDUAL_RTOL, atol=0)


@pytest.mark.parametrize("rows", [1, 2, 3, 40])
def test_key_products_of_few_rows_equal_the_whole_blocks(rows):
    """`_add_key_products` adds BᵀB of each key at its columns: keys of few rows (each pair
    of slots added once and mirrored) and of many (whole blocks) give the scatter of every
    entry, with slots that share a column (ties) and slots on the dropped column n."""
    rng = np.random.default_rng(rows)
    keys, slots, n = 30, 7, 12
    blocks = rng.normal(size=(keys, rows, slots))
    columns = rng.integers(0, n + 1, size=(keys, slots))  # n: the dropped column
    columns[:, 3] = columns[:, 1]  # two slots of every row on one column
    start = rng.normal(size=(n + 1, n + 1))
    start = start + start.T
    expected = start.copy()
    for b, c in zip(blocks, columns):
        np.add.at(expected, (c[:, None], c[None, :]), b.T @ b)
    added = np.asarray(_add_key_products(jnp.asarray(start), jnp.asarray(columns),
                                         jnp.asarray(blocks)))
    np.testing.assert_allclose(added, expected, rtol=1e-13, atol=1e-12)
