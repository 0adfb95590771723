"""The dependent relative orientation datum (`datum = "dependent"`) against other minimal
datums of the same block: σ̂0, redundancy and IOPs are datum-invariant."""

import json

import numpy as np
import pytest

import jaxba
from jaxba._report._console import summary_lines
from jaxba._report._json import results_json
from jaxba._report._text import out_text

GAUGE_RTOL = 1e-6  # gauge-invariant quantities agree across minimal datums
EOPS = ["X0", "Y0", "Z0", "omega", "phi", "kappa"]


def _with_settings(truth, **settings):
    lines = "".join(f"\n{key} = {value}" for key, value in settings.items())
    text = truth.project_file.read_text()
    path = truth.project_file.with_name(f"{'_'.join(settings) or 'base'}.toml")
    path.write_text(text.replace("[adjustment]", "[adjustment]" + lines))
    return jaxba.build_project(jaxba.read_project(path))


def _iops(result):
    return np.asarray(result.parameters.cameras["smac"]).ravel()


def _same_invariants(a, b):
    assert a.converged and b.converged
    assert a.precision.redundancy == b.precision.redundancy
    assert a.sigma0 == pytest.approx(b.sigma0, rel=1e-9)
    iop_a, iop_b = _iops(a), _iops(b)
    np.testing.assert_allclose(iop_a, iop_b, rtol=GAUGE_RTOL, atol=1e-10)


@pytest.fixture(scope="module")
def with_distances(tmp_path_factory):
    """The lab block (6 fixed coordinates, scale from distances) and the same observations
    with a dependent datum (6 EOPs of img03 fixed, scale from the distances)."""
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("dep"), seed=4, noise_px=0.3,
                                     n_images=10, n_targets=40)
    control = _with_settings(truth)
    dependent = _with_settings(truth, datum='"dependent"', datum_image='"img03"')
    return (control, jaxba.adjust_project(control)), (dependent, jaxba.adjust_project(dependent))


def test_dependent_datum_with_distances_fixes_six_eops(with_distances):
    (_, control), (project, dependent) = with_distances
    _same_invariants(control, dependent)
    assert project.datum == {"kind": "dependent", "image": "img03", "fixed": EOPS,
                             "scale": "distances", "base_image": None, "base_coordinate": None}
    free = np.asarray(project.problem.free.images)
    fixed = [(project.image_ids[i], EOPS[j]) for i, j in zip(*np.nonzero(~free))]
    assert fixed == [("img03", name) for name in EOPS]
    assert np.asarray(project.problem.free.points).all()  # the lab's fixed coordinates freed
    # The fixed image keeps its approximations exactly.
    np.testing.assert_array_equal(np.asarray(dependent.parameters.images)[2],
                                  np.asarray(project.problem.initial.images)[2])
    text = out_text(project, dependent)
    # One description of the datum (its bundle's fixed EOPs are not called control).
    datum_lines = [line.split() for line in text.splitlines() if line.split()[:1] == ["datum"]]
    assert datum_lines == [["datum", "dependent", "relative", "orientation:", *EOPS, "of",
                            "image", "img03", "fixed,", "scale", "from", "the", "distances"]]
    data = json.loads(results_json(project, dependent))
    assert data["datum"]["image"] == "img03" and data["datum"]["scale"] == "distances"
    assert data["datum"]["description"] == " ".join(datum_lines[0][1:])  # as in NAME.out
    console = [line for line in summary_lines(project, dependent) if line.startswith("datum:")]
    assert console == [f"datum: {data['datum']['description']}"]  # the console says the same
    assert all(data["images"]["img03"][name]["status"] == "fixed" for name in EOPS)


def test_dependent_datum_without_distances_fixes_the_longest_base(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_distances=0,
                                          n_images=10, n_targets=40)
    # Control: the lab's six fixed coordinates (X Y Z of A, Y Z of B, Z of C) plus X of B
    # for the scale, at their true values.
    points = truth.project_file.with_name("ground_points.txt")
    rows = [line.split() for line in points.read_text().splitlines()]
    b = next(k for k, row in enumerate(rows) if row[-3:] == ["-", "0", "0"])
    rows[b][1], rows[b][-3] = repr(truth.points[rows[b][0]][0]), "0"
    points.write_text("\n".join(" ".join(row) for row in rows) + "\n")
    control = _with_settings(truth)
    project = _with_settings(truth, datum='"dependent"')
    dependent = jaxba.adjust_project(project)
    _same_invariants(jaxba.adjust_project(control), dependent)

    # Independently: the image farthest from img01, and its largest base component.
    stations = {iid: np.array(spec.eop[:3]) for iid, spec in project.spec.images.items()}
    bases = {iid: xyz - stations["img01"] for iid, xyz in stations.items()}
    far = max(bases, key=lambda iid: np.linalg.norm(bases[iid]))
    axis = ["X0", "Y0", "Z0"][int(np.argmax(np.abs(bases[far])))]
    assert project.datum == {"kind": "dependent", "image": "img01", "fixed": EOPS,
                             "scale": "base", "base_image": far, "base_coordinate": axis}
    free = np.asarray(project.problem.free.images)
    fixed = [(project.image_ids[i], EOPS[j]) for i, j in zip(*np.nonzero(~free))]
    assert fixed == [("img01", name) for name in EOPS] + [(far, axis)]
    text = out_text(project, dependent)
    assert (f"image img01 fixed, {axis} of image {far} fixed (the longest base: the scale)"
            in text)
    assert "control" not in text
    data = json.loads(results_json(project, dependent))
    assert data["images"][far][axis]["status"] == "fixed"
    assert data["datum"]["base_image"] == far


def test_datum_image_must_exist_and_needs_the_dependent_datum(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_images=6,
                                          n_targets=30)
    with pytest.raises(jaxba.ProjectError, match="datum_image: no image 'img99'"):
        _with_settings(truth, datum='"dependent"', datum_image='"img99"')
    with pytest.raises(jaxba.ProjectError, match='datum_image needs datum = "dependent"'):
        _with_settings(truth, datum_image='"img02"')


@pytest.mark.parametrize("n_distances", [0, 4])
def test_schur_frees_the_gauge_and_lands_in_the_datum(tmp_path, n_distances):
    """The Schur backend solves with the dependent datum's unknowns free (`gauge`) and moves
    the solution back by a similarity: the same solution, in the datum, as the dense solve
    that holds them, the datum's unknowns exactly at their values; with distances the
    similarity has no scale (6 unknowns), without one station coordinate fixes it (7)."""
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_images=10,
                                          n_targets=40, n_distances=n_distances)
    project = _with_settings(truth, datum='"dependent"')
    problem = project.problem
    assert len(problem.gauge) == (6 if n_distances else 7)
    flat = jaxba.advanced.flatten(problem.free)
    assert not flat[list(problem.gauge)].any()  # held in the problem; the solver frees them
    dense = jaxba.adjust(problem, labels=project.labels, solver="dense")
    schur = jaxba.adjust(problem, labels=project.labels, solver="schur")
    assert dense.converged and schur.converged
    initial = jaxba.advanced.flatten(problem.initial)
    adjusted = jaxba.advanced.flatten(schur.parameters)
    np.testing.assert_allclose(adjusted[list(problem.gauge)], initial[list(problem.gauge)],
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(adjusted, jaxba.advanced.flatten(dense.parameters),
                               rtol=GAUGE_RTOL, atol=1e-9)
    assert schur.sigma0 == pytest.approx(dense.sigma0, rel=1e-9)
    sigma = {name: estimates["c"].sigma for name, estimates in schur.cameras.items()}
    assert sigma == pytest.approx({n: e["c"].sigma for n, e in dense.cameras.items()}, rel=1e-6)


def test_cost_rule_stops_after_a_small_cost_change_near_the_optimum(tmp_path):
    """`stop = "cost"` (Ceres' rule with a guard, as `jaxba import bal` writes): the Schur
    solve with the gauge released takes damped steps only and ends at an accepted step that
    lowered the cost by at most 1e-6 of it, where the next Gauss-Newton step would move every
    unknown by less than 1e-3 of its a priori σ: the solution, in the datum, lies within
    1e-3 + 1e-5 (the statistical rule's) a priori σ of the statistical rule's (reported σ:
    σ̂0/σ0 times those; 10 % for the model's curvature)."""
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_images=10,
                                          n_targets=40)
    statistical_project = _with_settings(truth, datum='"dependent"')
    project = _with_settings(truth, datum='"dependent"', stop='"cost"')
    assert project.spec.settings.stop == "cost"
    statistical = jaxba.adjust_project(statistical_project, solver="schur")
    cost = jaxba.adjust_project(project, solver="schur")
    assert statistical.converged and cost.converged
    costs = np.array([it.cost for it in cost.iterations])
    assert costs[-2] - costs[-1] <= 1e-6 * costs[-2]
    gauge = list(project.problem.gauge)
    adjusted = jaxba.advanced.flatten(cost.parameters)
    np.testing.assert_allclose(adjusted[gauge],
                               jaxba.advanced.flatten(project.problem.initial)[gauge],
                               rtol=0, atol=1e-12)
    sigma = jaxba.advanced.flatten(statistical.precision.std)
    reference = jaxba.advanced.flatten(statistical.parameters)
    free = sigma > 0
    bound = 1.1 * (1e-3 + 1e-5) / statistical.sigma0
    assert np.max(np.abs(adjusted - reference)[free] / sigma[free]) <= bound
    assert costs[-1] >= statistical.iterations[-1].cost - 1e-9 * costs[-1]


def test_stop_must_name_a_rule(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, noise_px=0.3, n_images=6,
                                          n_targets=30)
    with pytest.raises(jaxba.ProjectError, match="stop: expected one of"):
        _with_settings(truth, stop='"never"')
    project = _with_settings(truth)
    with pytest.raises(ValueError, match="stop must be one of statistical, cost, not 'never'"):
        jaxba.adjust(project.problem, stop="never")


def test_gauge_move_in_numpy_equals_the_compiled_one(tmp_path):
    """The dependent datum's move of omega-phi-kappa images in NumPy (Newton steps with
    central differences) lands where the compiled move (jax's `similarity_transform`,
    differentiated by autodiff) lands, from a solution turned, shifted and scaled off the
    datum (7 similarity parameters), and sets the gauge's unknowns to their datum values."""
    from jaxba._statistics import _gauge
    from jaxba._statistics._datum import network_centre, similarity_transform

    truth = jaxba.write_synthetic_project(tmp_path, seed=5, noise_px=0.3, n_images=6,
                                          n_targets=30, n_distances=0)
    problem = _with_settings(truth, datum='"dependent"').problem
    assert len(problem.gauge) == 7 and problem.pose == "opk"
    centre = network_centre(problem)
    theta = np.array([0.03, -0.02, 0.05, 0.004, -0.003, 0.006, 0.002])
    off = similarity_transform(problem.initial, theta, centre)
    numpy = _gauge._gauge_datum_opk(problem, off, centre)
    compiled = _gauge._gauge_datum_compiled(problem, off, centre)
    flat = jaxba.advanced.flatten
    np.testing.assert_allclose(flat(numpy), flat(compiled), rtol=0, atol=1e-12)
    np.testing.assert_allclose(flat(numpy)[list(problem.gauge)],
                               flat(problem.initial)[list(problem.gauge)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(flat(numpy), flat(problem.initial), rtol=0, atol=1e-9)
