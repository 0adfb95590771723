"""Tests of `jaxba adjust`, run in-process on copies of configs/lab.

One adjustment is shared by most tests (module fixture); the error cases stop before solving.
"""

import base64
import contextlib
import gc
import hashlib
import io
import json
import math
import pathlib
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

import jaxba
from jaxba._cli._main import main

LAB = pathlib.Path(__file__).resolve().parents[1] / "configs" / "lab"
OUTPUTS = ("lab.out", "lab.res", "lab.sigma", "results.json", "observations.csv")
PLOTS = ("residuals.png", "normalised_residuals.png", "coverage.png", "distortion_C1.png",
         "correlation_C1.png", "point_ellipses.png")  # written by --plots
HTML = "lab.html"  # written by --report html
APPROXIMATION_DEG = 10.0  # the lab's angle approximations are within a few degrees of the result
SIGMA_FILE_RTOL = 1e-9  # .sigma prints 11 significant digits
REDUNDANCY_RTOL = 1e-8  # Σ r_i against n - u (two dense factorisations of the same N)


def _copy_lab(folder: pathlib.Path) -> pathlib.Path:
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns(*OUTPUTS))
    return folder / "lab.toml"


def _hashes(folder: pathlib.Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _data_lines(path: pathlib.Path) -> list[list[str]]:
    lines = path.read_text().splitlines()
    return [line.split() for line in lines if line.strip() and not line.startswith("#")]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """`jaxba adjust lab.toml --plots --report html` (reports beside the project) on a fresh
    copy of the lab."""
    folder = tmp_path_factory.mktemp("cli") / "lab"
    project_file = _copy_lab(folder)
    inputs = _hashes(folder)
    code, stdout, stderr = _run("adjust", str(project_file), "--plots", "--report", "html")
    return {
        "folder": folder, "inputs": inputs, "code": code, "stdout": stdout, "stderr": stderr,
        "results": json.loads((folder / "results.json").read_text()),
    }


def test_exit_code_and_files(run):
    assert run["code"] == 0, run["stderr"]
    assert run["stderr"] == ""
    for name in OUTPUTS:
        assert (run["folder"] / name).is_file()
    for name in PLOTS:
        assert (run["folder"] / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (run["folder"] / HTML).read_text(encoding="utf-8")
    sigma0 = f'<span id="sigma0">{run["results"]["sigma0"]:.6g}</span>'
    assert page.startswith("<!DOCTYPE html>") and sigma0 in page
    for name in PLOTS:  # the same figures, embedded
        png = base64.b64encode((run["folder"] / name).read_bytes()).decode("ascii")
        assert f'src="data:image/png;base64,{png}"' in page


def test_inputs_untouched(run):
    after = _hashes(run["folder"])
    assert {name: after[name] for name in run["inputs"]} == run["inputs"]
    assert set(after) == set(run["inputs"]) | set(OUTPUTS) | set(PLOTS) | {HTML}


def test_results_json_contract(run):
    data = run["results"]
    assert data["converged"] is True
    assert isinstance(data["redundancy"], int) and data["redundancy"] > 0
    assert data["redundancy"] == data["n_observations"] - data["n_unknowns"]
    assert data["sigma0"] == pytest.approx(math.sqrt(data["sigma0_squared"]), rel=1e-12)
    assert 0.5 < data["sigma0"] < 2.0  # the lab's σ of image points is the simulated noise
    assert data["project"] == "lab" and isinstance(data["message"], str)
    for it in data["iterations"]:
        assert set(it) == {"iteration", "sigma0_squared", "cost"}
        assert isinstance(it["iteration"], int) and isinstance(it["cost"], float)
    assert data["iterations"][-1]["sigma0_squared"] == pytest.approx(data["sigma0_squared"])
    names = jaxba.CAMERA_MODELS["smac"].parameter_names
    assert list(data["cameras"]["C1"]) == list(names)
    for name, entry in data["cameras"]["C1"].items():
        assert isinstance(entry["value"], float) and isinstance(entry["std"], float), name
        assert (entry["std"] == 0.0) == (entry["status"] == "fixed"), name
    for entry in data["images"].values():
        assert list(entry) == list(jaxba.IMAGE_PARAMETER_NAMES)
        assert all(isinstance(e["value"], float) and e["std"] > 0 for e in entry.values())
    for entry in data["points"].values():
        coordinates = {name: entry[name] for name in jaxba.POINT_PARAMETER_NAMES}
        assert set(entry) - set(coordinates) <= {"ellipsoid"}
        assert all(isinstance(e["value"], float) and e["std"] >= 0 for e in coordinates.values())
    assert data["image_residuals"]["all"]["rms_x_px"] > 0


def test_results_json_statistics(run):
    data = run["results"]
    correlations = data["correlations"]["C1"]
    assert correlations["parameters"] == ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]
    matrix = np.array(correlations["matrix"])
    np.testing.assert_allclose(matrix, matrix.T, atol=1e-12)
    np.testing.assert_allclose(np.diag(matrix), 1.0, rtol=1e-12)
    assert np.all(np.abs(matrix) <= 1 + 1e-12)
    assert data["variance_components"] is None and data["variance_component_iterations"] is None
    assert data["rejections"] == []
    reliability = data["reliability"]
    assert reliability["redundancy_sum"] == pytest.approx(data["redundancy"], rel=REDUNDANCY_RTOL)
    assert 0 < reliability["alpha"] < 1 and reliability["critical_value"] > 2
    assert data["observations_file"] == "observations.csv" and "observations" not in data
    table = jaxba.read_observations(run["folder"] / data["observations_file"])
    image = table["type"] == "image_points"
    assert np.count_nonzero(image) == len(_data_lines(run["folder"] / "image_coordinates.txt"))
    r = np.column_stack([table["rx"][image], table["ry"][image]])
    assert np.all((r > 0) & (r < 1))
    assert not table["outlier"].any()
    assert table["type"][~image].tolist() == ["distances"] * 4
    assert np.sum(r) + np.sum(table["r"][~image]) == pytest.approx(
        reliability["redundancy_sum"], rel=REDUNDANCY_RTOL)
    for pid, entry in data["points"].items():
        std = [entry[name]["std"] for name in jaxba.POINT_PARAMETER_NAMES]
        if "ellipsoid" not in entry:
            assert std == [0.0, 0.0, 0.0], pid
            continue
        # The semi-axes² add up to the trace of the point's covariance, Σ σ².
        axes = entry["ellipsoid"]["axes"]
        assert sum(a**2 for a in axes) == pytest.approx(sum(s**2 for s in std), rel=1e-9)


def test_angles_in_degrees_near_approximations(run):
    rows = _data_lines(run["folder"] / "orientation.txt")
    approximations = {row[0]: [float(v) for v in row[5:8]] for row in rows}
    for iid, entry in run["results"]["images"].items():
        for name, approx in zip(("omega", "phi", "kappa"), approximations[iid]):
            difference = (entry[name]["value"] - approx + 180.0) % 360.0 - 180.0
            assert abs(difference) < APPROXIMATION_DEG, (iid, name)
            assert entry[name]["std"] < 1.0  # degrees: a σ of 1 rad would be 57


def test_sigma_file_matches_json(run):
    rows = _data_lines(run["folder"] / "lab.sigma")
    iterations = run["results"]["iterations"]
    assert len(rows) == len(iterations)
    for row, it in zip(rows, iterations):
        assert int(row[0]) == it["iteration"]
        assert float(row[1]) == pytest.approx(it["sigma0_squared"], rel=SIGMA_FILE_RTOL)
        assert float(row[2]) == pytest.approx(it["cost"], rel=SIGMA_FILE_RTOL)


def test_res_has_one_row_per_image_observation(run):
    rows = _data_lines(run["folder"] / "lab.res")
    measured = _data_lines(run["folder"] / "image_coordinates.txt")
    assert len(rows) == len(measured)
    assert {(r[0], r[1]) for r in rows} == {(m[0], m[1]) for m in measured}


def test_out_file_sections(run):
    text = (run["folder"] / "lab.out").read_text()
    for part in ("Camera C1", "Exterior orientation", "Object points", "a posteriori sigma0"):
        assert part in text
    # The run's facts in the header: backend, datum, the χ² test, outliers, seconds per phase.
    header = text.split("\n\n")[1]
    for pattern in (r"solver backend +dense", r"datum +control: 3 control points",
                    r"variance test +chi-square test passed", r"outliers +0 with \|w\| > 4\.28",
                    r"timings +seconds: read [\d.]+, start-up [\d.]+, datum check"):
        assert re.search(pattern, header), pattern
    results = json.loads((run["folder"] / "results.json").read_text())
    assert results["variance_test"]["passed"] is True
    assert results["outliers"]["count"] == 0 and results["datum"]["kind"] == "control"


def test_progress_and_summary(run):
    lines = run["stdout"].splitlines()
    progress = [line for line in lines if line.startswith("iter ")]
    assert len(progress) == len(run["results"]["iterations"])
    assert progress[0].split()[:3] == ["iter", "0", "cost"]
    assert any(line.startswith("sigma0 ") for line in lines)
    assert any(line.strip().startswith("c ") and "+/-" in line for line in lines)
    for name in OUTPUTS + PLOTS + (HTML,):
        assert any(line.strip().endswith(name) for line in lines)
    assert any(line.startswith("converged after") and "dense backend" in line for line in lines)
    assert any(line.startswith("  chi-square test passed: ") for line in lines)
    assert any(line.startswith("datum: control: 3 control points") for line in lines)
    assert any(line.startswith("outliers: 0 with |w| > 4.28") for line in lines)


def test_timings_on_the_console_and_in_results_json(run):
    """Where the time went: every phase on the console and in results.json, compilation apart,
    and the phases add up to the total."""
    timing = next(line for line in run["stdout"].splitlines() if line.startswith("seconds: "))
    phases = ("read", "start-up", "datum check", "solve", "statistics", "reports")
    for name in phases:
        assert f"{name} " in timing
    assert "compile " in timing and "from the cache" in timing
    assert run["results"]["solver"] == "dense"
    timings = run["results"]["timings"]
    seconds = timings["seconds"]
    assert list(seconds)[:5] == list(phases[:5])
    assert all(value >= 0 for value in seconds.values())
    assert sum(seconds[name] for name in phases[:5]) + seconds["compile"] == pytest.approx(
        seconds["total"], abs=1e-3)
    assert timings["compilations"] >= timings["cache_hits"] >= 0


def test_res_statistics_columns(run):
    rows = _data_lines(run["folder"] / "lab.res")
    assert {len(row) for row in rows} == {13}
    assert {row[-1] for row in rows} == {"0"}  # no outliers in the lab
    text = (run["folder"] / "lab.out").read_text()
    for part in ("IOP correlations of camera C1", "Reliability", "Error ellipsoids"):
        assert part in text
    assert "Variance components" not in text and "Data snooping" not in text


@pytest.mark.parametrize("option", [["--plots"], ["--report", "html"]])
def test_figures_without_matplotlib_refused_before_the_run(monkeypatch, tmp_path, option):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    code, stdout, stderr = _run("adjust", str(_copy_lab(tmp_path / "lab")), "--out",
                                str(tmp_path / "out"), *option)
    assert code == 2 and stdout == ""
    assert stderr.startswith(f"jaxba: error: {' '.join(option)}: matplotlib cannot be imported")
    assert not (tmp_path / "out").exists()


def test_html_report_over_an_input_refused_before_the_run(tmp_path):
    project_file = _copy_lab(tmp_path / "lab")
    (tmp_path / "lab" / "distances.txt").rename(tmp_path / "lab" / "lab.html")
    _edit(project_file, '"distances.txt"', '"lab.html"')
    before = _hashes(tmp_path / "lab")
    code, stdout, stderr = _run("adjust", str(project_file), "--report", "html")
    assert code == 2 and stdout == ""
    assert stderr.startswith("jaxba: error: ") and "lab.html" in stderr
    assert _hashes(tmp_path / "lab") == before


def test_output_would_overwrite_input(tmp_path):
    project_file = _copy_lab(tmp_path / "lab")
    (tmp_path / "lab" / "distances.txt").rename(tmp_path / "lab" / "lab.res")
    _edit(project_file, '"distances.txt"', '"lab.res"')
    before = _hashes(tmp_path / "lab")
    code, stdout, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "lab"))
    assert code == 2
    assert stderr.startswith("jaxba: error: ") and "lab.res" in stderr
    assert "Traceback" not in stderr
    assert _hashes(tmp_path / "lab") == before


def test_bad_file(tmp_path):
    project_file = _copy_lab(tmp_path / "lab")
    path = tmp_path / "lab" / "image_coordinates.txt"
    lines = path.read_text().splitlines()
    data_line = next(k for k, line in enumerate(lines) if line and not line.startswith("#"))
    lines[data_line] = lines[data_line].rsplit(maxsplit=1)[0] + " not-a-number"
    path.write_text("\n".join(lines) + "\n")
    code, _, stderr = _run("adjust", str(project_file))
    assert code == 2
    assert "image_coordinates.txt" in stderr and "Traceback" not in stderr
    assert not (tmp_path / "lab" / "results.json").exists()


def test_missing_project_file(tmp_path):
    code, _, stderr = _run("adjust", str(tmp_path / "nowhere.toml"))
    assert code == 2 and "nowhere.toml" in stderr


def test_datum_without_scale(tmp_path):
    project_file = _copy_lab(tmp_path / "lab")
    _edit(project_file, 'distances = "distances.txt"\n', "")
    code, _, stderr = _run("adjust", str(project_file))
    assert code == 2
    assert stderr.startswith("jaxba: error: ") and "scale" in stderr
    assert not (tmp_path / "lab" / "results.json").exists()


def test_usage(capsys):
    assert main(["--help"]) == 0
    assert main([]) == 2
    assert main(["adjust"]) == 2
    assert "usage" in capsys.readouterr().err


def test_version_is_the_distribution_version(capsys):
    """`jaxba --version` and `python -m jaxba --version` print the installed package's
    version, which `jaxba.__version__` also is (one source: pyproject.toml)."""
    import importlib.metadata

    installed = importlib.metadata.version("jaxba")
    assert jaxba.__version__ == installed
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"jaxba {installed}"
    module = subprocess.run([sys.executable, "-m", "jaxba", "--version"],
                            capture_output=True, text=True, check=True)
    assert module.stdout.strip() == f"jaxba {installed}"


def test_not_converged_still_writes_reports(tmp_path):
    project_file = _copy_lab(tmp_path / "lab")
    _edit(project_file, "max_iterations = 50", "max_iterations = 3")
    out = tmp_path / "reports"
    code, stdout, stderr = _run("adjust", str(project_file), "--out", str(out))
    assert code == 1
    assert "did not converge" in stderr and "NOT converged" in stdout
    data = json.loads((out / "results.json").read_text())
    assert data["converged"] is False and data["message"] != "converged"
    assert all((out / name).is_file() for name in OUTPUTS)


def test_solver_option_and_setting(run, tmp_path):
    """--solver schur eliminates the object points: same σ̂0 and IOP σ as the default (dense)
    run; the project's `solver` setting is read; a free network runs on 'schur' too."""
    project_file = _copy_lab(tmp_path / "lab")
    code, _, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "schur"),
                           "--solver", "schur")
    assert code == 0, stderr
    schur = json.loads((tmp_path / "schur" / "results.json").read_text())
    dense = run["results"]
    assert schur["sigma0"] == pytest.approx(dense["sigma0"], rel=1e-8)
    for name, entry in dense["cameras"]["C1"].items():
        assert schur["cameras"]["C1"][name]["std"] == pytest.approx(entry["std"], rel=1e-6), name
    _edit(project_file, "[adjustment]", '[adjustment]\nsolver = "fast"')
    code, _, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "bad"))
    assert code == 2 and "solver" in stderr and "fast" in stderr
    _edit(project_file, 'solver = "fast"', 'datum = "free"')
    code, _, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "free"),
                           "--solver", "schur")
    assert code == 0, stderr
    free = json.loads((tmp_path / "free" / "results.json").read_text())
    assert free["solver"] == "schur"
    # The lab's datum is minimal: σ̂0 and the IOPs' σ do not depend on it.
    assert free["sigma0"] == pytest.approx(dense["sigma0"], rel=1e-8)
    for name, entry in dense["cameras"]["C1"].items():
        assert free["cameras"]["C1"][name]["std"] == pytest.approx(entry["std"], rel=1e-6), name


@pytest.mark.parametrize("command", ["adjust", "bal"])
def test_bad_input_is_reported_before_jax_is_loaded(tmp_path, command):
    """Fail fast: a bad project or BAL file ends with exit 2 and the file named, and jax
    (over a second to import) was never loaded."""
    if command == "adjust":
        project_file = _copy_lab(tmp_path / "lab")
        _edit(project_file.parent / "image_coordinates.txt", "img01", "no_such_image")
        argv = ["adjust", str(project_file), "--out", str(tmp_path / "out")]
        named = "image_coordinates.txt"
    else:
        (tmp_path / "bad.txt").write_text("2 3 4\n0 0 1.0\n")
        argv = ["bal", str(tmp_path / "bad.txt"), "--out", str(tmp_path / "out")]
        named = "bad.txt"
    script = ("import sys; from jaxba._cli._main import main; code = main(sys.argv[1:]);"
              " print(code, 'jax' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True,
                          text=True, timeout=60)
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert named in done.stderr and done.stderr.startswith("jaxba: error: ")
    assert not (tmp_path / "out").exists()


def test_bal_refuses_a_step_limit_below_one(tmp_path):
    code, _, stderr = _run("bal", str(tmp_path / "any.txt"), "--max-steps", "-5")
    assert code == 2 and "--max-steps -5" in stderr


@pytest.mark.parametrize("snooping", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_blunder_warnings(tmp_path, snooping):
    """A 27-pixel blunder on img01 point 5 x: without data snooping the χ² test rejects σ̂0
    and the warning names the observation with the largest |w|; with it, the warning names
    the removed observation and σ̂0 passes the test."""
    project_file = _copy_lab(tmp_path / "lab")
    _edit(project_file.parent / "image_coordinates.txt", "img01 5 -1.19359937",
          "img01 5 -1.09359937")
    if snooping:
        _edit(project_file, "[adjustment]", "[adjustment]\ndata_snooping = true")
    code, _, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "out"))
    assert code == 0, stderr
    warnings = stderr.splitlines()
    assert all(line.startswith("jaxba: warning: ") for line in warnings)
    variance = [line for line in warnings if "chi-square test of the variance factor" in line]
    large = [line for line in warnings if "above the critical value" in line]
    removed = [line for line in warnings if "data snooping removed" in line]
    if snooping:
        assert not variance and not large
        assert len(removed) == 1 and "removed 1 observation(s): image img01 point 5 x" in stderr
    else:
        assert len(variance) == 1 and "blunders" in variance[0]
        assert len(large) == 1 and ": image img01 point 5 x |w| " in large[0]
        assert not removed


def test_an_adjustment_loads_no_plotting_or_table_modules(tmp_path):
    """`jaxba adjust` without figures imports neither matplotlib nor scipy.stats, pandas,
    Dask or rich (each 0.1-0.8 s of a whole run); in a process of its own it freezes what
    it imported for the garbage collector."""
    project_file = _copy_lab(tmp_path / "lab")
    heavy = ("matplotlib", "scipy.stats", "pandas", "dask", "distributed", "rich")
    script = ("import gc, sys; from jaxba._cli._main import main;"
              " code = main(sys.argv[1:], own_process=True);"
              f" print(code, gc.get_freeze_count() > 0, *[m for m in {heavy!r} if m in"
              " sys.modules])")
    done = subprocess.run([sys.executable, "-c", script, "adjust", str(project_file), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert done.stdout.splitlines()[-1].split() == ["0", "True"], done.stderr


def test_an_adjustment_in_a_callers_process_freezes_nothing(run):
    """`main` called from Python (the run fixture) leaves the caller's garbage collector as
    it was: frozen objects are never collected."""
    assert run["code"] == 0
    assert gc.get_freeze_count() == 0


def test_a_project_with_nothing_free_is_refused_with_exit_code_2(tmp_path):
    """Cameras, images and points all fixed: a clear error, not one from jax's internals."""
    project_file = _copy_lab(tmp_path / "lab")
    folder = project_file.parent
    cameras = folder / "cameras.toml"
    cameras.write_text(re.sub(r"free = \[.*\]", "free = []", cameras.read_text()))
    for name, fixed in (("orientation.txt", None), ("ground_points.txt", 3)):
        lines = (folder / name).read_text().splitlines()
        rows = [line.split() for line in lines if line.strip() and not line.startswith("#")]
        rows = [row[:len(row) - fixed] + ["0"] * fixed if fixed else row + ["0"] * 6
                for row in rows]
        (folder / name).write_text("\n".join(["# fixed", *(" ".join(r) for r in rows)]) + "\n")
    code, stdout, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "out"))
    assert code == 2
    assert "jaxba: error: the problem has no free unknowns" in stderr


def test_an_adjustment_piped_into_a_reader_that_stops_still_writes_its_reports(tmp_path):
    """`jaxba adjust ... | head -1`: the console's reader goes away after the first line; the
    run goes on silently and ends as it would have (exit 0, every report written)."""
    project_file = _copy_lab(tmp_path / "lab")
    out = tmp_path / "out"
    process = subprocess.Popen([sys.executable, "-m", "jaxba", "adjust", str(project_file),
                                "--out", str(out)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    assert process.stdout.readline().startswith("adjusting lab")
    process.stdout.close()
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 0, stderr
    assert "internal error" not in stderr
    assert {"lab.out", "lab.res", "lab.sigma", "results.json"} <= {p.name for p in out.iterdir()}
