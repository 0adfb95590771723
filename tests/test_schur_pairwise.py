"""The pair-wise reduced camera matrix of photogrammetric bundles
(`jaxba._solvers._schur._assembly`) against the dense normal equations: S = N_rr - N_re
N_ee⁻¹ N_er, and one damped step when the cameras of one model free different IOPs."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import jacfwd_jacobian, schur_damped_step

import jaxba
from jaxba._problem._bundle import free_indices
from jaxba._problem._parameters import flatten, unflatten
from jaxba._solvers._schur._assembly import bundle_normal_equations, schur_complement
from jaxba._solvers._schur._columns import reduced_positions
from jaxba._solvers._schur._normal import marquardt_diagonal, small_inverse
from jaxba._solvers._schur._structure import bundle_structure

RTOL = 1e-9  # Schur blocks vs dense normal equations (float64)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """8 images, 2 SMAC cameras (8 free IOPs each), GNSS/INS, 4 distances."""
    truth = jaxba.write_synthetic_project(
        tmp_path_factory.mktemp("pairwise"),
        seed=3, n_images=8, n_targets=30, n_cameras=2, gnss_sigma=(0.05, 0.01),
    )  # fmt: skip
    return jaxba.build_project(jaxba.read_project(truth.project_file)).problem


def _dense_normal(problem):
    """JᵀJ over the free unknowns and the flatten positions of its rows."""
    jacobian, _ = jacfwd_jacobian(problem, problem.initial)
    return np.asarray(jacobian.T @ jacobian), np.asarray(free_indices(problem))


@eqx.filter_jit
def _reduced_camera_matrix(problem, structure):
    """S = N_rr - N_re N_ee⁻¹ N_er at the approximations, as one program (op by op it compiled
    ~500 small programs)."""
    normal = bundle_normal_equations(problem, structure, problem.initial)
    product, _ = schur_complement(structure, normal, small_inverse(normal.point_hessian))
    return normal.reduced_hessian + product


def test_schur_complement_matches_dense(block):
    structure = bundle_structure(block)
    reduced = np.asarray(_reduced_camera_matrix(block, structure))

    hessian, index = _dense_normal(block)
    row_of = np.full(flatten(block.initial).size, -1)
    row_of[index] = np.arange(index.size)
    rows = row_of[reduced_positions(block, structure)]
    free = rows >= 0
    r = rows[free]
    e = np.setdiff1d(np.arange(index.size), r)
    expected = hessian[np.ix_(r, r)] - hessian[np.ix_(r, e)] @ np.linalg.solve(
        hessian[np.ix_(e, e)], hessian[np.ix_(e, r)]
    )
    np.testing.assert_allclose(
        reduced[np.ix_(free, free)], expected, rtol=RTOL, atol=RTOL * np.abs(expected).max()
    )


def test_cameras_freeing_different_iops(block):
    """IOP columns are those free in some camera of the model; the others stay fixed."""
    free = np.asarray(block.free.cameras["smac"]).copy()
    free[0, 3], free[1, 6] = True, False  # camera 0 frees IOP 3, camera 1 fixes IOP 6
    problem = eqx.tree_at(lambda p: p.free.cameras["smac"], block, jnp.asarray(free))
    structure = bundle_structure(problem)
    assert structure.iop_columns == ((0, 1, 2, 3, 4, 5, 6, 7, 8),)
    step_parameters, _ = schur_damped_step(problem, structure, problem.initial,
                                           jnp.asarray(1e-3))
    step = flatten(step_parameters)
    jacobian, residual = jacfwd_jacobian(problem, problem.initial)
    hessian = jacobian.T @ jacobian
    diagonal = marquardt_diagonal(jnp.diagonal(hessian), 1e-6, 1e32)
    expected = jnp.linalg.solve(hessian + 1e-3 * jnp.diag(diagonal), jacobian.T @ residual)
    index = free_indices(problem)
    np.testing.assert_allclose(
        step[index], expected, rtol=RTOL, atol=RTOL * np.abs(expected).max()
    )
    fixed = unflatten(problem.initial, ~flatten(problem.free))
    assert np.all(np.asarray(step_parameters.cameras["smac"])
                  [np.asarray(fixed.cameras["smac"])] == 0.0)
