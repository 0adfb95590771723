"""`jaxba import dbat|colmap|zhang|bal SOURCE --out DIR` and the BAL project writer."""

import contextlib
import io
import pathlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxba
from jaxba._cli._main import main
from jaxba._io._bal import read_bal, write_bal_project

DATA = pathlib.Path(__file__).parent / "data"
TOY = DATA / "bal" / "dubrovnik-3-7-pre.txt"
SOURCES = {
    "dbat": DATA / "dbat_camcal" / "camcaldemo.xml",
    "zhang": DATA / "zhang",
    "bal": TOY,
}
RESIDUAL_ATOL = 1e-8  # pixels: BAL's model in NumPy against the imported project's


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _colmap_model(folder: pathlib.Path) -> pathlib.Path:
    """A two-image COLMAP text model: one SIMPLE_PINHOLE camera, three points."""
    folder.mkdir()
    (folder / "cameras.txt").write_text("1 SIMPLE_PINHOLE 640 480 500 320 240\n")
    (folder / "images.txt").write_text(
        "1 1 0 0 0 0 0 5 1 a.jpg\n300 200 1 340 260 2 320 240 3\n"
        "2 1 0 0 0 -1 0 5 1 b.jpg\n260 200 1 300 260 2 280 240 3\n")
    (folder / "points3D.txt").write_text(
        "1 -0.2 -0.4 0 0 0 0 0.1 1 0 2 0\n2 0.2 0.2 0 0 0 0 0.1 1 1 2 1\n"
        "3 0 0 0 0 0 0 0.1 1 2 2 2\n")
    return folder


@pytest.mark.parametrize("kind", ["dbat", "colmap", "zhang", "bal"])
def test_import_writes_a_project_that_reads(kind, tmp_path):
    source = _colmap_model(tmp_path / "sparse") if kind == "colmap" else SOURCES[kind]
    out = tmp_path / "project"
    code, stdout, stderr = _run("import", kind, str(source), "--out", str(out))
    assert code == 0, stderr
    (project_file,) = [p for p in out.glob("*.toml") if p.name != "cameras.toml"]
    assert project_file.stem == source.name.split(".")[0]
    assert f"jaxba adjust {project_file}" in stdout
    spec = jaxba.read_project(project_file)
    assert spec.images and spec.image_points
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no staging


def test_import_name_option(tmp_path):
    code, _, stderr = _run("import", "bal", str(TOY), "--out", str(tmp_path / "p"),
                           "--name", "toy")
    assert code == 0, stderr
    assert jaxba.read_project(tmp_path / "p" / "toy.toml").name == "toy"


def test_import_refuses_a_non_empty_folder_and_writes_nothing(tmp_path):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "cameras.toml").write_text("mine\n")
    code, _, stderr = _run("import", "bal", str(TOY), "--out", str(out))
    assert code == 2 and "not empty" in stderr
    assert [p.name for p in out.iterdir()] == ["cameras.toml"]
    assert (out / "cameras.toml").read_text() == "mine\n"


def test_a_failed_import_leaves_nothing(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n0 0 1.0\n")
    code, _, stderr = _run("import", "bal", str(bad), "--out", str(tmp_path / "out"))
    assert code == 2 and "bal import of" in stderr and str(bad) in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt"]
    code, _, stderr = _run("import", "zhang", str(tmp_path / "nowhere"), "--out",
                           str(tmp_path / "out"))
    assert code == 2 and "no such file or folder" in stderr


def _bal_residuals(bal) -> np.ndarray:
    """BAL's own model (rotation vectors through SciPy): predicted - observed, (n_obs, 2)."""
    cameras = bal.cameras[bal.camera_index]
    p = Rotation.from_rotvec(cameras[:, :3]).apply(bal.points[bal.point_index]) + cameras[:, 3:6]
    p = -p[:, :2] / p[:, 2:]
    r2 = np.sum(p * p, axis=1, keepdims=True)
    f, k1, k2 = cameras[:, 6:7], cameras[:, 7:8], cameras[:, 8:9]
    return f * (1 + k1 * r2 + k2 * r2 * r2) * p - bal.observed


def test_bal_project_has_the_bal_residuals(tmp_path):
    """The imported project (omega-phi-kappa poses, X0 = -Rᵀt) predicts BAL's image points."""
    bal = read_bal(TOY)
    written = write_bal_project(TOY, tmp_path, name="toy")
    assert (written.n_images, written.n_points, written.n_image_points) == (3, 7, 19)
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    assert project.datum["kind"] == "dependent" and project.datum["image"] == "img0"
    assert project.spec.settings.stop == "cost"  # where jaxba bal and Ceres stop
    problem = project.problem
    expected = {(f"img{c}", str(p)): -v for c, p, v in
                zip(bal.camera_index, bal.point_index, _bal_residuals(bal))}
    groups = [g for g in problem.groups if isinstance(g, jaxba.ImagePoints)]
    assert len(groups) == 1  # one group of the "bal" model, a camera per image in its rows
    assert len(project.camera_rows) == 3
    for group, residual in zip(groups, problem.whitened(problem.initial)):
        for i, p, v in zip(np.asarray(group.image), np.asarray(group.point),
                           np.asarray(residual)):  # σ = 1 px: whitened = observed - predicted
            key = (project.image_ids[i], project.point_ids[p])
            np.testing.assert_allclose(v, expected.pop(key), atol=RESIDUAL_ATOL)
    assert not expected  # every BAL observation is in the project
