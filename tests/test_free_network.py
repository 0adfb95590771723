"""Free-network datum (inner constraints) against the lab's control datum."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._statistics._adjustable import adjustable
from jaxba._statistics._datum import similarity_transform
from jaxba._statistics._free_network import (
    free_network_precision,
    inner_constraint_group,
    to_inner_datum,
)
from jaxba.advanced import flatten, unflatten

GAUGE_RTOL = 1e-6  # gauge-invariant quantities agree across minimal datums


def _adjust(truth, **settings):
    if settings:
        lines = "".join(f"\n{key} = {value}" for key, value in settings.items())
        text = truth.project_file.read_text().replace("[adjustment]", "[adjustment]" + lines)
        truth.project_file.write_text(text)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    return project, jaxba.adjust_project(project)


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The same block with the lab datum (6 fixed coordinates) and as a free network.

    Its own block, not the session's shared one: the IOPs must agree to 1e-6 σ, tighter
    than the stopping rule promises (√(1e-12 r) σ ≈ 5e-5 σ), which this block's two solves
    meet and the shared block's do not (K3 5e-6 σ apart)."""
    directory = tmp_path_factory.mktemp("network")
    truth = jaxba.write_synthetic_project(directory, seed=4, noise_px=0.3)
    control = _adjust(truth)
    free = _adjust(truth, datum='"free"')
    return control, free


def test_free_network_converges_with_the_same_redundancy(both):
    (_, control), (project, free) = both
    assert control.converged and free.converged
    assert free.precision.redundancy == control.precision.redundancy
    assert free.sigma0 == pytest.approx(control.sigma0, rel=1e-9)
    constraints = [g for g in project.problem.groups if isinstance(g, jaxba.InnerConstraints)]
    assert len(constraints) == 1 and constraints[0].stddev.shape == (6, 1)  # scale from distances


def test_gauge_invariant_quantities_agree(both):
    (_, control), (_, free) = both
    for result_a, result_b in [(control, free)]:
        iop_a = np.asarray(result_a.parameters.cameras["smac"][0])
        iop_b = np.asarray(result_b.parameters.cameras["smac"][0])
        std_a = np.asarray(result_a.precision.std.cameras["smac"][0])
        std_b = np.asarray(result_b.precision.std.cameras["smac"][0])
        free_iop = std_a > 0
        assert np.all(np.abs(iop_a - iop_b)[free_iop] < 1e-6 * std_a[free_iop])
        np.testing.assert_allclose(std_b, std_a, rtol=GAUGE_RTOL)

    def distance(params):
        return jnp.linalg.norm(params.points[3] - params.points[50])

    value_a, var_a = jaxba.propagate(control, distance)
    value_b, var_b = jaxba.propagate(free, distance)
    assert float(value_b) == pytest.approx(float(value_a), abs=1e-6 * np.sqrt(var_a[0, 0]))
    assert var_b[0, 0] == pytest.approx(var_a[0, 0], rel=GAUGE_RTOL)


def test_covariance_is_the_inner_constraint_one(both):
    (_, control), (project, free) = both
    group = next(g for g in project.problem.groups if isinstance(g, jaxba.InnerConstraints))
    directions = np.asarray(group.directions)
    covariance = jaxba.full_covariance(free)
    # Bᵀ Cxx = 0: the constrained datum directions carry no variance.
    scale = np.abs(directions).max() * np.sqrt(np.abs(np.diag(covariance)).max())
    assert np.abs(directions @ covariance).max() < 1e-9 * scale * np.abs(directions).sum(1).max()
    # ... and of all datums it gives the points the smallest total variance.
    trace_free = np.trace(jaxba.point_covariances(free).sum(0))
    trace_control = np.trace(jaxba.point_covariances(control).sum(0))
    assert trace_free < trace_control
    total_r = sum(np.nansum(r) for r in free.reliability.redundancy_numbers)
    assert total_r == pytest.approx(free.precision.redundancy, rel=1e-9)


def test_datum_points_subset_and_seven_parameter_defect(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_distances=0)
    project, result = _adjust(truth, datum='"free"', datum_points='["1", "10", "40", "71"]')
    assert result.converged
    group = next(g for g in project.problem.groups if isinstance(g, jaxba.InnerConstraints))
    assert group.stddev.shape == (7, 1)  # no distances: scale is part of the defect
    positions = np.asarray(unflatten(result.parameters,
                                           np.arange(flatten(result.parameters).size))
                           .points)
    datum_rows = [project.point_ids.index(p) for p in ("1", "10", "40", "71")]
    others = np.setdiff1d(np.arange(len(project.point_ids)), datum_rows)
    assert np.all(np.asarray(group.directions)[:, positions[others].ravel()] == 0)


def test_unknown_datum_point_is_refused(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3)
    text = truth.project_file.read_text().replace(
        "[adjustment]", '[adjustment]\ndatum = "free"\ndatum_points = ["nope"]')
    truth.project_file.write_text(text)
    with pytest.raises(jaxba.ProjectError, match="nope"):
        jaxba.build_project(jaxba.read_project(truth.project_file))


@pytest.fixture(scope="module")
def free_block(tmp_path_factory):
    """The seed-4 block as a free network without distances (a 7-parameter defect),
    adjusted on the dense backend (inner constraints adjusted as observations)."""
    truth = jaxba.write_synthetic_project(
        tmp_path_factory.mktemp("free"), seed=4, noise_px=0.3, n_distances=0)
    return _adjust(truth, datum='"free"', solver='"dense"')


def _similar(params, theta):
    centre = np.mean(np.asarray(params.points), axis=0)
    return eqx.filter_jit(similarity_transform)(params, jnp.asarray(theta), centre)


def test_schur_free_network_solves_to_the_inner_constraint_datum(free_block):
    project, dense = free_block
    schur = jaxba.adjust_project(project, solver="schur")
    assert schur.converged and schur.backend == "schur"
    datum = f"free network: inner constraints (7 conditions) over {len(project.point_ids)} points"
    assert f"datum          {datum}\n" in schur.summary()
    assert schur.sigma0 == pytest.approx(dense.sigma0, rel=1e-9)
    assert schur.precision.redundancy == dense.precision.redundancy
    group = inner_constraint_group(project.problem)
    violation = np.asarray(group.residuals(schur.parameters, project.problem.refraction))[:, 0]
    # Bᵀ(x - x₀) sums terms of up to ~1e7 here: zero to rounding relative to their sizes.
    terms = np.abs(np.asarray(group.directions)) @ np.abs(flatten(schur.parameters))
    assert np.all(np.abs(violation) < 1e-13 * terms)
    std = np.asarray(flatten(dense.precision.std))
    free = std > 0
    difference = np.abs(np.asarray(flatten(schur.parameters))
                        - np.asarray(flatten(dense.parameters)))
    assert np.max(difference[free] / std[free]) < 1e-3  # two solves, each converged


def test_to_inner_datum_undoes_a_similarity(free_block):
    project, dense = free_block
    moved = _similar(dense.parameters, [0.3, -0.2, 0.1, 2e-3, -1e-3, 3e-3, 1e-3])
    back = to_inner_datum(project.problem, moved)
    np.testing.assert_allclose(flatten(back), flatten(dense.parameters),
                               rtol=0, atol=1e-9)


def test_s_transformed_covariance_equals_the_bordered_inverse(free_block):
    """At the same parameters the Schur route's covariance blocks and redundancy numbers
    equal the dense inner-constraint ones (bordered normal matrix), and the datum points'
    constraint directions carry no variance."""
    project, dense = free_block
    problem, params = project.problem, dense.parameters
    transformed = free_network_precision(problem, params)
    bordered = jaxba.precision(problem, params)
    np.testing.assert_allclose(flatten(transformed.std), flatten(bordered.std),
                               rtol=1e-9, atol=0)
    np.testing.assert_allclose(transformed.schur.points, _point_blocks(bordered, params),
                               rtol=0, atol=1e-9 * np.abs(transformed.schur.points).max())
    reduced = transformed.schur.reduced_positions
    np.testing.assert_allclose(transformed.schur.reduced, bordered.covariance_of(reduced),
                               rtol=0, atol=1e-9 * np.abs(transformed.schur.reduced).max())
    r_schur, e_schur = adjustable(problem, "schur").redundancy_numbers(params)
    r_dense, e_dense = adjustable(problem, "dense").redundancy_numbers(params)
    np.testing.assert_allclose(r_schur, r_dense, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e_schur, e_dense, rtol=0, atol=1e-9)


def _point_blocks(precision, params):
    positions = np.asarray(unflatten(params, np.arange(flatten(params).size))
                           .points)
    return np.stack([precision.covariance_of(row) for row in positions])


@pytest.fixture(scope="module")
def unkind(tmp_path_factory):
    """The close-range block of `write_close_range_project` (seed 3, 12 images, 400 wall
    points): with the old minimal datum (the point coordinates a similarity moves the
    most, i.e. far 2-ray points) its free Schur solve crawled to 100 steps unconverged;
    here it is adjusted with the dependent datum and as a free network, on both backends."""
    results = {}
    for datum in ("dependent", "free"):
        truth = jaxba.write_close_range_project(tmp_path_factory.mktemp(datum), seed=3,
                                                n_images=12, n_points=400, datum=datum)
        project = jaxba.build_project(jaxba.read_project(truth.project_file))
        for solver in ("schur", "dense"):
            results[datum, solver] = jaxba.adjust_project(project, solver=solver)
    return results


@pytest.mark.parametrize("solver", ["schur", "dense"])
def test_free_network_on_an_unkind_block_converges_as_the_dependent_datum(unkind, solver):
    """Same σ̂0 and IOPs to 1e-9, the same σ of the IOPs, residuals and redundancy numbers
    (gauge invariant) to `GAUGE_RTOL`, in no more iterations than the dependent datum."""
    dependent, free = unkind["dependent", solver], unkind["free", solver]
    assert dependent.converged and free.converged
    assert free.steps <= dependent.steps
    assert free.sigma0 == pytest.approx(dependent.sigma0, rel=1e-9)
    iop_a = np.asarray(dependent.parameters.cameras["smac"][0])
    iop_b = np.asarray(free.parameters.cameras["smac"][0])
    std_a = np.asarray(dependent.precision.std.cameras["smac"][0])
    std_b = np.asarray(free.precision.std.cameras["smac"][0])
    np.testing.assert_allclose(iop_b, iop_a, rtol=1e-9, atol=1e-9 * std_a.max())
    np.testing.assert_allclose(std_b, std_a, rtol=GAUGE_RTOL)
    residuals_a = np.concatenate([np.ravel(r) for r in dependent.residuals])
    residuals_b = np.concatenate([np.ravel(r) for r in free.residuals])[:residuals_a.size]
    np.testing.assert_allclose(residuals_b, residuals_a, rtol=0,
                               atol=1e-6 * np.abs(residuals_a).max())
    r_a = np.concatenate([np.ravel(r) for r in dependent.reliability.redundancy_numbers])
    r_b = np.concatenate([np.ravel(r) for r in free.reliability.redundancy_numbers])
    np.testing.assert_allclose(r_b[:r_a.size], r_a, rtol=0, atol=GAUGE_RTOL)
