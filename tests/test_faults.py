"""Faults, interrupts and bad input: every case ends with its exit code (0 converged, 1 not
converged with reports, 2 bad input, 3 internal error, 130 interrupted), no traceback unless
asked for, no partial report and no input changed.

Most cases stop before jax is loaded; those run `python -m jaxba` in a subprocess, as a
user would. The cases that adjust are marked slow.
"""

import contextlib
import fcntl
import hashlib
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import move_tie_points

import jaxba
from jaxba._cli._main import EXIT_INTERNAL, EXIT_INTERRUPTED, main
from jaxba._files import OutputError, output_lock, replace_files, resolved

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAB = ROOT / "configs" / "lab"
REPORTS = ("lab.out", "lab.res", "lab.sigma", "results.json", "observations.csv")
# Reports the command-line run and prints whether jax was loaded.
RUN_AND_SAY_JAX = ("import sys; from jaxba._cli._main import main; code = main(sys.argv[1:]);"
                   " print(code, 'jax' in sys.modules)")


INTERRUPTIBLE_JAXBA = (
    "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "runpy.run_module('jaxba', run_name='__main__', alter_sys=True)"
)


def _env() -> dict:
    """The test's environment, this checkout first on the path."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}


def _jaxba(*argv, timeout=60) -> subprocess.CompletedProcess:
    """`main(argv)` in a fresh interpreter; stdout is "<exit code> <jax loaded>"."""
    return subprocess.run([sys.executable, "-c", RUN_AND_SAY_JAX, *map(str, argv)],
                          capture_output=True, text=True, timeout=timeout, env=_env())


def _copy_lab(folder: pathlib.Path) -> pathlib.Path:
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns(*REPORTS))
    return folder / "lab.toml"


def _hashes(folder: pathlib.Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


def _run(*argv: str, capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# --- bad input: exit 2, before jax ---------------------------------------------------------


def test_project_toml_not_utf8(tmp_path):
    project = tmp_path / "bad.toml"
    project.write_bytes(b'[project]\nname = "caf\xe9"\n')
    done = _jaxba("adjust", project, "--out", tmp_path / "out")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert done.stderr.startswith("jaxba: error: bad.toml:2: not UTF-8")
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


OPENCV_CAMERA = ('[C1]\nmodel = "opencv"\npixel_size = [0.00369, 0.00369]\n'
                 'sensor = [6000, 4000]\nfx = -2300.0\nfy = 2300.0\ncx = 3000.0\ncy = 2000.0\n')


@pytest.mark.parametrize("file, old, new, expected", [
    ("cameras.toml", "c = 8.5", "c = 0", "cameras.toml: [C1] c: the principal distance"
     " (focal length) of model 'smac' must be > 0, got 0"),
    ("cameras.toml", "c = 8.5", "c = -8.5", "cameras.toml: [C1] c: the principal distance"),
    ("cameras.toml", "c = 8.5\n", "", "cameras.toml: [C1] c: the principal distance (focal"
     " length) of model 'smac' must be > 0, got 0.0 (not given: it defaults to 0)"),
    ("cameras.toml", None, OPENCV_CAMERA, "cameras.toml: [C1] fx: the principal distance"
     " (focal length) of model 'opencv' must be > 0, got -2300.0"),
    ("ground_points.txt", "0.416145635", "1e308",
     "ground_points.txt:3: column X: 1e308 is out of range: numbers must be at most 1e12"),
    ("ground_points.txt", "0.004278617 0 0 0", "-2e12 0 0 0",  # a control point
     "ground_points.txt:2: column Z: -2e12 is out of range"),
    ("ground_points.txt", "0.416145635", "nan", "ground_points.txt:3: column X: expected a"
     " number, got 'nan'"),
    ("orientation.txt", "0.230505449", "1e300", "orientation.txt:2: column X0: 1e300 is out"),
    ("orientation.txt", "26.45930797", "inf", "orientation.txt:2: column omega: expected a"
     " number, got 'inf'"),
    ("image_coordinates.txt", "-8.32120136", "-1E13", "image_coordinates.txt:2: column x:"
     " -1E13 is out of range"),
    ("distances.txt", "4.304697603", "1e20", "distances.txt:2: column distance: 1e20 is out"),
])
def test_bad_values_named_at_reading(tmp_path, file, old, new, expected):
    """A principal distance ≤ 0 (it divides the model or mirrors it) and non-finite or
    absurd numbers (|value| > 1e12, a typo or unit mistake that overflows the model) are
    refused as the project is read, naming the file, line and column or the camera and
    parameter: exit 2 before jax (they were blamed on "camera C1 K1, K2, ..." by the
    datum check)."""
    project = _copy_lab(tmp_path / "lab")
    if old is None:
        (project.parent / file).write_text(new)
    else:
        _edit(project.parent / file, old, new)
    done = _jaxba("adjust", project, "--out", tmp_path / "out")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert done.stderr.startswith("jaxba: error: " + expected), done.stderr
    assert len(done.stderr.splitlines()) == 1 and not (tmp_path / "out").exists()


@pytest.mark.parametrize("text", ["0 0 0\n", "1 0 1\n0 0 1.0 2.0\n1 2 3 4 5 6 7 8 9\n",
                                  "1 1 1\n0 0 1.0 2.0\n1 2 3 4 5 6 7 8 9\n1 2 3\n"])
def test_bal_empty_or_underdetermined(tmp_path, text):
    problem = tmp_path / "problem.txt"
    problem.write_text(text)
    done = _jaxba("bal", problem, "--out", tmp_path / "out")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert done.stderr.startswith("jaxba: error: ") and "problem.txt" in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


def test_bal_results_would_overwrite_the_problem(tmp_path):
    problem = tmp_path / "results.json"
    problem.write_text("1 1 1\n")
    done = _jaxba("bal", problem, "--out", tmp_path)
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert "overwrite an input" in done.stderr and problem.read_text() == "1 1 1\n"


@pytest.mark.parametrize("taken", ["summary.csv", "lab/results.json"])
def test_batch_never_writes_over_an_input(tmp_path, taken):
    """A table of the project where batch would write summary.csv, or a project's report:
    exit 2 before jax, every file unchanged."""
    project = _copy_lab(tmp_path / "in")
    target = tmp_path / "in" / taken
    target.parent.mkdir(exist_ok=True)
    (tmp_path / "in" / "distances.txt").rename(target)
    _edit(project, '"distances.txt"', f'"{taken}"')
    before = _hashes(tmp_path / "in")
    done = _jaxba("batch", project, "--out", tmp_path / "in")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert taken.split("/")[-1] in done.stderr and "overwrite an input" in done.stderr
    assert _hashes(tmp_path / "in") == before


def test_resolved_paths_follow_links_like_realpath(tmp_path, monkeypatch):
    """The output checks resolve folders once and each name by one lstat: through linked
    folders and files, "..", relative and missing paths the same as os.path.realpath."""
    real = tmp_path / "real"
    (real / "sub").mkdir(parents=True)
    (real / "sub" / "file.txt").write_text("x")
    (tmp_path / "linked").symlink_to(real)
    (real / "alias.txt").symlink_to(real / "sub" / "file.txt")
    monkeypatch.chdir(tmp_path)
    paths = ["linked/sub/file.txt", "linked/alias.txt", "real/sub/../alias.txt",
             "linked/missing/new.txt", str(tmp_path / "linked" / "sub"), ".", "/",
             "linked/sub/./file.txt"]
    assert resolved(paths) == {os.path.realpath(path) for path in paths}


def test_batch_refuses_a_report_reached_through_a_link(tmp_path):
    """A project's report folder in --out is a link to the project's own folder: its
    results.json would be the project's input there."""
    project = _copy_lab(tmp_path / "in")
    (tmp_path / "in" / "distances.txt").rename(tmp_path / "in" / "results.json")
    _edit(project, '"distances.txt"', '"results.json"')
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "lab").symlink_to(tmp_path / "in")
    before = _hashes(tmp_path / "in")
    done = _jaxba("batch", project, "--out", tmp_path / "out")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert "results.json" in done.stderr and "overwrite an input" in done.stderr
    assert _hashes(tmp_path / "in") == before


@contextlib.contextmanager
def _read_only(folder: pathlib.Path):
    """`folder` made read-only: by its mode, or (as root, whom modes do not stop) by the
    immutable attribute; skips the test where neither holds."""
    folder.chmod(0o555)
    immutable = False
    try:
        if os.access(folder, os.W_OK):  # root
            immutable = subprocess.run(["chattr", "+i", str(folder)],
                                       capture_output=True).returncode == 0
            if not immutable:
                pytest.skip("cannot make a folder read-only here")
        yield folder
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(folder)], check=True)
        folder.chmod(0o755)


@pytest.mark.parametrize("command", ["adjust", "batch"])
def test_read_only_output_folder(tmp_path, command):
    project = _copy_lab(tmp_path / "lab")
    (tmp_path / "out").mkdir()
    with _read_only(tmp_path / "out"):
        done = _jaxba(command, project, "--out", tmp_path / "out" / "reports")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert "cannot write" in done.stderr and str(tmp_path / "out") in done.stderr
    assert list((tmp_path / "out").iterdir()) == []


def test_concurrent_run_into_one_folder(tmp_path):
    """Another run holds the output folder: exit 2 naming the folder, before jax."""
    project = _copy_lab(tmp_path / "lab")
    out = tmp_path / "out"
    out.mkdir()
    descriptor = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        for command in ("adjust", "batch"):
            done = _jaxba(command, project, "--out", out)
            assert done.stdout.split() == ["2", "False"], done.stderr
            assert str(out) in done.stderr and "another jaxba run" in done.stderr
    finally:
        os.close(descriptor)
    assert list(out.iterdir()) == []


def test_output_lock_is_released(tmp_path):
    with output_lock(tmp_path / "a"):
        with pytest.raises(OutputError, match="another jaxba run"):
            with output_lock(tmp_path / "a"):
                pass
    with output_lock(tmp_path / "a"):
        pass
    assert list((tmp_path / "a").iterdir()) == []  # no lock file left behind


# --- internal errors and interrupts ----------------------------------------------------------


def _fail_with(exception):
    def run(args):
        raise exception

    return run


def test_internal_error_is_one_line_exit_3(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr("jaxba._cli._adjust.run", _fail_with(TypeError("bad thing\nmore detail")))
    code, _, err = _run("adjust", tmp_path / "p.toml", capsys=capsys)
    assert code == EXIT_INTERNAL == 3
    assert err.startswith("jaxba: internal error: TypeError: bad thing. This is a bug")
    assert "--debug" in err and "Traceback" not in err and len(err.splitlines()) == 1
    code, _, err = _run("adjust", tmp_path / "p.toml", "--debug", capsys=capsys)
    assert code == 3 and err.startswith("Traceback") and "TypeError: bad thing" in err


def test_interrupt_is_exit_130_without_traceback(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr("jaxba._cli._batch.run", _fail_with(KeyboardInterrupt()))
    code, _, err = _run("batch", tmp_path / "p.toml", "--out", tmp_path, capsys=capsys)
    assert code == EXIT_INTERRUPTED == 130
    assert err == "jaxba: interrupted\n"


def test_interrupt_dropped_in_a_finaliser_is_silent_and_still_stops_the_run(capsys):
    """A Ctrl-C whose KeyboardInterrupt is raised inside a finaliser or garbage-collector
    callback (jax runs one at every collection) is dropped by Python: the command still
    stops with it at the end, and Python's "Exception ignored" traceback is not printed."""
    from jaxba._cli._common import remember_interrupt, remembered_interrupts

    class InterruptedWhileCollected:
        def __del__(self):
            remember_interrupt(signal.SIGINT, None)

    hook_before = sys.unraisablehook
    # As from an interactive shell: a background job (CI) inherits SIGINT ignored, and the
    # CLI then leaves interrupts alone.
    handler_before = signal.signal(signal.SIGINT, signal.default_int_handler)
    went_on = False
    try:
        with pytest.raises(KeyboardInterrupt), remembered_interrupts():
            InterruptedWhileCollected()  # dropped at once: __del__ runs, its exception is lost
            went_on = True  # the run goes on past the lost interrupt
    finally:
        signal.signal(signal.SIGINT, handler_before)
    assert went_on
    assert capsys.readouterr().err == ""
    assert sys.unraisablehook is hook_before


@pytest.mark.parametrize("durable", [True, False])
def test_replace_files_keeps_the_old_files_when_writing_fails(tmp_path, monkeypatch, durable):
    old = {tmp_path / "a.txt": "old a", tmp_path / "b.txt": "old b"}
    for path, text in old.items():
        path.write_text(text)
    real_fdopen = os.fdopen
    calls = []

    def full_disk_on_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real_fdopen(*args, **kwargs)

    monkeypatch.setattr(os, "fdopen", full_disk_on_second)
    with pytest.raises(OSError, match="No space"):
        replace_files({path: "new" for path in old}, durable=durable)
    assert {path: path.read_text() for path in old} == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]  # no temporary


@pytest.mark.parametrize("durable", [True, False])
def test_replace_files_flushes_each_file_only_when_durable(tmp_path, monkeypatch, durable):
    """`durable`: one fsync per file before the renames; without it none. Either way every
    file is replaced with the permissions 0o666 less the umask (read, not set, to find it)."""
    synced = []
    monkeypatch.setattr(os, "fsync", synced.append)
    umask = os.umask(0o027)
    try:
        replace_files({tmp_path / "a.txt": "a", tmp_path / "b.bin": b"b"}, durable=durable)
    finally:
        os.umask(umask)
    assert len(synced) == (2 if durable else 0)
    assert (tmp_path / "a.txt").read_text() == "a" and (tmp_path / "b.bin").read_bytes() == b"b"
    assert {path.stat().st_mode & 0o777 for path in tmp_path.iterdir()} == {0o640}


@pytest.mark.slow  # starts jax and compiles
def test_sigint_during_a_run(tmp_path):
    """Ctrl-C while the adjustment starts: exit 130, "interrupted", no traceback, no report
    (nor a temporary file) in the output folder. The child gets an empty compilation cache
    so that the run is still compiling (seconds) when the signal comes."""
    project = _copy_lab(tmp_path / "lab")
    out = tmp_path / "out"
    env = {**_env(), "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    # A shell's background job (CI) ignores SIGINT and its children inherit that; Python
    # then installs no KeyboardInterrupt handler, so the child installs it first (as
    # `python -m jaxba` would have from an interactive shell).
    process = subprocess.Popen(
        [sys.executable, "-c", INTERRUPTIBLE_JAXBA, "adjust", str(project), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        for line in process.stdout:  # interrupt once the run is under way
            if line.startswith("adjusting"):
                break
        time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, stderr
    assert stderr.strip().endswith("jaxba: interrupted") and "Traceback" not in stderr
    assert list(out.iterdir()) == []


# --- failed solves still write their reports --------------------------------------------------


def test_adjust_refuses_float32():
    project = jaxba.build_project(jaxba.read_project(LAB / "lab.toml"))
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="float64"):
            jaxba.adjust(project.problem)


@pytest.mark.slow  # a cold compilation of its own shapes
def test_singular_normal_matrix_writes_reports_exit_1(tmp_path, capsys):
    """K0 weighted with a vague prior (σ 1000) beside a free c (both free is refused by the
    datum check): the solve collapses (c → 0, K0 → 1) and N is singular at its end. Exit 1,
    reports written with σ unavailable (null in results.json), no traceback."""
    truth = jaxba.write_synthetic_project(tmp_path / "k0", seed=3, n_images=6, n_targets=20)
    cameras = truth.project_file.parent / "cameras.toml"
    cameras.write_text(cameras.read_text() + "\n[C1.sigma]\nK0 = 1000.0\n")
    code, out, err = _run("adjust", truth.project_file, "--out", tmp_path / "out",
                          capsys=capsys)
    assert code == 1, err
    assert "singular" in err and "Traceback" not in err and "NOT converged" in out
    data = jaxba.read_observations(tmp_path / "out" / "observations.csv")
    assert np.all(np.isnan(data["rx"]))  # no reliability
    results = (tmp_path / "out" / "results.json").read_text()
    assert '"converged": false' in results and '"std": null' in results


# --- messages that name the cause ------------------------------------------------------------


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A small self-calibration block (6 images, 20 targets), written once per module."""
    folder = tmp_path_factory.mktemp("synthetic")
    return jaxba.write_synthetic_project(folder, seed=3, n_images=6, n_targets=20).project_file


def _tables(source: pathlib.Path, folder: pathlib.Path) -> pathlib.Path:
    shutil.copytree(source.parent, folder)
    return folder / source.name


def _rows(path: pathlib.Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines()]


def _write_rows(path: pathlib.Path, rows: list[list[str]]) -> None:
    path.write_text("\n".join(" ".join(row) for row in rows) + "\n")


def _move_stations(project: pathlib.Path, moves: dict[str, tuple[float, float, float]]):
    """Give images new approximate projection centres (orientation.txt)."""
    rows = _rows(project.parent / "orientation.txt")
    for row in rows:
        if row and row[0] in moves:
            row[2:5] = (repr(v) for v in moves[row[0]])
    _write_rows(project.parent / "orientation.txt", rows)


def _station(project: pathlib.Path, image: str) -> tuple[float, float, float]:
    row = next(r for r in _rows(project.parent / "orientation.txt") if r and r[0] == image)
    return tuple(float(v) for v in row[2:5])


def _only_in(project: pathlib.Path, point: str, images: set[str]) -> None:
    """Keep the measurements of `point` in `images` only (image_coordinates.txt)."""
    path = project.parent / "image_coordinates.txt"
    rows = [r for r in _rows(path) if not (len(r) > 1 and r[1] == point and r[0] not in images)]
    _write_rows(path, rows)
    assert {r[0] for r in rows if len(r) > 1 and r[1] == point} == images


def _datum_error(project: pathlib.Path, solver: str) -> str:
    built = jaxba.build_project(jaxba.read_project(project))
    with pytest.raises(jaxba.DatumError) as error:
        jaxba.adjust(built.problem, labels=built.labels, solver=solver)
    return str(error.value)


@pytest.mark.slow  # a 16-dimensional null space, and the first compilations of the module
@pytest.mark.parametrize("solver", ["dense", "schur"])
def test_all_stations_on_one_point(synthetic, tmp_path, solver):
    """Every image at one projection centre: no point is intersected. Named as such, not as
    "rank deficiency 76 ... point 63 Z, ..."."""
    project = _tables(synthetic, tmp_path / "p")
    centre = _station(project, "img01")
    _move_stations(project, {f"img0{k}": centre for k in range(2, 7)})
    message = _datum_error(project, solver)
    assert message.startswith("rank deficiency ")
    assert ": all 6 images have the same projection centre (" in message
    assert "are seen from that station only and cannot be intersected" in message


@pytest.mark.parametrize("solver", ["dense", "schur"])
def test_two_images_at_one_station(synthetic, tmp_path, solver):
    """Point 3 measured only in img01 and img02, which have the same approximate projection
    centre: the images and the point are named."""
    project = _tables(synthetic, tmp_path / "p")
    _only_in(project, "3", {"img01", "img02"})
    _move_stations(project, {"img02": _station(project, "img01")})
    message = _datum_error(project, solver)
    assert message.startswith("rank deficiency 1: images img01 and img02 have the same"
                              " projection centre ("), message
    assert message.endswith(": point 3 is seen from that station only and cannot be"
                            " intersected"), message


def test_nearly_parallel_rays(synthetic, tmp_path):
    """Point 3 measured only in img01 and img02, whose stations are 1e-7 m apart (2 m
    from the point): the rays meet at ~3e-6°, a defect for the Schur check's threshold."""
    project = _tables(synthetic, tmp_path / "p")
    _only_in(project, "3", {"img01", "img02"})
    x, y, z = _station(project, "img01")
    _move_stations(project, {"img02": (x + 1e-7, y, z)})
    message = _datum_error(project, "schur")
    assert message.startswith("rank deficiency 1: the rays to point 3 (< "), message
    assert message.endswith("°) are nearly parallel at the approximations, intersecting at"
                            " less than 0.001°"), message


def test_point_in_one_image_through_the_library(synthetic):
    """The reader refuses a free point measured once; a problem built otherwise (here: its
    other measurements masked) names the point and the image, not a datum defect."""
    built = jaxba.build_project(jaxba.read_project(synthetic))
    group = built.problem.groups[0]
    point = built.point_ids.index("3")
    rows = np.flatnonzero(np.asarray(group.point) == point)
    stddev = np.asarray(group.stddev).copy()
    stddev[rows[1:]] = np.inf
    masked = eqx.tree_at(lambda p: p.groups[0].stddev, built.problem, jnp.asarray(stddev))
    image = built.image_ids[int(np.asarray(group.image)[rows[0]])]
    for solver in ("dense", "schur"):
        with pytest.raises(jaxba.DatumError) as error:
            jaxba.adjust(masked, labels=built.labels, solver=solver)
        assert str(error.value) == (
            f"rank deficiency 1: point 3 ({image}) is observed in only one image")


@pytest.mark.parametrize("solver", ["dense", "schur"])
def test_parameter_without_effect_is_not_a_datum_defect(synthetic, tmp_path, solver):
    """P3 free while P1 = P2 = 0 (fixed): no observation depends on it; named as such."""
    project = _tables(synthetic, tmp_path / "p")
    _edit(project.parent / "cameras.toml", '"P1", "P2"]', '"P3"]')
    message = _datum_error(project, solver)
    assert message.startswith("no observation depends on camera C1 P3 at the approximations"
                              " (not a datum matter"), message
    assert "datum defect" not in message


def _point_at_station(project: pathlib.Path, point: str, image: str) -> None:
    """Put the approximation of `point` at the projection centre of `image`."""
    path = project.parent / "ground_points.txt"
    rows = _rows(path)
    for row in rows:
        if row and row[0] == point:
            row[1:4] = (repr(v) for v in _station(project, image))
    _write_rows(path, rows)


@pytest.mark.slow  # compiles a solve of its own
def test_nonfinite_residuals_at_the_start_are_named(synthetic, tmp_path):
    """A point at an image's projection centre: its residuals there are NaN. The datum check
    names the observation; without the check the solve (whose first iterate, the
    approximations, is the only one a non-finite cost can come from: later trial points with
    one are rejected) ends in the same DatumError, exit 2, instead of an exit 1 without
    reports."""
    project = _tables(synthetic, tmp_path / "p")
    _point_at_station(project, "3", "img02")
    built = jaxba.build_project(jaxba.read_project(project))
    expected = ("the residuals are not finite at the approximations of image img02 point 3"
                " (a point at or beside an image's projection centre?): check these"
                " approximations")
    for check in (True, False):
        with pytest.raises(jaxba.DatumError) as error:
            jaxba.adjust(built.problem, labels=built.labels, check=check)
        assert str(error.value) == expected


@pytest.mark.slow  # 50 steps and a cold compilation of their shapes
@pytest.mark.parametrize("solver", ["dense", "schur"])
def test_divergence_names_the_approximations(synthetic, tmp_path, capsys, solver):
    """Tie points 5 m off (the network is 4 m across): the solve stalls at σ̂0 ≈ 700. Exit 1
    with reports marked not converged, and one warning naming what it diverged from and the
    images with the largest residuals, instead of optimistix's bare message."""
    project = _tables(synthetic, tmp_path / "p")
    move_tie_points(project.parent / "ground_points.txt", 5.0)
    code, out, err = _run("adjust", project, "--out", tmp_path / "out", "--solver", solver,
                          capsys=capsys)
    assert code == 1, err
    warning = next(line for line in err.splitlines() if "diverged" in line)
    assert warning.startswith("jaxba: warning: the adjustment diverged from the"
                              " approximations of "), warning
    assert "; the largest residuals are in images img" in warning
    assert "(the maximum number of steps (50) was reached; σ̂0/σ0 = " in warning
    assert "Traceback" not in err and "NOT converged" in out
    results = (tmp_path / "out" / "results.json").read_text()
    assert '"converged": false' in results and "diverged from the approximations" in results
