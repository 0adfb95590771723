"""`adjust(solver="schur")`: the object points eliminated from the solve, the datum check and
the statistics (covariance in blocks, redundancy numbers, variance components, data snooping)
give what the dense adjustment gives, on a synthetic self-calibration block (two cameras,
GNSS/INS, distances, a planted blunder)."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba import _programs
from jaxba._solvers._schur._choice import SCHUR_MIN_UNKNOWNS, use_schur
from jaxba._statistics._covariance import SchurCovariance
from jaxba.advanced import flatten

SIGMA_RTOL = 1e-6  # σ, correlations, covariances: the two solves stop ~1e-6 σ apart
PARAMETER_SIGMAS = 1e-4  # adjusted unknowns agree to this fraction of their σ
REDUNDANCY_ATOL = 1e-6
# √cofactors of a bundle whose point is held by a pseudo-inverse against one whose point
# coordinate is fixed: the pseudo-inverse drops the rays' ~1e-16 relative information on
# depth, and the two solves stop ~1e-6 σ apart.
COFACTOR_RTOL = 1e-5

# ~2 min for the module: one dense and one Schur adjustment with variance components and data
# snooping (each re-adjusts), shared by every test.
pytestmark = pytest.mark.slow


def _project(directory, **settings):
    sigma_mm = 0.3 * 0.00369
    truth = jaxba.write_synthetic_project(
        directory, seed=21, n_images=8, n_targets=30, n_cameras=2, noise_px=0.3,
        gnss_sigma=(0.05, 0.01), blunders=[("img03", "17", 0, 25 * sigma_mm)],
    )  # fmt: skip
    lines = "".join(f"\n{key} = {value}" for key, value in settings.items())
    text = truth.project_file.read_text().replace("[adjustment]", "[adjustment]" + lines)
    truth.project_file.write_text(text)
    return jaxba.build_project(jaxba.read_project(truth.project_file))


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The same project adjusted densely and with its points eliminated, with variance
    components and data snooping."""
    project = _project(tmp_path_factory.mktemp("schur_adjust"), variance_components="true",
                       data_snooping="true")
    dense = jaxba.adjust_project(project, solver="dense")
    schur = jaxba.adjust_project(project, solver="schur")
    return project, dense, schur


def test_auto_picks_schur_by_size(both, tmp_path):
    project, _, _ = both
    assert not use_schur(project.problem)  # ~300 unknowns
    assert use_schur(project.problem, "schur") and not use_schur(project.problem, "dense")
    assert SCHUR_MIN_UNKNOWNS >= 1000
    with pytest.raises(ValueError, match="solver must be one of"):
        use_schur(project.problem, "qr")
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, n_images=6, n_targets=25)
    text = truth.project_file.read_text().replace("[adjustment]", '[adjustment]\ndatum = "free"')
    truth.project_file.write_text(text)
    free = jaxba.build_project(jaxba.read_project(truth.project_file))
    assert use_schur(free.problem, "schur") and not use_schur(free.problem)  # small: dense


def test_parameters_sigma0_and_sigmas_agree(both):
    _, dense, schur = both
    assert dense.converged and schur.converged
    assert dense.precision.covariance is not None and dense.precision.schur is None
    assert schur.precision.covariance is None
    assert isinstance(schur.precision.schur, SchurCovariance)
    assert schur.sigma0 == pytest.approx(dense.sigma0, rel=1e-8)
    assert schur.precision.redundancy == dense.precision.redundancy
    std = flatten(dense.precision.std)
    np.testing.assert_allclose(flatten(schur.precision.std), std, rtol=SIGMA_RTOL)
    difference = np.abs(flatten(schur.parameters) - flatten(dense.parameters))
    free = std > 0
    assert np.all(difference[free] <= PARAMETER_SIGMAS * std[free])
    assert np.all(difference[~free] == 0)


def test_correlations_point_covariances_and_propagation_agree(both):
    project, dense, schur = both
    for model, row in project.camera_rows.values():
        names_d, rho_d = jaxba.camera_correlation(dense, model, row)
        names_s, rho_s = jaxba.camera_correlation(schur, model, row)
        assert names_s == names_d
        np.testing.assert_allclose(rho_s, rho_d, rtol=0, atol=SIGMA_RTOL)
    points_d, points_s = jaxba.point_covariances(dense), jaxba.point_covariances(schur)
    np.testing.assert_allclose(points_s, points_d, rtol=SIGMA_RTOL,
                               atol=SIGMA_RTOL * np.abs(points_d).max())
    distances = next(g for g in project.problem.groups if isinstance(g, jaxba.Distances))
    a, b = int(distances.a[0]), int(distances.b[0])  # reduced points (in a distance)

    def span(params):
        return jnp.linalg.norm(params.points[a] - params.points[b])

    def camera_constants(params):  # IOPs of both cameras: reduced unknowns
        return jnp.stack([params.cameras["smac"][0, 2], params.cameras["smac"][1, 2]])

    def one_point(params):  # an eliminated point's coordinates
        return params.points[10] * 2.0

    for function in (span, camera_constants, one_point):
        value_d, covariance_d = jaxba.propagate(dense, function)
        value_s, covariance_s = jaxba.propagate(schur, function)
        np.testing.assert_allclose(covariance_s, covariance_d, rtol=SIGMA_RTOL,
                                   atol=SIGMA_RTOL * np.abs(covariance_d).max())

    def point_and_camera(params):  # an eliminated point with an IOP: not in the blocks
        return params.points[10, 0] + params.cameras["smac"][0, 2]

    with pytest.raises(ValueError, match="eliminated"):
        jaxba.propagate(schur, point_and_camera)


def test_reliability_variance_components_and_snooping_agree(both):
    _, dense, schur = both
    assert [(r.group, r.row, r.coordinate) for r in schur.rejections] == [
        (r.group, r.row, r.coordinate) for r in dense.rejections]
    assert len(dense.rejections) >= 1
    for r_s, r_d in zip(schur.reliability.redundancy_numbers, dense.reliability.redundancy_numbers):
        np.testing.assert_allclose(r_s, r_d, rtol=0, atol=REDUNDANCY_ATOL)
    assert dense.variance_components.keys() == schur.variance_components.keys()
    for name, component in dense.variance_components.items():
        other = schur.variance_components[name]
        assert other.sigma0 == pytest.approx(component.sigma0, rel=1e-5), name
        assert other.redundancy == pytest.approx(component.redundancy, rel=1e-6), name


def test_results_by_id_agree(both):
    """The result by ID is NumPy on both backends and gives the same σ, point covariances,
    statuses and observation table (data-snooping rejections included)."""
    project, dense, schur = both
    for result in (dense, schur):
        assert all(isinstance(leaf, np.ndarray) for leaf in jax.tree.leaves(
            (result.parameters, result.precision.std)))
    for cid in project.camera_rows:
        for name, estimate in dense.cameras[cid].items():
            other = schur.cameras[cid][name]
            assert other.status == estimate.status, (cid, name)
            if estimate.sigma is not None:
                assert other.sigma == pytest.approx(estimate.sigma, rel=SIGMA_RTOL), (cid, name)
    statuses = {e.status for iid in project.image_ids for e in schur.images[iid].values()}
    assert statuses == {"weighted"}  # GNSS/INS on every EOP
    for pid in project.point_ids:
        np.testing.assert_allclose(schur.points[pid].covariance, dense.points[pid].covariance,
                                   rtol=SIGMA_RTOL, atol=1e-18, err_msg=pid)
        assert schur.points[pid].kind == dense.points[pid].kind
    table_d, table_s = (dense.observations, schur.observations)
    rejected = {(r.group, r.row) for r in dense.rejections}
    removed = table_s["removed"]
    assert removed.sum() == len(rejected) >= 1
    np.testing.assert_array_equal(removed, table_d["removed"])
    np.testing.assert_allclose(table_s["wx"], table_d["wx"], rtol=0, atol=SIGMA_RTOL)
    np.testing.assert_allclose(table_s["ry"], table_d["ry"], rtol=0, atol=REDUNDANCY_ATOL)
    text = schur.summary()
    assert "schur backend" in text and f"{len(rejected)} removed by data snooping" in text


def test_redundancy_numbers_come_with_the_covariance(both):
    """The Schur adjustment's covariance holds its redundancy numbers (one program for both),
    the same as `schur_redundancy_numbers` computed apart at the solution. The whitened
    residuals e = (x - x̂)/σ of the two programs may differ by a rounding of the image
    coordinates (one ulp of 18 mm is 3.6e-15 mm) over σ: a few 1e-12."""
    _, _, schur = both
    cached_r, cached_e = schur.precision.schur.redundancy
    r, e = jaxba.advanced.schur_redundancy_numbers(schur.problem, schur.parameters)
    np.testing.assert_allclose(cached_r, r, rtol=0, atol=1e-12)
    sigma = np.concatenate([np.asarray(g.stddev)[np.asarray(g.mask())]
                            for g in schur.problem.groups if not g.constraint])
    np.testing.assert_allclose(cached_e, e, rtol=0, atol=4 * np.spacing(18.0) / sigma.min())


def test_reports_are_written_from_the_blocks(both, tmp_path):
    """results.json of both adjustments: the same statistics (σ, correlations, point σ,
    redundancy numbers) to SIGMA_RTOL (the values themselves: see above); the text
    reports are written alike."""
    project, dense, schur = both
    jaxba.write_reports(project, dense, tmp_path / "dense")
    jaxba.write_reports(project, schur, tmp_path / "schur")
    data_d = json.loads((tmp_path / "dense" / "results.json").read_text())
    data_s = json.loads((tmp_path / "schur" / "results.json").read_text())
    # σ relative; correlations, redundancy numbers and w-tests (order 1) absolute.
    for key, rtol, atol in (("cameras", SIGMA_RTOL, 0), ("points", SIGMA_RTOL, 0),
                            ("correlations", 0, SIGMA_RTOL), ("reliability", 0, SIGMA_RTOL)):
        numbers_d, numbers_s = _numbers(data_d[key]), _numbers(data_s[key])
        assert len(numbers_s) == len(numbers_d) > 0, key
        np.testing.assert_allclose(numbers_s, numbers_d, rtol=rtol, atol=atol, err_msg=key)
    name = project.spec.name
    for suffix in (".out", ".res", ".sigma"):
        lines_d = (tmp_path / "dense" / f"{name}{suffix}").read_text().splitlines()
        lines_s = (tmp_path / "schur" / f"{name}{suffix}").read_text().splitlines()
        more_iterations = len(schur.iterations) - len(dense.iterations)  # one row each in .sigma
        assert len(lines_s) == len(lines_d) + (suffix == ".sigma") * more_iterations, suffix


def _numbers(tree) -> np.ndarray:
    """All floats in a JSON tree in document order (None as NaN), but the adjusted values
    and the ellipsoids' axis directions (eigenvectors of nearly equal axes turn with tiny
    changes of the covariance)."""
    if isinstance(tree, dict):
        parts = [_numbers(v) for k, v in tree.items() if k not in ("value", "directions")]
        return np.concatenate(parts or [np.zeros(0)])
    if isinstance(tree, list):
        return np.concatenate([_numbers(v) for v in tree] or [np.zeros(0)])
    if isinstance(tree, bool) or isinstance(tree, str):
        return np.zeros(0)
    return np.array([np.nan if tree is None else float(tree)])


def test_the_datum_check_and_the_statistics_are_one_program_each(tmp_path, monkeypatch):
    """What a run traces, lowers and loads from the cache in every process (jax's compile
    events, counted per phase by `Timings`): the datum check one program (the normal
    equations with S), the statistics one more (covariance blocks, redundancy numbers and
    residuals; the normal equations at the solution reuse the datum check's program), the
    stepwise solve its init, step and result (and, once per process, the probe of the
    compiler options). The step and the statistics, compiled ahead on a worker thread,
    count where they are called."""
    project = _project(tmp_path)
    jax.clear_caches()  # every program of the run is traced again (loaded from the cache)
    monkeypatch.setattr(_programs, "_loaded", {})  # as in a process of its own
    result = jaxba.adjust_project(project, solver="schur")
    compiled = {phase.name: phase.compilations for phase in result.timings.phases}
    assert compiled["datum check"] == 1
    assert compiled["statistics"] == 1
    assert 3 <= compiled["solve"] <= 4
    assert sum(compiled.values()) == result.timings.compilations


def test_a_point_on_nearly_coincident_rays_alone_has_no_sigma(tmp_path):
    """Point 2 seen only by img01 and its twin img99 (station 1e-7 m away, the same
    measurements): N is singular along the point's rays. The Schur backend names its three
    coordinates, and every other unknown has the σ of the same bundle with one coordinate
    of point 2 fixed, solved dense (an independent computation: the null direction lies
    within the point, so its other unknowns' cofactors do not depend on how it is held).
    The datum check, which would refuse the rays at the approximations, is skipped: the
    singularity at the solution is what is tested."""
    truth = jaxba.write_synthetic_project(tmp_path, seed=2, n_images=8, n_targets=30)
    orientation = tmp_path / "orientation.txt"
    lines = orientation.read_text().splitlines()
    first = lines[1].split()
    twin = ["img99", first[1], repr(float(first[2]) + 1e-7), *first[3:]]
    orientation.write_text("\n".join([*lines, " ".join(twin)]) + "\n")
    table = tmp_path / "image_coordinates.txt"
    rows = table.read_text().splitlines()
    kept = [r for r in rows if r.startswith("#") or r.split()[1] != "2" or r.startswith("img01 ")]
    kept += ["img99 " + r.split(maxsplit=1)[1] for r in rows if r.startswith("img01 ")]
    table.write_text("\n".join(kept) + "\n")
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    result = jaxba.adjust(project.problem, labels=project.labels, solver="schur", check=False)
    assert result.converged
    named = {project.labels[k]: why for k, why in result.no_sigma.items()}
    assert sorted(named) == ["point 2 X", "point 2 Y", "point 2 Z"]
    assert all("rays (nearly) coincide" in why for why in named.values())
    std = flatten(result.precision.std)
    free = flatten(project.problem.free)
    others = free & np.isfinite(std)
    assert others.sum() == free.sum() - 3

    # The same bundle, point 2's coordinate along its rays fixed at the Schur solution.
    row = project.point_ids.index("2")
    ray = np.asarray(result.parameters.points)[row] - np.asarray(result.parameters.images)[0, :3]
    axis = int(np.argmax(np.abs(ray)))
    held = project.problem
    held = eqx.tree_at(lambda p: p.initial, held, result.parameters)
    held = eqx.tree_at(lambda p: p.free.points, held,
                       jnp.asarray(held.free.points).at[row, axis].set(False))
    dense = jaxba.adjust(held, labels=project.labels, solver="dense")
    assert dense.converged and not dense.no_sigma, dense.message
    dense_std = flatten(dense.precision.std)
    np.testing.assert_allclose(std[others] / result.sigma0,
                               dense_std[others] / dense.sigma0, rtol=COFACTOR_RTOL)
