"""Comparing two calibrations (`jaxba.compare`, `jaxba compare`) and the projection
uncertainty files of `jaxba adjust --uncertainty`."""

import dataclasses
import json
import math

import jax
import numpy as np
import pytest
import scipy.stats
import stereo_cameras
from board_scene import SENSOR, TRUTH, adjusted, write_project

import jaxba
from jaxba._cli._main import main
from jaxba._report import results_dict
from jaxba._statistics._projection import sensor_grid

PAIRS = 100
ALPHA = 0.05


@pytest.fixture(scope="module")
def calibrations(tmp_path_factory):
    """Two calibrations of the true camera (other stations, other noise) and one of a camera
    whose fx is 6 px (about 5σ) longer, as (project file, project, result)."""
    root = tmp_path_factory.mktemp("calibrations")
    out = []
    for name, seed, camera in (("a", 5, TRUTH), ("b", 6, TRUTH),
                               ("long", 7, {**TRUTH, "fx": TRUTH["fx"] + 6})):
        project_file = write_project(root / name, seed, camera=camera)
        out.append((project_file, *adjusted(project_file)))
    return out


@pytest.mark.slow
def test_independent_calibrations_pass_at_the_expected_rate(calibrations):
    """Pairs of re-adjustments with independent noise: their p-values are uniform, and the
    test rejects about ALPHA of them (with a fitted rotation and without)."""
    _, _, result = calibrations[0]
    replicates = jaxba.monte_carlo(result.problem, 2 * PAIRS, jax.random.key(5),
                                   at=result.parameters)
    iops = np.asarray(replicates.solutions.parameters.cameras["opencv"][:, 0])
    base = jaxba.calibration_of(result, "C1", SENSOR)
    # The replicates' noise is the a priori σ: their covariance is N⁻¹ (σ0 = 1).
    base = dataclasses.replace(base, covariance=base.covariance / result.sigma0**2)
    for fit in ("rotation", "none"):
        p_values = np.array([
            jaxba.compare(dataclasses.replace(base, parameters=iops[2 * k]),
                          dataclasses.replace(base, parameters=iops[2 * k + 1]),
                          fit=fit).p_value
            for k in range(PAIRS)
        ])
        assert scipy.stats.kstest(p_values, "uniform").pvalue > 0.001, fit
        rejected = int(np.sum(p_values < ALPHA))
        # The count is Binomial(PAIRS, ALPHA): above its 0.999 quantile 1 run in 1000.
        assert rejected <= scipy.stats.binom.ppf(0.999, PAIRS, ALPHA), (fit, rejected)


def test_same_camera_consistent_other_camera_rejected(calibrations):
    (_, _, a), (_, _, b), (_, _, long) = calibrations
    same = [jaxba.compare(*(jaxba.calibration_of(r, "C1", SENSOR) for r in (a, b)), fit=fit)
            for fit in ("rotation", "none")]
    other = [jaxba.compare(*(jaxba.calibration_of(r, "C1", SENSOR) for r in (a, long)), fit=fit)
             for fit in ("rotation", "none")]
    for comparison in same:
        assert comparison.p_value > 0.001 and comparison.dof > 0
    for comparison in other:
        assert comparison.p_value < 1e-6
    # The rotation is fitted: it takes out most of the principal points' difference.
    assert np.sqrt(np.mean(same[0].norm**2)) < 0.5 * np.sqrt(np.mean(same[1].norm**2))
    assert np.all(same[1].rotation == 0) and np.any(same[0].rotation != 0)


def test_fitted_rotation_absorbs_a_moved_principal_point(calibrations):
    """B's principal point moved by 1 % of f (what a 0.57° turn of its frame does, up to a
    second-order difference at the edges): with the rotation fitted the calibrations stay
    consistent, without it the test rejects them at ALPHA."""
    (_, _, a), (_, _, b), _ = calibrations
    first, second = (jaxba.calibration_of(r, "C1", SENSOR) for r in (a, b))
    names = jaxba.OpenCVCamera.parameter_names
    shifted = second.parameters.copy()
    shifted[names.index("cx")] -= 0.01 * shifted[names.index("fx")]  # ≈ 0.57° about y
    turned = dataclasses.replace(second, parameters=shifted)
    before, after = (jaxba.compare(first, c) for c in (second, turned))
    assert before.p_value > ALPHA and after.p_value > ALPHA
    # The fit turns further about y by the shift over f.
    assert after.rotation[1] - before.rotation[1] == pytest.approx(-0.01, rel=0.1)
    assert jaxba.compare(first, turned, fit="none").p_value < ALPHA


def test_cli_uncertainty_distance_checked_before_the_run(calibrations, tmp_path, capsys):
    """A distance that is not positive is bad usage, said before anything is adjusted or
    written."""
    (file_a, _, _), _, _ = calibrations
    out = tmp_path / "out"
    assert main(["adjust", str(file_a), "--out", str(out), "--uncertainty", "-5"]) == 2
    assert "--uncertainty -5.0: the distance must be > 0" in capsys.readouterr().err
    assert not out.exists()


def test_cli_uncertainty_and_compare(calibrations, tmp_path, capsys):
    """`adjust --uncertainty` writes the map the API gives; `compare` reads results.json,
    writes its files and agrees with `jaxba.compare`."""
    (file_a, project_a, a), (file_b, _, _), _ = calibrations
    out_a, out_b = tmp_path / "a", tmp_path / "b"
    assert main(["adjust", str(file_a), "--out", str(out_a), "--uncertainty", "800",
                 "--report", "html"]) == 0
    assert main(["adjust", str(file_b), "--out", str(out_b)]) == 0
    table = np.loadtxt(out_a / "uncertainty_C1.csv", delimiter=",", skiprows=1)
    header = (out_a / "uncertainty_C1.csv").read_text().splitlines()[0]
    assert header == "u,v,sigma_worst,sigma_rms,cov_uu,cov_uv,cov_vv"
    np.testing.assert_allclose(table[:, :2], sensor_grid(SENSOR))
    expected = a.projection_uncertainty("C1", table[:, :2], 800.0)
    np.testing.assert_allclose(table[:, 2], expected.sigma_worst, rtol=1e-6)
    np.testing.assert_allclose(table[:, 4], expected.covariance[:, 0, 0], rtol=1e-6)
    for name in ("uncertainty_C1.png", "uncertainty_distance_C1.png"):
        assert (out_a / name).read_bytes().startswith(b"\x89PNG")
    page = (out_a / f"{project_a.spec.name}.html").read_text()
    assert '<section id="uncertainty">' in page and "uncertainty_distance_C1.png" in page

    out = tmp_path / "compare"
    argv = ["compare", str(out_a / "results.json"), str(out_b / "results.json"),
            "--out", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "compare_C1.json").read_text())
    expected = jaxba.compare(out_a / "results.json", out_b / "results.json", camera="C1")
    assert summary["chi2"] == pytest.approx(expected.chi2, rel=1e-9)
    assert summary["dof"] == expected.dof and summary["rejected"] is False
    rows = np.loadtxt(out / "compare_C1.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 4], expected.norm, rtol=1e-9)
    assert "degrees of freedom" in capsys.readouterr().out
    # Bad input: a camera that is not there, exit code 2 and its name.
    assert main([*argv, "--camera", "C7"]) == 2
    assert "C7" in capsys.readouterr().err


def test_results_json_carries_the_camera_model(calibrations):
    (_, project, result), _, _ = calibrations
    tree = results_dict(project, result)
    entry = tree["camera_models"]["C1"]
    assert entry["model"] == "opencv" and entry["sensor"] == list(SENSOR)
    assert entry["parameters"] == list(jaxba.OpenCVCamera.parameter_names)
    covariance = np.array(entry["covariance"])
    std = np.sqrt(np.diag(covariance))
    assert std[0] == pytest.approx(result.cameras["C1"]["fx"].sigma, rel=1e-12)
    assert std[entry["parameters"].index("skew")] == 0.0  # fixed


@pytest.mark.slow
def test_opencv_stereo_cross_validation(tmp_path):
    """OpenCV's stereo sample: odd- against even-numbered images of the left camera (the
    outcome is printed: model error may show), and the left camera against the right one,
    which the test must reject."""
    cv2 = pytest.importorskip("cv2")
    if not stereo_cameras.DATA.is_dir():
        pytest.skip(f"no {stereo_cameras.DATA}")
    left, right = stereo_cameras.corners(cv2, "left"), stereo_cameras.corners(cv2, "right")
    assert len(left) == len(right) == 13

    def calibration(found, numbers, name):
        project_file = stereo_cameras.write_project(cv2, tmp_path / name, found, numbers, name)
        _, result = adjusted(project_file)
        assert result.converged
        return jaxba.calibration_of(result, "C1", stereo_cameras.SENSOR, name=name)

    numbers = stereo_cameras.NUMBERS
    odd = calibration(left, [n for n in numbers if n % 2], "left_odd")
    even = calibration(left, [n for n in numbers if not n % 2], "left_even")
    both_left, both_right = calibration(left, numbers, "left"), calibration(right, numbers, "right")
    halves = jaxba.compare(odd, even)
    sides = jaxba.compare(both_left, both_right)
    print(f"left odd vs even: chi2 {halves.chi2:.1f} dof {halves.dof} p {halves.p_value:.3g},"
          f" |Δ| rms {math.sqrt(np.mean(halves.norm**2)):.3f} px;"
          f" left vs right: chi2 {sides.chi2:.1f} dof {sides.dof} p {sides.p_value:.3g},"
          f" |Δ| rms {math.sqrt(np.mean(sides.norm**2)):.3f} px")
    assert sides.p_value < 1e-6
