"""Rigs in the core: an image's pose composed from its frame's and its camera's relative pose
(`Parameters.mounts`, `ImagePoints.mount`) against the composed pose written as an ordinary
image, row Jacobians against central differences, the Schur backend against the dense one,
and the formal σ of the baseline and the relative angles against Monte Carlo replicates."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_ATOL, FD_RTOL, central_difference, synthetic_aerial, synthetic_rig

import jaxba
from jaxba._models._poses import OpkPose
from jaxba._problem._parameters import flatten, parameter_labels, unflatten
from jaxba._statistics._rigs import baseline, composed_pose_sigma, composed_poses

COMPOSE_ATOL = 1e-9  # pixels: a rig row against its composed pose as an image row (float64)
BACKEND_ATOL = 1e-8  # unknowns (mm, rad, px), Schur against dense
SIGMA_RTOL = 1e-7  # σ, Schur against dense
# Central differences of whitened pixel residuals (~4000 in magnitude before the difference):
# rounding ~4e-13 / step, truncation ~step²: 1e-4 (relative) balances them below 1e-9.
RIG_FD_STEP = 1e-4
N_REPLICATES = 200
# The empirical σ of N_REPLICATES replicates scatters about the formal one by ~1/sqrt(2N)
# = 5 % (relative); four times that bounds it for every compared quantity.
MONTE_CARLO_RTOL = 0.2


@pytest.fixture(scope="module")
def rig():
    return synthetic_rig(seed=0)


@pytest.fixture(scope="module")
def adjusted(rig):
    problem, _ = rig
    return jaxba.adjust(problem, solver="dense"), jaxba.adjust(problem, solver="schur")


def test_rig_row_is_the_composed_pose(rig):
    """The residuals of rig rows equal those of ordinary image rows whose poses are the
    composition written out: M = M_c M_f, X0 = X0_f + M_fᵀ X0_c."""
    problem, truth = rig
    group = problem.groups[0]
    frame, mount = np.asarray(group.image), np.asarray(group.mount)
    m_f = np.array([np.asarray(OpkPose.from_parameters(r).rotation()) for r in truth.images])
    m_c = np.array([np.asarray(OpkPose.from_parameters(r).rotation()) for r in truth.mounts])
    rotation = np.einsum("nij,njk->nik", m_c[mount], m_f[frame])
    station = (np.asarray(truth.images)[frame, :3]
               + np.einsum("nji,nj->ni", m_f[frame], np.asarray(truth.mounts)[mount, :3]))
    images = np.array([np.asarray(OpkPose.from_rotation(r, x).parameters())
                       for r, x in zip(rotation, station)])
    plain = eqx.tree_at(lambda g: (g.image, g.mount), group,
                        (jnp.arange(frame.size), None), is_leaf=lambda x: x is None)
    expected = plain.residuals(eqx.tree_at(lambda p: p.images, truth, jnp.asarray(images)),
                               problem.refraction)
    got = group.residuals(truth, problem.refraction)
    np.testing.assert_allclose(got, expected, rtol=0, atol=COMPOSE_ATOL)
    np.testing.assert_allclose(composed_poses(truth, "opk", frame[:5], mount[:5]), images[:5],
                               rtol=0, atol=1e-12)


def test_rig_row_jacobians_match_differences(rig):
    """`row_jacobians` (IOP, frame, mount, point columns: `local_values`) against central
    differences of `residuals` of the row alone, its unknowns as one-row blocks."""
    problem, truth = rig
    group = problem.groups[0]
    _, jacobians = group.row_jacobians(truth, problem.refraction)
    values = np.asarray(group.local_values(truth))
    assert values.shape[1] == 10 + 6 + 6 + 3
    @jax.jit
    def residual(v, measured, stddev):  # the row alone, its unknowns as one-row blocks
        one = eqx.tree_at(lambda g: (g.camera, g.image, g.point, g.mount, g.measured, g.stddev),
                          group, (jnp.zeros(1, int),) * 4 + (measured, stddev))
        params = jaxba.Parameters({"opencv": v[None, :10]}, v[None, 10:16], v[None, 22:],
                                  v[None, 16:22])
        return one.residuals(params, problem.refraction)[0]

    for row in (0, 100, 500, 700):  # both cameras
        def f(v, row=row):
            return residual(v, group.measured[row:row + 1], group.stddev[row:row + 1])

        steps = RIG_FD_STEP * np.maximum(1.0, np.abs(values[row]))
        expected = central_difference(f, jnp.asarray(values[row]), steps)
        np.testing.assert_allclose(jacobians[row], expected, rtol=FD_RTOL, atol=FD_ATOL)


def test_schur_matches_dense(adjusted):
    dense, schur = adjusted
    assert dense.converged and schur.converged and schur.backend == "schur"
    np.testing.assert_allclose(flatten(schur.parameters), flatten(dense.parameters),
                               rtol=0, atol=BACKEND_ATOL)
    np.testing.assert_allclose(flatten(schur.precision.std), flatten(dense.precision.std),
                               rtol=SIGMA_RTOL, atol=1e-15)
    for result in adjusted:
        np.testing.assert_allclose(baseline(result.parameters, result.precision, 1),
                                   baseline(dense.parameters, dense.precision, 1),
                                   rtol=SIGMA_RTOL)


def test_labels_and_estimates_name_mounts(rig, adjusted):
    problem, _ = rig
    labels = parameter_labels(problem.initial, {"opencv": ["L", "R"]}, None, None,
                              ["reference", "stereo/right"])
    assert labels[-6:] == [f"mount stereo/right {n}" for n in OpkPose.parameter_names]
    result = jaxba.adjust(problem, labels=labels)
    right = result.mounts["stereo/right"]
    assert right["X0"].status == "free" and right["X0"].sigma > 0
    assert result.mounts["reference"]["phi"].status == "fixed"
    np.testing.assert_allclose(right["X0"].value, adjusted[0].parameters.mounts[1, 0])


def test_composed_sigma_matches_propagation(adjusted):
    """An image's σ composed from its frame and its camera (12 x 12 covariance) against the
    same propagation by finite differences of `composed_poses`."""
    result = adjusted[0]
    params, precision = result.parameters, result.precision
    sigma = composed_pose_sigma(params, precision, "opk", 3, 1)
    values = np.concatenate([params.images[3], params.mounts[1]])

    def compose(v):
        moved = eqx.tree_at(lambda p: (p.images, p.mounts), params,
                            (jnp.asarray(params.images).at[3].set(v[:6]),
                             jnp.asarray(params.mounts).at[1].set(v[6:])))
        return jnp.asarray(composed_poses(moved, "opk", np.array([3]), np.array([1]))[0])

    jacobian = np.asarray(central_difference(compose, jnp.asarray(values), 1e-7))
    positions = unflatten(params, np.arange(flatten(params).size))
    index = np.concatenate([np.asarray(positions.images)[3], np.asarray(positions.mounts)[1]])
    covariance = precision.covariance_of(index)
    expected = np.sqrt(np.diag(jacobian @ covariance @ jacobian.T))
    np.testing.assert_allclose(sigma, expected, rtol=1e-5)


def test_baseline_and_angle_sigma_match_monte_carlo(rig, adjusted):
    """The formal σ of the baseline and of the relative angles against the spread of
    N_REPLICATES re-adjusted replicates with fresh image noise (one batched call)."""
    problem, _ = rig
    result = adjusted[0]
    replicates = jaxba.monte_carlo(problem, N_REPLICATES, jax.random.key(7),
                                   at=result.parameters)
    mounts = np.asarray(replicates.solutions.parameters.mounts)[:, 1]
    empirical = np.concatenate([[np.std(np.linalg.norm(mounts[:, :3], axis=1), ddof=1)],
                                np.std(mounts[:, 3:], axis=0, ddof=1)])
    scale = 1 / result.sigma0  # the replicates' noise is the a priori σ
    formal = np.concatenate([[baseline(result.parameters, result.precision, 1)[1]],
                             np.asarray(result.precision.std.mounts)[1, 3:]]) * scale
    np.testing.assert_allclose(empirical, formal, rtol=MONTE_CARLO_RTOL)


def test_batch_of_rigs_equals_each_alone(adjusted):
    """Two rigs of different sizes padded into one batch (`adjust_batch`): each as
    `adjust` alone, its mounts and their σ included."""
    small, _ = synthetic_rig(seed=1, n_frames=6)
    results = jaxba.adjust_batch([synthetic_rig(seed=0)[0], small])
    for result, alone in zip(results, (adjusted[0], jaxba.adjust(small))):
        assert result.converged
        np.testing.assert_allclose(result.parameters.mounts, alone.parameters.mounts,
                                   rtol=0, atol=BACKEND_ATOL)
        np.testing.assert_allclose(result.precision.std.mounts, alone.precision.std.mounts,
                                   rtol=SIGMA_RTOL, atol=1e-15)


@pytest.mark.parametrize("backend", ["dense", "schur"])
def test_baseline_gradient_through_the_solve(rig, backend):
    """d baseline / d (one measured coordinate of the right camera) through the solve
    (`jaxba.adjusted`, implicit differentiation) against central differences of re-solves."""
    problem, _ = rig
    row = 600  # a right-camera row

    def length(shift):
        group = problem.groups[0]
        moved = eqx.tree_at(lambda g: g.measured, group, group.measured.at[row, 0].add(shift))
        solved = jaxba.adjusted(eqx.tree_at(lambda p: p.groups, problem, (moved,)),
                                backend=backend)
        return jnp.linalg.norm(solved.mounts[1, :3])

    gradient = jax.grad(length)(0.0)
    step = 1e-3  # pixels: the baseline is smooth in the data, the re-solves converge to 1e-10
    expected = (length(step) - length(-step)) / (2 * step)
    assert gradient != 0
    np.testing.assert_allclose(gradient, expected, rtol=1e-5)


def test_reliability_of_a_rig_on_both_backends(adjusted):
    """Redundancy numbers of a rig's image points: the same from the Schur blocks as from
    the dense normal matrix, and they add up to the redundancy."""
    dense, schur = (jaxba.reliability(result) for result in adjusted)
    np.testing.assert_allclose(schur.redundancy_numbers[0], dense.redundancy_numbers[0],
                               rtol=0, atol=1e-9)
    assert np.nansum(dense.redundancy_numbers[0]) == pytest.approx(
        adjusted[0].precision.redundancy, rel=1e-9)


def test_variance_components_of_a_rigs_cameras(rig):
    """Both cameras measured with 0.2 px noise, the right one's σ declared 0.4 px: its
    variance component comes out 0.5 (n = 864 coordinates: ±2.4 %), the left's 1."""
    problem, _ = rig
    group = problem.groups[0]
    right = np.asarray(group.camera) == 1
    stddev = jnp.where(jnp.asarray(right)[:, None], 2 * group.stddev, group.stddev)
    declared = dataclasses.replace(eqx.tree_at(lambda g: g.stddev, group, stddev),
                                   per_camera=True)
    result = jaxba.adjust(eqx.tree_at(lambda p: p.groups, problem, (declared,)))
    _, components, _ = jaxba.estimate_variance_components(result)
    assert components["image_points:1"].sigma0 == pytest.approx(0.5, rel=0.1)
    assert components["image_points:0"].sigma0 == pytest.approx(1.0, rel=0.1)


def test_lever_arm_and_boresight_of_an_aerial_block():
    """A camera on a GNSS/INS platform (`synthetic_aerial`: 3 strips, 60 % / 30 % overlap,
    GNSS 5 cm, INS 0.005 degrees): the body's pose followed by the camera's mount recovers
    the boresight (0.3, -0.2, 0.4 degrees, σ ~0.002-0.01) and the lever arm (15, -25, 30 cm)
    within 3 σ of the truth. The lever arm is weakly determined by the block alone (σ 7-19
    cm: strips flown both ways separate it from the GNSS offsets, barely), as is known."""
    problem, truth = synthetic_aerial()
    result = jaxba.adjust(problem)
    assert result.converged
    mount, sigma = result.parameters.mounts[0], result.precision.std.mounts[0]
    np.testing.assert_array_less(np.abs(mount - truth.mounts[0]), 3 * sigma)
    assert np.all(np.degrees(sigma[3:]) < 0.02)  # the boresight is well determined


def test_four_camera_head():
    """Four cameras at the corners of a 120 mm square (`synthetic_rig(n_cameras=4)`): the
    three relative poses within 3 σ of the truth, the baselines (120, 120, 170 mm) too."""
    problem, truth = synthetic_rig(seed=2, n_frames=6, n_cameras=4)
    result = jaxba.adjust(problem)
    assert result.converged
    mounts, sigma = result.parameters.mounts[1:], result.precision.std.mounts[1:]
    np.testing.assert_array_less(np.abs(mounts - truth.mounts[1:]), 3 * sigma)
    for row in (1, 2, 3):
        length, length_sigma = baseline(result.parameters, result.precision, row)
        assert abs(length - np.linalg.norm(truth.mounts[row, :3])) < 3 * length_sigma
