"""Ties between camera parameters (BundleProblem.ties, cameras.toml `ties`, `share`,
`per_image`): two cameras sharing one lens's distortion recover the independently simulated
truth; ties give the same adjustment as an equivalent formulation with fewer parameters
(two fully tied cameras = one camera; OpenCV's fy = fx = SMAC's one c); dense and Schur
agree; the reader refuses bad ties naming file, camera and parameter."""

import math
import pathlib
import shutil

import equinox as eqx
import numpy as np
import pytest

import jaxba
from jaxba import advanced
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


SHARE = f'share = {{ camera = "C1", parameters = {list(DISTORTION)!r} }}'.replace("'", '"')


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """A block of two cameras with one lens (C2 shares C1's K1..P2), simulated by NumPy."""
    directory = tmp_path_factory.mktemp("shared")
    truth = jaxba.write_synthetic_project(
        directory, seed=5, n_images=8, n_targets=30, n_cameras=2,
        camera={"C1": DEFAULT_CAMERA, "C2": LENS_2})
    _write(directory, _camera_table("C1", _approximations(DEFAULT_CAMERA), FREE)
           + _camera_table("C2", _approximations(LENS_2), ("xp", "yp", "c"), [SHARE]))
    return truth


@pytest.fixture(scope="module")
def shared(block):
    """The block adjusted densely."""
    project = jaxba.build_project(jaxba.read_project(block.project_file))
    return block, project, jaxba.adjust(project.problem, labels=project.labels, solver="dense")


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
    positions = advanced.unflatten(problem.initial,
                                   np.arange(advanced.flatten(problem.initial).size))
    k1 = jaxba.CAMERA_MODELS[model].parameter_names.index("K1")
    pair = np.asarray(positions.cameras[model])[:, k1]
    covariance = result.precision.covariance_of(pair)
    np.testing.assert_allclose(covariance, s1["K1"] ** 2 * np.ones((2, 2)), rtol=1e-12)


def test_schur_agrees_with_dense(shared):
    _, project, dense = shared
    schur = jaxba.adjust(project.problem, solver="schur", check=False)
    assert schur.backend == "schur"
    for a, b in zip(advanced.flatten(schur.parameters), advanced.flatten(dense.parameters)):
        assert a == pytest.approx(b, abs=1e-9)
    np.testing.assert_allclose(advanced.flatten(schur.precision.std),
                               advanced.flatten(dense.precision.std), rtol=1e-6, atol=1e-15)
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
    a = jaxba.adjust(tied.problem, solver=solver, check=False)
    b = jaxba.adjust(one.problem, solver=solver, check=False)
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
    a = jaxba.adjust(smac.problem, solver="dense", check=False)
    b = jaxba.adjust(opencv.problem, solver="dense", check=False)
    assert a.precision.sigma0_squared == pytest.approx(b.precision.sigma0_squared, rel=1e-8)
    c, cv = _camera(smac, a, "C1"), _camera(opencv, b, "C1")
    sc, scv = _camera(smac, a, "C1", "std"), _camera(opencv, b, "C1", "std")
    assert cv["fy"] == cv["fx"] and scv["fy"] == scv["fx"]
    assert cv["fx"] * ps == pytest.approx(c["c"], rel=1e-9)
    assert scv["fx"] * ps == pytest.approx(sc["c"], rel=1e-6)
    assert (cv["cx"] - centre[0]) * ps == pytest.approx(c["xp"], abs=1e-9)
    assert (centre[1] - cv["cy"]) * ps == pytest.approx(c["yp"], abs=1e-9)
    np.testing.assert_allclose(b.parameters.points, a.parameters.points, atol=1e-8)


def test_per_image_cameras_share_all_but_their_own(tmp_path):
    """`per_image = ["c", "xp", "yp"]`: one camera per image; each estimates its own c, xp,
    yp (one truth here: all recover it) and shares the lens."""
    truth = jaxba.write_synthetic_project(tmp_path, seed=6, n_images=6, n_targets=24)
    _write(tmp_path, _camera_table("C1", _approximations(DEFAULT_CAMERA), FREE,
                                   ['per_image = ["c", "xp", "yp"]']))
    spec = jaxba.read_project(truth.project_file)
    assert [image.camera for image in spec.images.values()] == [
        f"C1@{iid}" for iid in spec.images]
    first = next(iter(spec.images))
    assert spec.cameras[f"C1@{list(spec.images)[1]}"].ties["K1"] == (f"C1@{first}", "K1")
    project = jaxba.build_project(spec)
    n_points = int(np.sum(np.asarray(project.problem.free.points)))
    assert project.problem.n_unknowns() == len(FREE) + 3 * 5 + 6 * 6 + n_points
    result = jaxba.adjust(project.problem, labels=project.labels, solver="dense")
    assert result.converged
    assert 0.7 < math.sqrt(result.precision.sigma0_squared) < 1.3
    lens = _camera(project, result, f"C1@{first}")
    for cid in project.camera_rows:
        value, std = _camera(project, result, cid), _camera(project, result, cid, "std")
        for name in FREE:
            assert abs(value[name] - truth.cameras["C1"][name]) < 4 * std[name], (cid, name)
        assert all(value[name] == lens[name] for name in DISTORTION)


def test_shared_k0_with_per_image_c_is_refused(tmp_path):
    """K0 (shared) and each image's c are one scale: refused by the datum check that `adjust`
    runs first (test_metrology: for either solver), naming them."""
    from jaxba._statistics._datum import check_separable

    truth = jaxba.write_synthetic_project(tmp_path, seed=6, n_images=4, n_targets=16)
    _write(tmp_path, _camera_table("C1", _approximations(DEFAULT_CAMERA), (*FREE, "K0"),
                                   ['per_image = ["c"]']))
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    k0 = jaxba.SmacCamera.parameter_names.index("K0")
    assert not np.asarray(project.problem.free.cameras["smac"])[1:, k0].any()  # tied
    with pytest.raises(jaxba.DatumError, match="K0 and c of camera C1@img01 are not separable"):
        check_separable(project.problem, project.labels)


C1 = _camera_table("C1", _approximations(DEFAULT_CAMERA), FREE)
C2_START = _approximations(LENS_2)


@pytest.mark.parametrize("cameras, expected", [
    (_camera_table("C2", C2_START, (), ['ties = { Q1 = "K1" }']),
     ["cameras.toml", "[C2] ties Q1", "unknown parameter 'Q1'"]),
    (_camera_table("C2", C2_START, (), ['ties = { K1 = "C9.K1" }']),
     ["[C2] ties K1", "unknown camera 'C9'"]),
    (_camera_table("C2", C2_START, (), ['ties = { K1 = "C1.K2" }']),
     ["[C2] ties K1", "one name", "K1 = C1.K2"]),
    ('[C2]\nmodel = "opencv"\nfx = 2300.0\nfy = 2300.0\nties = { k1 = "C1.k1" }\n',
     ["[C2] ties k1", "unknown parameter 'k1' of camera C1", "smac"]),
    (_camera_table("C2", C2_START, ("c", "K1"), [SHARE]),
     ["[C2] ties K1", "'K1' is also free", "C1.K1"]),
    (_camera_table("C2", C2_START | {"K1": 1e-3}, ("c",), [SHARE]),
     ["[C2] K1 = 0.001", "tied to C1.K1"]),
    (_camera_table("C2", C2_START, ("c",), ['share = { camera = "C1" }']),
     ["[C2] share", "expected"]),
    (_camera_table("C2", C2_START, ("c",), ['per_image = ["K3"]']),
     ["[C2] per_image", "'K3' is fixed"]),
    (_camera_table("C2", C2_START, ("c",), ['ties = { A1 = "C3.A1" }'])
     + _camera_table("C3", C2_START, (), ['ties = { A1 = "C2.A1" }']),
     ["cameras.toml", "cycle", "C2.A1 = C3.A1 = C2.A1"]),
    (_camera_table("C2", C2_START, ("c",), ['ties = { A1 = "C3.A1" }'])
     + _camera_table("C3", C2_START, ("A1",)),
     ["[C2] ties A1", "camera C3", "used by no image"]),
])
def test_bad_ties_are_refused(block, tmp_path, cameras, expected):
    for path in block.project_file.parent.iterdir():
        shutil.copy(path, tmp_path / path.name)
    _write(tmp_path, C1 + cameras)
    with pytest.raises(jaxba.ProjectError) as error:
        jaxba.read_project(tmp_path / block.project_file.name)
    for part in expected:
        assert part in str(error.value)


def test_reports_mark_tied_parameters(shared):
    """results.json and the .out file: a tied parameter with its source's value and σ."""
    from jaxba._report import out_text, results_dict

    _, project, result = shared
    cameras = results_dict(project, result)["cameras"]
    assert cameras["C2"]["K1"]["status"] == "tied to C1.K1"
    assert cameras["C2"]["K1"]["std"] == cameras["C1"]["K1"]["std"] > 0
    assert cameras["C2"]["K1"]["value"] == cameras["C1"]["K1"]["value"]
    assert cameras["C2"]["c"]["status"] == "free"
    row = next(line.split() for line in out_text(project, result).splitlines()
               if "tied to C1.P2" in line)
    assert row[0] == "P2" and float(row[2]) == pytest.approx(cameras["C1"]["P2"]["std"], rel=1e-3)


def test_jacobian_of_tied_slots_is_the_sum_of_their_columns(shared):
    """A tie within a camera (C1's P2 = P1: one row's two slots in one column) and between
    cameras: the per-row blocks scattered into the source's column (dense Jacobian, column
    norms) equal forward-mode differentiation through the tie's gather (J·T)."""
    from helpers import jacfwd_jacobian

    from jaxba._problem._linearisation import column_norms, dense_jacobian

    _, project, result = shared
    problem = project.problem
    model = project.camera_rows["C1"][0]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    positions = np.asarray(advanced.unflatten(
        problem.initial, np.arange(advanced.flatten(problem.initial).size)).cameras[model])
    p1, p2 = (int(positions[0, names.index(n)]) for n in ("P1", "P2"))
    ties = tuple((d, p1 if s == p2 else s) for d, s in problem.ties) + ((p2, p1),)
    free = problem.free.cameras[model].at[0, names.index("P2")].set(False)
    tied = jaxba.BundleProblem(
        problem.initial, eqx.tree_at(lambda f: f.cameras[model], problem.free, free),
        problem.groups, ties=ties)
    assert tied.n_unknowns() == problem.n_unknowns() - 1
    params = tied.with_free(result.parameters)
    jacobian, e = (np.asarray(a) for a in dense_jacobian(tied, params))
    reference, e_ref = (np.asarray(a) for a in jacfwd_jacobian(tied, params))
    np.testing.assert_allclose(jacobian, reference, rtol=1e-9, atol=1e-9 * np.abs(reference).max())
    np.testing.assert_allclose(e, e_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(column_norms(tied, params)),
                               np.linalg.norm(reference, axis=0), rtol=1e-9)
