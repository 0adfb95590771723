"""Missing approximations: `jaxba adjust` computes them first, `jaxba init`
writes the completed project. Run in-process on copies of configs/lab whose EOPs are all `-`
and whose tie points (the rows with three free coordinates) are left out of the points table.
"""

import contextlib
import hashlib
import io
import json
import pathlib
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from doc_excerpts import incomplete_lab

import jaxba
from jaxba._cli._main import main
from jaxba._io import _synthetic as syn

LAB = pathlib.Path(__file__).resolve().parents[1] / "configs" / "lab"
OUTPUTS = ("lab.out", "lab.res", "lab.sigma", "results.json", "observations.csv")
TABLES = ("lab.toml", "cameras.toml", "orientation.txt", "image_coordinates.txt",
          "ground_points.txt", "distances.txt")
RTOL, ATOL = 1e-6, 1e-9  # the adjustment from computed approximations against the lab's own


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _hashes(folder: pathlib.Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _data_lines(path: pathlib.Path) -> list[list[str]]:
    return [line.split("#")[0].split() for line in path.read_text().splitlines()
            if line.split("#")[0].strip()]


def _assert_same_adjustment(result: dict, reference: dict, rtol: float = RTOL) -> None:
    """σ̂0 and every camera, image and point parameter, by ID."""
    assert result["converged"] and reference["converged"]
    assert result["sigma0"] == pytest.approx(reference["sigma0"], rel=rtol)
    for section in ("cameras", "images", "points"):
        assert result[section].keys() == reference[section].keys(), section
        for key, entry in reference[section].items():
            for name, value in entry.items():
                if name != "ellipsoid":
                    assert result[section][key][name]["value"] == pytest.approx(
                        value["value"], rel=rtol, abs=ATOL), (section, key, name)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The lab adjusted as it is, and its incomplete copy adjusted and initialised."""
    root = tmp_path_factory.mktemp("init")
    code, _, stderr = _run("adjust", str(LAB / "lab.toml"), "--out", str(root / "reference"))
    assert code == 0, stderr
    project_file = incomplete_lab(root / "incomplete")
    inputs = _hashes(root / "incomplete")
    adjusted = _run("adjust", str(project_file), "--out", str(root / "adjusted"))
    initialised = _run("init", str(project_file), "--out", str(root / "completed"))
    return {
        "root": root, "project_file": project_file, "inputs": inputs,
        "reference": json.loads((root / "reference" / "results.json").read_text()),
        "adjusted": adjusted, "initialised": initialised,
    }


# --- jaxba adjust ----------------------------------------------------------------------------


def test_adjust_computes_the_approximations_first(lab):
    code, stdout, stderr = lab["adjusted"]
    assert code == 0, stderr
    assert "computing approximations for 18 images and 77 points ..." in stdout
    assert "initialised 18 of 18 images and 80 of 80 points" in stdout
    assert "pair img01-" in stdout  # indices named by ID
    assert stdout.index("computing approximations") < stdout.index("iter  0")
    assert "suspect blunders" not in stderr  # clean data: what the camera's unknown
    assert "0 blunders flagged" in stdout  # distortion leaves is no evidence of a blunder
    assert "camera C1: 1395 image points in 18 images" in stdout  # named by its ID
    results = json.loads((lab["root"] / "adjusted" / "results.json").read_text())
    _assert_same_adjustment(results, lab["reference"])
    assert "initialisation" not in lab["reference"]


def test_results_json_says_what_was_computed(lab):
    section = json.loads((lab["root"] / "adjusted" / "results.json").read_text())[
        "initialisation"]
    assert len(section["computed_images"]) == 18 and section["computed_images"][0] == "img01"
    assert len(section["computed_points"]) == 77 and "1" not in section["computed_points"]
    assert sum(section["image_methods"].values()) == 18 and "given" not in section["image_methods"]
    assert section["point_methods"] == {"given": 3, "intersection": 77}
    assert section["frame"] == "control"
    assert any(line.startswith("initialised 18 of 18 images") for line in section["log"])
    assert section["suspects"] == []  # clean data, an approximate camera
    for suspect in section["suspects"]:
        assert set(suspect) == {"image", "point", "line", "sigmas"} and suspect["sigmas"] > 3
    assert _hashes(lab["root"] / "incomplete") == lab["inputs"]


# --- jaxba init ------------------------------------------------------------------------------


def test_init_writes_the_completed_project(lab):
    code, stdout, stderr = lab["initialised"]
    assert code == 0, stderr
    folder = lab["root"] / "completed"
    assert sorted(p.name for p in folder.iterdir()) == sorted(TABLES)
    for name in ("cameras.toml", "image_coordinates.txt", "distances.txt"):
        assert (folder / name).read_bytes() == (LAB / name).read_bytes(), name
    images = _data_lines(folder / "orientation.txt")
    assert len(images) == 18 and not any("-" in row[2:8] for row in images)
    points = _data_lines(folder / "ground_points.txt")
    assert [row[0] for row in points[:3]] == ["1", "10", "71"]  # the given rows first, kept
    assert len(points) == 80 and all(row[4:] == ["-", "-", "-"] for row in points[3:])
    assert _hashes(lab["root"] / "incomplete") == lab["inputs"]
    spec = jaxba.read_project(folder / "lab.toml")
    assert spec.complete and spec.settings == jaxba.read_project(LAB / "lab.toml").settings


def test_the_completed_project_adjusts_without_computing(lab):
    folder = lab["root"] / "completed"
    code, stdout, stderr = _run("adjust", str(folder / "lab.toml"),
                                "--out", str(lab["root"] / "again"))
    assert code == 0, stderr
    assert "computing approximations" not in stdout
    results = json.loads((lab["root"] / "again" / "results.json").read_text())
    assert "initialisation" not in results
    adjusted = json.loads((lab["root"] / "adjusted" / "results.json").read_text())
    _assert_same_adjustment(results, adjusted, rtol=1e-12)  # the same approximations
    _assert_same_adjustment(results, lab["reference"])


def test_init_of_a_complete_project_copies_it(lab, tmp_path):
    code, stdout, _ = _run("init", str(LAB / "lab.toml"), "--out", str(tmp_path / "copy"))
    assert code == 0 and "nothing to compute" in stdout
    for name in TABLES[1:]:
        assert (tmp_path / "copy" / name).read_bytes() == (LAB / name).read_bytes(), name


def test_a_camera_used_by_no_image_is_named_in_a_warning(tmp_path):
    """A cameras file shared by several projects lists cameras that this one does not use:
    not an error, but never dropped in silence (the API: `ProjectSpec.unused_cameras`)."""
    shutil.copytree(LAB, tmp_path / "lab", ignore=shutil.ignore_patterns(*OUTPUTS))
    cameras = tmp_path / "lab" / "cameras.toml"
    cameras.write_text(cameras.read_text() + '\n[spare]\nmodel = "smac"\nc = 24.0\n')
    assert jaxba.read_project(tmp_path / "lab" / "lab.toml").unused_cameras == ["spare"]
    code, _, stderr = _run("init", str(tmp_path / "lab" / "lab.toml"),
                           "--out", str(tmp_path / "copy"))
    assert code == 0
    assert ("jaxba: warning: cameras.toml: camera [spare] used by no image of orientation.txt:"
            " left out of the adjustment") in stderr


def test_python_api(lab):
    spec = jaxba.read_project(lab["project_file"])
    with pytest.raises(jaxba.ProjectError, match="18 images .* and 77 points .* have no"
                                                 " approximations"):
        jaxba.build_project(spec)
    same, completion = jaxba.complete_project(jaxba.read_project(LAB / "lab.toml"))
    assert same.complete and not completion.computed_images and not completion.computed_points


# --- errors ----------------------------------------------------------------------------------


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


def test_a_partial_eop_row_is_refused(tmp_path):
    project_file = incomplete_lab(tmp_path / "lab")
    _edit(project_file.parent / "orientation.txt", "img02 C1 - - -", "img02 C1 1.0 2.0 3.0")
    for command in ("adjust", "init"):
        code, _, stderr = _run(command, str(project_file), "--out", str(tmp_path / command))
        assert code == 2, stderr
        assert "orientation.txt:3: column omega" in stderr and "all six" in stderr
        assert not (tmp_path / command).exists()


def test_an_image_that_cannot_be_oriented_is_refused(tmp_path):
    """An image with 3 image points cannot be resected, and a new tie point seen by it and
    one other image cannot be intersected: both named, with the reason, exit 2."""
    project_file = incomplete_lab(tmp_path / "lab")
    with (project_file.parent / "orientation.txt").open("a") as stream:
        stream.write("img19 C1 - - - - - -\n")
    image_points = project_file.parent / "image_coordinates.txt"
    line = len(image_points.read_text().splitlines()) + 3
    with image_points.open("a") as stream:
        stream.write("img19 2 -1.0 -1.0\nimg19 3 1.0 1.0\nimg19 999 0.5 0.5\nimg01 999 0.3 0.3\n")
    code, _, stderr = _run("adjust", str(project_file), "--out", str(tmp_path / "out"))
    assert code == 2, stderr
    assert stderr.startswith("jaxba: error: cannot compute the approximations of 1 image")
    assert "'img19' (orientation.txt:20)" in stderr and "a resection needs 6" in stderr
    assert f"1 point: '999' (image_coordinates.txt:{line}): seen in 2 images, 1 of them" in stderr
    assert "Traceback" not in stderr and not (tmp_path / "out" / "results.json").exists()


def test_init_refuses_the_input_folder(tmp_path):
    project_file = incomplete_lab(tmp_path / "lab")
    before = _hashes(tmp_path / "lab")
    code, _, stderr = _run("init", str(project_file), "--out", str(tmp_path / "lab"))
    assert code == 2
    assert "the folder of the input project lab.toml" in stderr and "--out" in stderr
    assert _hashes(tmp_path / "lab") == before
    # A table beside the output: would be overwritten, refused too.
    (tmp_path / "elsewhere").mkdir()
    shutil.move(tmp_path / "lab" / "distances.txt", tmp_path / "elsewhere" / "distances.txt")
    _edit(project_file, '"distances.txt"', '"../elsewhere/distances.txt"')
    code, _, stderr = _run("init", str(project_file), "--out", str(tmp_path / "elsewhere"))
    assert code == 2 and "distances.txt" in stderr and "overwrite an input" in stderr
    assert main(["init", str(project_file)]) == 2  # --out is required


def test_input_errors_are_reported_before_jax_is_loaded(tmp_path):
    """Fail fast with missing approximations too: a partial `-` row (adjust, init) and the
    input folder as init's output end with exit 2, the file named, and jax never loaded."""
    project_file = incomplete_lab(tmp_path / "lab")
    broken = incomplete_lab(tmp_path / "broken")
    _edit(broken.parent / "orientation.txt", "img05 C1 - - - - - -", "img05 C1 - - - - - 0")
    runs = [["adjust", str(broken), "--out", str(tmp_path / "out")],
            ["init", str(broken), "--out", str(tmp_path / "out")],
            ["init", str(project_file), "--out", str(tmp_path / "lab")]]
    script = ("import json, sys; from jaxba._cli._main import main;"
              " codes = [main(argv) for argv in json.loads(sys.argv[1])];"
              " print(*codes, 'jax' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", script, json.dumps(runs)],
                          capture_output=True, text=True, timeout=60)
    assert done.stdout.split() == ["2", "2", "2", "False"], done.stderr
    assert done.stderr.count("orientation.txt:6: column kappa") == 2
    assert "the folder of the input project" in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow  # ~30 s CPU: an initialisation and two adjustments of 1,070 image points
def test_adjust_defers_weak_points_and_names_those_left_out(tmp_path):
    """A close-range block from nothing: its far 2-ray points under 2° wait for the adjusted
    block and are adjusted in a second run; one whose ray was moved by 60 px cannot be
    intersected even then, and is left out, named on the console, in the .out and in
    results.json."""
    folder = tmp_path / "block"
    truth = jaxba.write_close_range_project(folder, seed=0, n_images=8, n_points=300,
                                            approximations=False)
    table = folder / "image_coordinates.txt"
    lines = table.read_text().splitlines(keepends=True)
    victim = max((line.split()[1] for line in lines[1:]), key=int)  # a far 2-ray point
    rows = [k for k, line in enumerate(lines) if line.split()[1] == victim]
    (image, _, x, y), other = lines[rows[0]].split(), lines[rows[1]].split()[0]
    # Moved by 60 px across its epipolar line (along it, the rays would still meet).
    point = np.array(truth.points[victim])
    m = syn.rotation_matrix(*np.radians(truth.images[image][3:]))
    station, c = np.array(truth.images[image][:3]), truth.cameras["C1"]["c"]
    ends = np.array([point, point + 0.1 * (np.array(truth.images[other][:3]) - point)])
    along = np.diff(syn.project_ideal(ends, station, m, c)[0], axis=0)[0]
    across = np.array([-along[1], along[0]]) / np.linalg.norm(along) * 60 * syn.PIXEL_SIZE[0]
    lines[rows[0]] = f"{image} {victim} {float(x) + across[0]:.8f} {float(y) + across[1]:.8f}\n"
    table.write_text("".join(lines))

    code, stdout, stderr = _run("adjust", str(folder / "close_range.toml"),
                                "--out", str(tmp_path / "out"))
    assert code == 0, stderr
    deferred = int(re.search(r"deferred (\d+) points until the block is adjusted",
                             stdout).group(1))
    assert deferred >= 3
    assert (f"intersected {deferred - 1} of the {deferred} deferred points from the adjusted"
            " block") in stdout
    assert "left out 1 deferred point that the adjusted block cannot intersect" in stdout
    assert f"'{victim}': its 2 rays do not meet" in stdout
    assert stdout.index("intersecting the") < stdout.rindex("iter  0")  # adjusted again

    out = (tmp_path / "out" / "close_range.out").read_text()
    assert f"deferred until the block was adjusted: {deferred} points" in out
    assert "left out, with their image points: 1 points" in out
    assert f"    {victim}: its 2 rays do not meet" in out
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    section = results["initialisation"]
    assert len(section["deferred_points"]) == deferred and victim in section["deferred_points"]
    assert len(section["added_points"]) == deferred - 1
    assert list(section["left_out_points"]) == [victim]
    assert results["converged"]


@pytest.mark.slow  # ~10 s CPU: one initialisation
def test_init_writes_deferred_points_without_approximations(tmp_path):
    """jaxba init cannot intersect the weak points before an adjustment: it writes them
    absent from the points table (their image points kept), says so, and the written project
    misses only them."""
    jaxba.write_close_range_project(tmp_path / "block", seed=0, n_images=8, n_points=300,
                                    approximations=False)
    code, stdout, stderr = _run("init", str(tmp_path / "block" / "close_range.toml"),
                                "--out", str(tmp_path / "completed"))
    assert code == 0, stderr
    count = int(re.search(r"deferred (\d+) points until", stdout).group(1))
    assert (f"the {count} deferred points are written without approximations (absent from"
            " ground_points.txt)") in stdout
    written = jaxba.read_project(tmp_path / "completed" / "close_range.toml")
    assert not written.missing_images and len(written.missing_points) == count
    before = (tmp_path / "block" / "image_coordinates.txt").read_bytes()
    assert (tmp_path / "completed" / "image_coordinates.txt").read_bytes() == before
