"""End-to-end adjustment of independent synthetic blocks (jaxba._io._synthetic, NumPy model)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SYNTHETIC_BLOCK

import jaxba
from jaxba._problem._checks import ProblemError
from jaxba._statistics._datum import check_datum_schur

# A result is "recovered" when it is within this many of its reported σ of the truth.
RECOVERY_SIGMAS = 4.0
# σ̂0 when the prior σ equals the simulated noise; r ≈ 2500 gives std(σ̂0) ≈ 1.4 %.
SIGMA0_TOLERANCE = 0.10
FREE_IOPS = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2")


def _adjust(directory, **kwargs):
    truth = jaxba.write_synthetic_project(directory, **kwargs)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    return truth, project, jaxba.adjust_project(project)


@pytest.fixture(scope="module")
def lab(synthetic_block):
    """An 18-image block, datum of 6 fixed coordinates plus four distances (the lab's)."""
    return synthetic_block


def test_converges_with_unit_variance_factor(lab):
    _, project, result = lab
    assert result.converged, result.message
    assert abs(result.sigma0 - 1.0) < SIGMA0_TOLERANCE
    costs = [it.cost for it in result.iterations]
    assert costs[-1] < 1e-3 * costs[0]
    assert result.precision.redundancy == (
        project.problem.n_observations() - project.problem.n_unknowns()
    )
    sigma0_squared = [it.sigma0_squared for it in result.iterations]
    assert math.isclose(sigma0_squared[-1], result.precision.sigma0_squared, rel_tol=1e-8)


def test_recovers_interior_orientation_within_its_sigma(lab):
    truth, project, result = lab
    model, row = project.camera_rows["C1"]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    values = np.asarray(result.parameters.cameras[model][row])
    std = np.asarray(result.precision.std.cameras[model][row])
    for name in FREE_IOPS:
        k = names.index(name)
        assert std[k] > 0, name
        assert abs(values[k] - truth.cameras["C1"][name]) < RECOVERY_SIGMAS * std[k], name
    for name in set(names) - set(FREE_IOPS):
        k = names.index(name)
        assert std[k] == 0 and values[k] == 0, name


def test_recovers_exterior_orientation_within_its_sigma(lab):
    truth, project, result = lab
    values = np.asarray(result.parameters.images)
    std = np.asarray(result.precision.std.images)
    for row, image_id in enumerate(project.image_ids):
        true = np.asarray(truth.images[image_id], dtype=float)
        difference = values[row] - np.r_[true[:3], np.radians(true[3:])]
        difference[3:] = (difference[3:] + np.pi) % (2 * np.pi) - np.pi
        assert np.all(np.abs(difference) < RECOVERY_SIGMAS * std[row]), image_id


def test_fixed_control_stays_put_and_points_are_recovered(lab):
    truth, project, result = lab
    free = np.asarray(project.problem.free.points)
    values = np.asarray(result.parameters.points)
    std = np.asarray(result.precision.std.points)
    true = np.array([truth.points[p] for p in project.point_ids])
    assert (~free).sum() == 6
    np.testing.assert_array_equal(values[~free], np.asarray(project.problem.initial.points)[~free])
    np.testing.assert_allclose(values[~free], true[~free], atol=1e-9)  # files hold 9 decimals
    assert np.all(std[~free] == 0)
    outside = np.abs(values - true)[free] > RECOVERY_SIGMAS * std[free]
    # 4σ bounds on ~234 coordinates: expect none outside; allow one by chance.
    assert outside.sum() <= 1


def test_pixel_units_give_the_same_adjustment(tmp_path, lab):
    _, _, result_mm = lab
    _, _, result_px = _adjust(tmp_path, **SYNTHETIC_BLOCK, image_units="pixel")
    # Files round coordinates to 1e-8 (mm or px): results agree far below their σ.
    iop_mm = np.asarray(result_mm.parameters.cameras["smac"][0])
    iop_px = np.asarray(result_px.parameters.cameras["smac"][0])
    std = np.asarray(result_mm.precision.std.cameras["smac"][0])
    free = std > 0
    assert np.all(np.abs(iop_mm - iop_px)[free] < 1e-3 * std[free])
    assert math.isclose(result_mm.sigma0, result_px.sigma0, rel_tol=1e-4)


def test_missing_scale_is_refused_before_solving(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=7, n_distances=0)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    with pytest.raises(jaxba.DatumError, match="scale"):
        jaxba.adjust_project(project)


# The dense check (SVD of the Jacobian) and the one from the Schur split (large bundles).
DATUM_CHECKS = {"dense": jaxba.check_datum, "schur": check_datum_schur}


def test_schur_datum_check_passes_a_determined_block_and_names_missing_scale(tmp_path, lab):
    _, project, _ = lab
    check_datum_schur(project.problem, labels=project.labels)
    truth = jaxba.write_synthetic_project(tmp_path, seed=7, n_distances=0)
    no_scale = jaxba.build_project(jaxba.read_project(truth.project_file))
    with pytest.raises(jaxba.DatumError, match="rank deficiency 1.*scale"):
        check_datum_schur(no_scale.problem, labels=no_scale.labels)


@pytest.mark.parametrize("check", DATUM_CHECKS)
def test_no_datum_at_all_names_translation_rotation_and_scale(tmp_path, check):
    truth = jaxba.write_synthetic_project(tmp_path, seed=7, datum="none", n_distances=0)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    with pytest.raises(jaxba.DatumError) as error:
        DATUM_CHECKS[check](project.problem, labels=project.labels)
    message = str(error.value)
    assert "rank deficiency 7" in message
    for word in ("translation in X", "rotation about Z", "scale"):
        assert word in message


@pytest.mark.parametrize("check", DATUM_CHECKS)
def test_point_on_a_single_ray_is_named(lab, check):
    """A tie point seen from two images taken at one station has no depth: name it."""
    _, project, _ = lab
    problem = project.problem
    group = problem.groups[0]
    point = 40
    seen_in = np.flatnonzero(np.asarray(group.point) == point)
    keep = (np.asarray(group.point) != point) | np.isin(np.arange(group.point.size), seen_in[:2])
    image_a, image_b = np.asarray(group.image)[seen_in[:2]]
    thinned = eqx.tree_at(
        lambda g: (g.camera, g.image, g.point, g.measured, g.stddev),
        group,
        tuple(leaf[keep] for leaf in (group.camera, group.image, group.point,
                                      group.measured, group.stddev)),
    )
    images = problem.initial.images.at[image_b, :3].set(problem.initial.images[image_a, :3])
    degenerate = eqx.tree_at(
        lambda p: (p.groups, p.initial.images), problem, ((thinned, *problem.groups[1:]), images)
    )
    with pytest.raises(jaxba.DatumError) as error:
        DATUM_CHECKS[check](degenerate, labels=project.labels)
    message = str(error.value)
    point_id = project.point_ids[point]
    a, b = sorted([project.image_ids[image_a], project.image_ids[image_b]])
    assert message.startswith(f"rank deficiency 1: images {a} and {b} have the same"
                              " projection centre ("), message
    assert message.endswith(f": point {point_id} is seen from that station only and cannot"
                            " be intersected"), message


def test_non_convergence_is_reported_not_hidden(lab):
    _, project, _ = lab
    result = jaxba.adjust(project.problem, max_steps=2, labels=project.labels)
    assert not result.converged
    assert "maximum number of steps" in result.message.lower()
    with pytest.raises(jaxba.NotConvergedError):
        jaxba.adjust(project.problem, max_steps=2, throw=True)


def test_schur_datum_check_with_nothing_free_but_points(lab):
    """A forward intersection (every IOP and EOP known, no distances): no reduced unknown
    is free, and both checks pass."""
    _, project, _ = lab
    problem = project.problem
    groups = tuple(g for g in problem.groups if not isinstance(g, jaxba.Distances))
    fixed = eqx.tree_at(
        lambda p: (p.groups, p.free.cameras["smac"], p.free.images),
        problem,
        (groups, jnp.zeros_like(problem.free.cameras["smac"]),
         jnp.zeros_like(problem.free.images)),
    )
    jaxba.check_datum(fixed, labels=project.labels)
    check_datum_schur(fixed, labels=project.labels)


def _grown(problem, block, free_row):
    """`problem` with one more row in `block` ("images" or a camera model), a copy of its
    first, with the free mask `free_row`: an image or camera no observation reaches."""
    if block == "images":
        where = lambda params: params.images  # noqa: E731
    else:
        where = lambda params: params.cameras[block]  # noqa: E731
    initial, free = (eqx.tree_at(where, params, jnp.concatenate([where(params),
                                                                where(params)[:1]]))
                     for params in (problem.initial, problem.free))
    free = eqx.tree_at(where, free, where(free).at[-1].set(free_row))
    return eqx.tree_at(lambda p: (p.initial, p.free), problem, (initial, free))


@pytest.mark.parametrize("case", ["observations", "unknowns", "image", "camera"])
def test_empty_and_degenerate_problems_are_named_before_jax(lab, case):
    """No observations, nothing free, an image with no points, a camera with no images:
    a `ProblemError` naming what is missing (not jax's "Need at least one array")."""
    _, project, _ = lab
    problem = project.problem
    model = next(iter(problem.initial.cameras))
    if case == "observations":
        problem, message = eqx.tree_at(lambda p: p.groups, problem, ()), "no observations"
    elif case == "unknowns":
        problem = eqx.tree_at(lambda p: p.free, problem,
                              jax.tree.map(jnp.zeros_like, problem.free))
        message = "no free unknowns"
    elif case == "image":
        problem, message = _grown(problem, "images", True), "image 18: no image points"
    else:
        problem, message = _grown(problem, model, True), "camera 1: no image was taken"
    with pytest.raises(ProblemError, match=message):
        jaxba.adjust(problem)
    if case in ("image", "camera"):  # fixed, the extra row is no unknown: adjusted as before
        fixed = _grown(project.problem, "images" if case == "image" else model, False)
        assert jaxba.adjust(fixed).converged
