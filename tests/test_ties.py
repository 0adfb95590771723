"""Ties between camera parameters (BundleProblem.ties, cameras.toml `ties`, `share`,
`per_image`): two cameras sharing one lens's distortion recover the independently simulated
truth; ties give the same adjustment as an equivalent formulation with fewer parameters
(two fully tied cameras = one camera; OpenCV's fy = fx = SMAC's one c); dense and Schur
agree; the reader refuses bad ties naming file, camera and parameter."""

import math
import pathlib
import shutil

import numpy as np
import pytest

import jaxba
from jaxba._io._synthetic import DEFAULT_CAMERA, IOP_NAMES, PIXEL_SIZE, SENSOR

DISTORTION = ("K1", "K2", "K3", "P1", "P2")
FREE = ("xp", "yp", "c", *DISTORTION)
# One lens (C1's distortion) on two bodies: their own principal point and distance.
LENS_2 = DEFAULT_CAMERA | {"xp": 0.03, "yp": 0.011, "c": 8.61}


def _camera_table(cid, values, free, extra=()):
    lines = [f"[{cid}]", 'model = "smac"', f"pixel_size = [{PIXEL_SIZE[0]}, {PIXEL_SIZE[1]}]",
             f"sensor = [{SENSOR[0]}, {SENSOR[1]}]"]
    lines += [f"{name} = {values[name]!r}" for name in IOP_NAMES if values.get(name)]
    lines += [f"free = {list(free)!r}".replace("'", '"'), *extra, ""]
    return "\n".join(lines)


def _approximations(truth):
    return {name: (round(truth["c"], 1) if name == "c" else 0.0) for name in IOP_NAMES}


def _write(directory: pathlib.Path, cameras_toml: str) -> None:
    (directory / "cameras.toml").write_text(cameras_toml)


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """A block of two cameras with one lens (C2 shares C1's K1..P2), adjusted densely."""
    directory = tmp_path_factory.mktemp("shared")
    truth = jaxba.write_synthetic_project(
        directory, seed=5, n_images=8, n_targets=30, n_cameras=2,
        camera={"C1": DEFAULT_CAMERA, "C2": LENS_2})
    share = f'share = {{ camera = "C1", parameters = {list(DISTORTION)!r} }}'.replace("'", '"')
    _write(directory, _camera_table("C1", _approximations(DEFAULT_CAMERA), FREE)
           + _camera_table("C2", _approximations(LENS_2), ("xp", "yp", "c"), [share]))
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    return truth, project, jaxba.adjust(project.problem, labels=project.labels, solver="dense")


def _camera(project, result, cid, what="parameters"):
    model, row = project.camera_rows[cid]
    tree = result.parameters if what == "parameters" else result.precision.std
    names = jaxba.CAMERA_MODELS[model].parameter_names
    return dict(zip(names, np.asarray(tree.cameras[model])[row].tolist()))


def test_shared_distortion_recovers_the_truth(shared):
    truth, project, result = shared
    assert result.converged
    problem = project.problem
    # 8 IOPs of C1 + 3 of C2 + 6 per image + the free coordinates: the tie counts once.
    n_points = int(np.sum(np.asarray(problem.free.points)))
    assert problem.n_unknowns() == 8 + 3 + 6 * 8 + n_points
    assert result.precision.redundancy == problem.n_observations() - problem.n_unknowns()
    assert 0.75 < math.sqrt(result.precision.sigma0_squared) < 1.25
    for cid in ("C1", "C2"):
        value, std = _camera(project, result, cid), _camera(project, result, cid, "std")
        for name in FREE:
            assert std[name] > 0
            assert abs(value[name] - truth.cameras[cid][name]) < 4 * std[name], (cid, name)
    # The tied parameters are C1's unknowns: same value and σ, correlation 1.
    c1, c2 = (_camera(project, result, cid) for cid in ("C1", "C2"))
    s1, s2 = (_camera(project, result, cid, "std") for cid in ("C1", "C2"))
    for name in DISTORTION:
        assert c2[name] == c1[name] and s2[name] == s1[name]
    model = project.camera_rows["C1"][0]
    positions = jaxba.unflatten(problem.initial, np.arange(jaxba.flatten(problem.initial).size))
    k1 = jaxba.CAMERA_MODELS[model].parameter_names.index("K1")
    pair = np.asarray(positions.cameras[model])[:, k1]
    covariance = result.precision.covariance_of(pair)
    np.testing.assert_allclose(covariance, s1["K1"] ** 2 * np.ones((2, 2)), rtol=1e-12)


def test_schur_agrees_with_dense(shared):
    _, project, dense = shared
    schur = jaxba.adjust(project.problem, labels=project.labels, solver="schur")
    assert schur.backend == "schur"
    for a, b in zip(jaxba.flatten(schur.parameters), jaxba.flatten(dense.parameters)):
        assert a == pytest.approx(b, abs=1e-9)
    np.testing.assert_allclose(jaxba.flatten(schur.precision.std),
                               jaxba.flatten(dense.precision.std), rtol=1e-6, atol=1e-15)
    assert schur.precision.redundancy == dense.precision.redundancy


def test_two_fully_tied_cameras_are_one_camera(tmp_path, solver="dense"):
    """Images of C1 and C2 with C2 tied to C1 in every free IOP = all images on C1."""
    truth = jaxba.write_synthetic_project(tmp_path, seed=2, n_images=6, n_targets=24,
                                          n_cameras=2, camera={"C1": DEFAULT_CAMERA,
                                                               "C2": DEFAULT_CAMERA})
    share = f'share = {{ camera = "C1", parameters = {list(FREE)!r} }}'.replace("'", '"')
    start = _approximations(DEFAULT_CAMERA)
    _write(tmp_path, _camera_table("C1", start, FREE) + _camera_table("C2", start, (), [share]))
    tied = jaxba.build_project(jaxba.read_project(truth.project_file))
    one_dir = tmp_path / "one"
    shutil.copytree(tmp_path, one_dir, ignore=shutil.ignore_patterns("one"))
    orientation = one_dir / "orientation.txt"
    orientation.write_text(orientation.read_text().replace(" C2 ", " C1 "))
    one = jaxba.build_project(jaxba.read_project(one_dir / truth.project_file.name))
    a = jaxba.adjust(tied.problem, labels=tied.labels, solver=solver)
    b = jaxba.adjust(one.problem, labels=one.labels, solver=solver)
    assert tied.problem.n_unknowns() == one.problem.n_unknowns()
    assert a.precision.redundancy == b.precision.redundancy
    assert a.precision.sigma0_squared == pytest.approx(b.precision.sigma0_squared, rel=1e-9)
    for cid in ("C1", "C2"):
        np.testing.assert_allclose(list(_camera(tied, a, cid).values()),
                                   list(_camera(one, b, "C1").values()), atol=1e-9)
        np.testing.assert_allclose(list(_camera(tied, a, cid, "std").values()),
                                   list(_camera(one, b, "C1", "std").values()), rtol=1e-6)
    np.testing.assert_allclose(a.parameters.points, b.parameters.points, atol=1e-9)
    np.testing.assert_allclose(a.parameters.images, b.parameters.images, atol=1e-9)


def test_opencv_fy_tied_to_fx_is_smac_with_one_c(tmp_path):
    """A pinhole (no distortion) in pixels: OpenCV with fy = fx tied and SMAC with its one c
    are the same least-squares problem, c = fx ps, xp = (cx - centre) ps."""
    pinhole = {name: (DEFAULT_CAMERA[name] if name in ("xp", "yp", "c") else 0.0)
               for name in IOP_NAMES}
    truth = jaxba.write_synthetic_project(tmp_path, seed=4, n_images=5, n_targets=24,
                                          image_units="pixel", camera=pinhole,
                                          free=("xp", "yp", "c"))
    smac = jaxba.build_project(jaxba.read_project(truth.project_file))
    ps, centre = PIXEL_SIZE[0], [(n - 1) / 2 for n in SENSOR]
    focal = round(pinhole["c"], 1) / ps
    opencv_dir = tmp_path / "opencv"
    shutil.copytree(tmp_path, opencv_dir, ignore=shutil.ignore_patterns("opencv"))
    (opencv_dir / "cameras.toml").write_text("\n".join([
        "[C1]", 'model = "opencv"', f"pixel_size = [{ps}, {ps}]",
        f"sensor = [{SENSOR[0]}, {SENSOR[1]}]", f"fx = {focal!r}", f"fy = {focal!r}",
        f"cx = {centre[0]!r}", f"cy = {centre[1]!r}", 'free = ["fx", "cx", "cy"]',
        'ties = { fy = "fx" }', ""]))
    opencv = jaxba.build_project(jaxba.read_project(opencv_dir / truth.project_file.name))
    assert opencv.problem.n_unknowns() == smac.problem.n_unknowns()
    a = jaxba.adjust(smac.problem, labels=smac.labels, solver="dense")
    b = jaxba.adjust(opencv.problem, labels=opencv.labels, solver="dense")
    assert a.precision.sigma0_squared == pytest.approx(b.precision.sigma0_squared, rel=1e-8)
    c, cv = _camera(smac, a, "C1"), _camera(opencv, b, "C1")
    sc, scv = _camera(smac, a, "C1", "std"), _camera(opencv, b, "C1", "std")
    assert cv["fy"] == cv["fx"] and scv["fy"] == scv["fx"]
    assert cv["fx"] * ps == pytest.approx(c["c"], rel=1e-9)
    assert scv["fx"] * ps == pytest.approx(sc["c"], rel=1e-6)
    assert (cv["cx"] - centre[0]) * ps == pytest.approx(c["xp"], abs=1e-9)
    assert (centre[1] - cv["cy"]) * ps == pytest.approx(c["yp"], abs=1e-9)
    np.testing.assert_allclose(b.parameters.points, a.parameters.points, atol=1e-8)
