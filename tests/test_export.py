"""`jaxba export`: calibrated cameras and rigs of a results.json for OpenCV and COLMAP.

The lab (configs/lab, a SMAC camera in mm) is adjusted once; the pixel cameras and the rig
are results.json files written here by hand from known values. Every check compares with an
independent computation: OpenCV itself (cv2.FileStorage, cv2.projectPoints,
cv2.stereoCalibrate), the SMAC camera's rays in closed form, jaxba's COLMAP reader.
"""

import contextlib
import io
import json
import pathlib
import shutil
import subprocess
import sys

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._cli._main import main
from jaxba._io import read_colmap_model
from jaxba._io._colmap import colmap_pose_to_eop, quaternion_to_matrix
from jaxba._models._rotation_numpy import opk_to_matrix
from jaxba._report._csv import COLUMNS

LAB = pathlib.Path(__file__).resolve().parents[1] / "configs" / "lab"
PIXEL_ATOL = 1e-9  # cv2's projection of an exactly exported camera against jaxba's, pixels
STEREO_ATOL = 1e-6  # stereoCalibrate's R, T, E (relative for F) from noise-free corners
MISFIT_RTOL = 0.05  # the misfit on a denser grid against the export's (41 points a side)
POSE_ATOL = 1e-9  # COLMAP's pose back as EOPs (object units, radians)
G = np.diag([1.0, -1.0, -1.0])  # jaxba's camera frame <-> OpenCV's
OPENCV = {"fx": 812.5, "fy": 809.25, "cx": 331.75, "cy": 236.5, "skew": 0.0, "k1": -0.21,
          "k2": 0.13, "p1": 7e-4, "p2": -4e-4, "k3": -0.02}
OPENCV_FULL = {**OPENCV, "k4": 0.05, "k5": -0.01, "k6": 0.002, "s1": 1e-3, "s2": -2e-4,
               "s3": 5e-4, "s4": 1e-4}
FISHEYE = {"fx": 300.5, "fy": 301.25, "cx": 319.5, "cy": 239.75, "k1": 0.03, "k2": -0.01,
           "k3": 0.002, "k4": -1e-4}
RIG = {"X0": 0.12, "Y0": 0.004, "Z0": -0.003, "omega": 1.5, "phi": -4.0, "kappa": 0.7}


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _entries(values: dict) -> dict:
    return {name: {"value": value, "std": 0.0, "status": "free"} for name, value in values.items()}


def _write_results(folder: pathlib.Path, cameras: dict, *, rigs=None, images=None,
                   observations=None) -> pathlib.Path:
    """A results.json of `cameras` (ID -> (model, values, sensor)) and, optionally, rigs,
    images (ID -> (camera, EOP)) and observations.csv rows (image, point, camera, x, y,
    removed); points P1.. at (k, 2k, -10)."""
    folder.mkdir(parents=True, exist_ok=True)
    images = images or {}
    points = sorted({row[1] for row in observations or []})
    results = {
        "cameras": {cid: _entries(values) for cid, (_, values, _) in cameras.items()},
        "camera_models": {cid: {"model": model, "sensor": sensor, "pixel_size": None}
                          for cid, (model, _, sensor) in cameras.items()},
        "images": {iid: _entries(dict(zip(("X0", "Y0", "Z0", "omega", "phi", "kappa"), eop)))
                   for iid, (_, eop) in images.items()},
        "image_cameras": {iid: camera for iid, (camera, _) in images.items()},
        "points": {pid: _entries({"X": k, "Y": 2.0 * k, "Z": -10.0})
                   for k, pid in enumerate(points)},
    }
    if rigs is not None:
        results["rigs"] = rigs
    (folder / "results.json").write_text(json.dumps(results))
    if observations is not None:
        rows = [",".join(COLUMNS)]
        for image, point, camera, x, y, removed in observations:
            fields = dict.fromkeys(COLUMNS, "") | {
                "type": "image_points", "group": f"image_points:{camera}", "image": image,
                "point": point, "camera": camera, "x": repr(x), "y": repr(y),
                "removed": str(int(removed)), "outlier": str(int(removed))}
            rows.append(",".join(fields[name] for name in COLUMNS))
        (folder / "observations.csv").write_text("\n".join(rows) + "\n")
    return folder


def _read_yaml(path: pathlib.Path, *names: str) -> list:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        return [storage.getNode(name).mat() if storage.getNode(name).isMap()
                else storage.getNode(name).real() for name in names]
    finally:
        storage.release()


def _camera(model: str, values: dict):
    names = jaxba.CAMERA_MODELS[model].parameter_names
    return jaxba.CAMERA_MODELS[model].from_parameters(jnp.array([values[n] for n in names]))


def _jaxba_pixels(camera, p_camera: np.ndarray) -> np.ndarray:
    return np.array([np.asarray(camera.image_point(jnp.asarray(p), jnp.zeros(2), 0.0))
                     for p in p_camera])


def _points_in_front(n: int, seed: int) -> np.ndarray:
    """(n, 3) points of jaxba's camera frame within ±30° of the axis, 1 to 3 units away."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.5, 0.5, (n, 2))
    return np.column_stack([xy, -np.ones(n)]) * rng.uniform(1.0, 3.0, (n, 1))


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> pathlib.Path:
    """configs/lab adjusted (jaxba adjust): the folder with its results.json."""
    folder = tmp_path_factory.mktemp("export") / "lab"
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns("results.json"))
    code, _, stderr = _run("adjust", str(folder / "lab.toml"), "--out", str(folder / "out"))
    assert code == 0, stderr
    return folder / "out"


def test_results_json_names_each_cameras_model_and_sensor(lab):
    results = json.loads((lab / "results.json").read_text())
    model = results["camera_models"]["C1"]
    assert {key: model[key] for key in ("model", "sensor", "pixel_size")} == {
        "model": "smac", "sensor": [6000, 4000], "pixel_size": [0.00369, 0.00369]}


def test_the_lab_camera_is_fitted_its_misfit_reported_and_warned(lab, tmp_path):
    """The SMAC camera has no OpenCV equivalent: through the console (python -m jaxba), the
    fit's misfit is printed and, at about 3 px, warned about; the misfit recomputed on a
    denser grid from the camera's rays in closed form and cv2.projectPoints agrees."""
    to = tmp_path / "opencv"
    done = subprocess.run([sys.executable, "-m", "jaxba", "export", str(lab), "--format",
                           "opencv", "--to", str(to)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    manifest = json.loads((to / "export.json").read_text())["cameras"]["C1"]
    reported = manifest["max_misfit_px"]
    assert not manifest["exact"] and "smac model has no OpenCV equivalent" in done.stdout
    assert f"misfit max {reported:.3g} px" in done.stdout and 2.5 < reported < 3.5
    warnings = done.stderr.strip().splitlines()
    assert len(warnings) == 1 and warnings[0].startswith("jaxba: warning: camera C1:")
    assert f"by up to {reported:.3g} px" in warnings[0] and "above 0.1 px" in warnings[0]

    k, distortion, width, height = _read_yaml(to / "C1.yml", "camera_matrix",
                                              "distortion_coefficients", "image_width",
                                              "image_height")
    assert (width, height) == (6000, 4000)
    results = json.loads((lab / "results.json").read_text())
    smac = _camera("smac", {n: e["value"] for n, e in results["cameras"]["C1"].items()})
    grid = jaxba.PixelGrid((0.00369, 0.00369), (6000, 4000))
    cols, rows = np.meshgrid(np.linspace(-0.5, 5999.5, 121), np.linspace(-0.5, 3999.5, 81))
    pixels = np.column_stack([cols.ravel(), rows.ravel()])
    measured = np.asarray(grid.pixel_to_image(jnp.asarray(pixels)))
    # SMAC corrects the measured point: x = xp + c a + dist(x) for the ray (a, b, -1), so
    # (a, b) = (x - image_point((0, 0, -1), x)) / c, no iteration.
    centre = np.array([np.asarray(smac.image_point(jnp.array([0.0, 0.0, -1.0]), jnp.asarray(m),
                                                   0.0)) for m in measured])
    ab = (measured - centre) / float(smac.c)
    rays_cv = np.column_stack([ab[:, 0], -ab[:, 1], np.ones(len(ab))])
    projected, _ = cv2.projectPoints(rays_cv, np.zeros(3), np.zeros(3), k, distortion)
    dense = np.max(np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1))
    assert dense == pytest.approx(reported, rel=MISFIT_RTOL)


def test_more_coefficients_fit_the_lab_camera_closer(lab, tmp_path):
    code, stdout, stderr = _run("export", str(lab), "--format", "opencv", "--coefficients",
                                "8", "--to", str(tmp_path))
    assert code == 0, stderr
    manifest = json.loads((tmp_path / "export.json").read_text())
    assert manifest["coefficients"] == 8 and manifest["cameras"]["C1"]["max_misfit_px"] < 1.0
    distortion, = _read_yaml(tmp_path / "C1.yml", "distortion_coefficients")
    assert distortion.size == 12 and np.all(distortion.ravel()[5:8] != 0)


def test_opencv_cameras_are_written_exactly(tmp_path):
    """opencv, opencv_full (thin prism included) and fisheye cameras: no fit, no warning;
    the YAML read back by cv2.FileStorage holds the values bit for bit, and OpenCV's
    projection with them is jaxba's."""
    out = _write_results(tmp_path / "out", {
        "A": ("opencv", OPENCV, [640, 480]), "B": ("opencv_full", OPENCV_FULL, [640, 480]),
        "F": ("fisheye", FISHEYE, [640, 480])})
    code, stdout, stderr = _run("export", str(out), "--format", "opencv")
    assert code == 0 and stderr == "", stderr
    assert [line.endswith(": exact") for line in stdout.splitlines()[:3]] == [True] * 3
    folder = out / "export" / "opencv"
    manifest = json.loads((folder / "export.json").read_text())["cameras"]
    assert all(entry["exact"] and entry["max_misfit_px"] == 0.0 for entry in manifest.values())
    p_camera = _points_in_front(50, seed=3)
    for cid, model, values, names in [
            ("A", "opencv", OPENCV, ("k1", "k2", "p1", "p2", "k3")),
            ("B", "opencv_full", OPENCV_FULL, ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
                                               "s1", "s2", "s3", "s4")),
            ("F", "fisheye", FISHEYE, ("k1", "k2", "k3", "k4"))]:
        k, distortion = _read_yaml(folder / f"{cid}.yml", "camera_matrix",
                                   "distortion_coefficients")
        assert k.tolist() == [[values["fx"], values.get("skew", 0.0), values["cx"]],
                              [0.0, values["fy"], values["cy"]], [0.0, 0.0, 1.0]]
        assert distortion.ravel().tolist() == [values[name] for name in names]
        p_cv = (p_camera @ G)[:, None, :]
        project = cv2.fisheye.projectPoints if model == "fisheye" else cv2.projectPoints
        cv_pixels, _ = project(p_cv, np.zeros(3), np.zeros(3), k, distortion)
        np.testing.assert_allclose(cv_pixels.reshape(-1, 2),
                                   _jaxba_pixels(_camera(model, values), p_camera),
                                   atol=PIXEL_ATOL)


def test_skew_has_no_equivalent_it_is_fitted_or_refused(tmp_path):
    """OpenCV's projection ignores K's skew and COLMAP has none: a skewed opencv camera is
    fitted (the message names skew), or refused with --exact."""
    skewed = {**OPENCV, "skew": 0.75}
    out = _write_results(tmp_path / "out", {"A": ("opencv", skewed, [640, 480])})
    code, stdout, stderr = _run("export", str(out), "--format", "opencv")
    assert code == 0, stderr
    assert "skew = 0.75 has no OpenCV equivalent (cv2.projectPoints ignores" in stdout
    manifest = json.loads((out / "export" / "opencv" / "export.json").read_text())
    # Least squares is no worse than the camera with its skew dropped, off by skew y'' with
    # y'' = (row - cy) / fy: its RMS over the sensor (the fit's grid is 41 x 31 of it).
    rows = np.linspace(-0.5, 479.5, 31)
    dropped = skewed["skew"] * np.sqrt(np.mean(((rows - skewed["cy"]) / skewed["fy"]) ** 2))
    assert 0.0 < manifest["cameras"]["A"]["rms_misfit_px"] <= dropped
    assert manifest["cameras"]["A"]["max_misfit_px"] > 0.1
    assert stderr.startswith("jaxba: warning: camera A: the exported OpenCV camera misses")
    for target in ("opencv", "colmap"):
        code, _, stderr = _run("export", str(out), "--format", target, "--exact",
                               "--to", str(tmp_path / f"exact_{target}"))
        assert code == 2 and "camera 'A': skew = 0.75 has no" in stderr
        assert not (tmp_path / f"exact_{target}").exists()


def test_a_mm_project_exports_to_colmap_and_reads_back(lab, tmp_path):
    """The lab (SMAC, mm) as a COLMAP model: poses, points and image points (mm -> COLMAP
    pixels) as results.json and observations.csv say; every image point is its point
    reprojected through the COLMAP camera to within the fit's misfit plus its residual."""
    code, stdout, stderr = _run("export", str(lab), "--format", "colmap", "--coefficients",
                                "8", "--to", str(tmp_path))
    assert code == 0, stderr
    assert "C1: smac -> COLMAP FULL_OPENCV fitted" in stdout
    model = read_colmap_model(tmp_path)
    results = json.loads((lab / "results.json").read_text())
    observations = jaxba._report.read_observations(lab / "observations.csv")
    misfit = json.loads((tmp_path / "export.json").read_text())["cameras"]["C1"]["max_misfit_px"]
    (camera,) = model.cameras.values()
    assert (camera.model, camera.width, camera.height) == ("FULL_OPENCV", 6000, 4000)
    assert [image.name for image in model.images.values()] == list(results["images"])
    assert len(model.points) == len(set(observations["point"][observations["type"]
                                                              == "image_points"]))
    fx, fy, cx, cy, *distortion = camera.params
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    points = {p.id: p for p in model.points.values()}
    worst = 0.0
    for image in model.images.values():
        entries = results["images"][image.name]
        eop = colmap_pose_to_eop(image.qvec, image.tvec)
        expected = [entries[n]["value"] for n in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
        np.testing.assert_allclose(eop, np.r_[expected[:3], np.radians(expected[3:])],
                                   atol=POSE_ATOL)
        rows = (observations["image"] == image.name) & (observations["type"] == "image_points")
        measured = np.column_stack([observations["x"][rows], observations["y"][rows]])
        # mm (y up, origin at the sensor's centre) -> COLMAP pixels (origin at a corner)
        pixels = measured / [0.00369, -0.00369] + [3000.0, 2000.0]
        xy = np.array([(x, y) for x, y, _ in image.points2d])
        np.testing.assert_allclose(xy, pixels, rtol=1e-12, atol=1e-9)
        assert [str(pid) for _, _, pid in image.points2d] == observations["point"][rows].tolist()
        xyz = np.array([points[pid].xyz for _, _, pid in image.points2d])
        np.testing.assert_array_equal(xyz, [[results["points"][str(pid)][c]["value"]
                                             for c in "XYZ"] for _, _, pid in image.points2d])
        rotation = cv2.Rodrigues(quaternion_to_matrix(image.qvec))[0]
        projected, _ = cv2.projectPoints(xyz, rotation, np.array(image.tvec), k,
                                         np.array(distortion))
        v_px = np.hypot(observations["vx"][rows], observations["vy"][rows]) / 0.00369
        error = np.linalg.norm(projected.reshape(-1, 2) - xy, axis=1)
        worst = max(worst, np.max(error - (1 + MISFIT_RTOL) * v_px))
    assert worst <= misfit * (1 + MISFIT_RTOL)


def _stereo_results(folder: pathlib.Path, rig: dict | None = None) -> pathlib.Path:
    right = {**OPENCV, "fx": 805.0, "fy": 803.5, "cx": 322.25, "k1": -0.19, "p2": 2e-4}
    rigs = {"stereo": {"reference": "left", "right": _entries(RIG)}} if rig is None else rig
    return _write_results(folder, {"left": ("opencv", OPENCV, [640, 480]),
                                   "right": ("opencv", right, [640, 480])}, rigs=rigs)


def test_a_rig_is_written_as_opencv_stereo_yaml(tmp_path):
    """A two-camera rig: K1 D1 K2 D2 as the cameras' YAML, and R, T that carry OpenCV's
    projection of camera 1 to jaxba's camera 2; cv2.stereoCalibrate on noise-free corners of
    a board seen by the rig finds the same R, T, E and F."""
    out = _stereo_results(tmp_path / "out")
    code, stdout, stderr = _run("export", str(out), "--format", "opencv")
    assert code == 0 and stderr == "", stderr
    folder = out / "export" / "opencv"
    assert sorted(p.name for p in folder.iterdir()) == [
        "export.json", "left.yml", "right.yml", "stereo_left_right.yml"]
    stereo = folder / "stereo_left_right.yml"
    k1, d1, k2, d2, r, t, e, f, baseline = _read_yaml(
        stereo, "K1", "D1", "K2", "D2", "R", "T", "E", "F", "baseline")
    for k, d, name in ((k1, d1, "left"), (k2, d2, "right")):
        k_alone, d_alone = _read_yaml(folder / f"{name}.yml", "camera_matrix",
                                      "distortion_coefficients")
        np.testing.assert_array_equal(k, k_alone)
        np.testing.assert_array_equal(d, d_alone)
    assert t.shape == (3, 1)
    assert baseline == pytest.approx(np.linalg.norm([RIG["X0"], RIG["Y0"], RIG["Z0"]]),
                                     rel=1e-15)

    station = np.array([RIG["X0"], RIG["Y0"], RIG["Z0"]])
    m = opk_to_matrix(np.radians([RIG["omega"], RIG["phi"], RIG["kappa"]]))
    right_values = {n: e["value"] for n, e in
                    json.loads((out / "results.json").read_text())["cameras"]["right"].items()}
    left, right = _camera("opencv", OPENCV), _camera("opencv", right_values)
    p_rig = _points_in_front(40, seed=5)
    cv_pixels, _ = cv2.projectPoints(p_rig @ G, cv2.Rodrigues(r)[0], t, k2, d2)
    np.testing.assert_allclose(cv_pixels.reshape(-1, 2),
                               _jaxba_pixels(right, (p_rig - station) @ m.T), atol=PIXEL_ATOL)

    # A 9 x 6 board (3 cm) seen from 0.8 units in eight frames, each pixel by jaxba's models.
    rng = np.random.default_rng(11)
    cols, rows = np.meshgrid(np.arange(9) * 0.03 - 0.12, np.arange(6) * 0.03 - 0.075)
    board = np.column_stack([cols.ravel(), rows.ravel(), np.zeros(cols.size)])
    objects, pixels_1, pixels_2 = [], [], []
    for _ in range(8):
        m_frame = opk_to_matrix(np.radians(rng.uniform(-20.0, 20.0, 3)))
        frame_rig = (board - [rng.uniform(-0.05, 0.1), rng.uniform(-0.05, 0.05), 0.8]) @ m_frame.T
        objects.append(board.astype(np.float32))
        pixels_1.append(_jaxba_pixels(left, frame_rig).astype(np.float32)[:, None])
        pixels_2.append(_jaxba_pixels(right, (frame_rig - station) @ m.T)
                        .astype(np.float32)[:, None])
    *_, r_cv, t_cv, e_cv, f_cv = cv2.stereoCalibrate(
        objects, pixels_1, pixels_2, k1, d1, k2, d2, (640, 480), flags=cv2.CALIB_FIX_INTRINSIC)
    np.testing.assert_allclose(r, r_cv, atol=STEREO_ATOL)
    np.testing.assert_allclose(t, t_cv, atol=STEREO_ATOL)
    np.testing.assert_allclose(e, e_cv, atol=STEREO_ATOL)
    np.testing.assert_allclose(f, f_cv, rtol=STEREO_ATOL * 10, atol=STEREO_ATOL * np.abs(f).max())


def test_a_rig_without_its_reference_is_refused_and_one_camera_has_no_pair(tmp_path):
    out = _stereo_results(tmp_path / "out", rig={"stereo": {"right": _entries(RIG)}})
    code, _, stderr = _run("export", str(out), "--format", "opencv")
    assert code == 2 and "rig 'stereo': names no reference camera" in stderr
    out = _stereo_results(tmp_path / "one")
    code, _, stderr = _run("export", str(out), "--format", "opencv", "--camera", "left")
    assert code == 0, stderr
    assert sorted(p.name for p in (out / "export" / "opencv").iterdir()) == [
        "export.json", "left.yml"]


def test_a_pixel_camera_exports_exactly_to_colmap(tmp_path):
    """An opencv camera without skew is COLMAP's FULL_OPENCV as it is (pixels + 0.5); image
    points as observations.csv has them, + 0.5, those removed by data snooping left out."""
    observations = [("i1", "P1", "A", 100.25, 200.5, False), ("i1", "P2", "A", 300.0, 50.0, True),
                    ("i2", "P1", "A", 110.0, 190.0, False), ("i2", "P2", "A", 320.5, 60.0, False)]
    images = {"i1": ("A", (0.1, 0.2, 5.0, 1.0, -2.0, 30.0)),
              "i2": ("A", (1.1, -0.2, 5.5, -3.0, 2.0, 28.0))}
    out = _write_results(tmp_path / "out", {"A": ("opencv", OPENCV, [640, 480])},
                         images=images, observations=observations)
    code, stdout, stderr = _run("export", str(out), "--format", "colmap")
    assert code == 0 and stderr == "", stderr
    assert "A: opencv -> COLMAP FULL_OPENCV: exact" in stdout
    model = read_colmap_model(out / "export" / "colmap")
    (camera,) = model.cameras.values()
    assert camera.params == tuple(OPENCV[n] + (0.5 if n in ("cx", "cy") else 0.0) for n in (
        "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6") if n in OPENCV
    ) + (0.0, 0.0, 0.0)
    first, second = model.images.values()
    assert [(x, y) for x, y, _ in first.points2d] == [(100.75, 201.0)]
    assert [(x, y) for x, y, _ in second.points2d] == [(110.5, 190.5), (321.0, 60.5)]
    for image, (_, eop) in zip((first, second), images.values()):
        np.testing.assert_allclose(colmap_pose_to_eop(image.qvec, image.tvec),
                                   np.r_[eop[:3], np.radians(eop[3:])], atol=POSE_ATOL)
    assert sorted(len(p.track) for p in model.points.values()) == [1, 2]


def test_bad_input_is_refused_with_a_clear_error(lab, tmp_path):
    code, _, stderr = _run("export", str(tmp_path / "nothing"), "--format", "opencv")
    assert code == 2 and "nothing: no such folder" in stderr
    (tmp_path / "empty").mkdir()
    code, _, stderr = _run("export", str(tmp_path / "empty"), "--format", "colmap")
    assert code == 2 and f"{tmp_path / 'empty' / 'results.json'}: no such file" in stderr
    code, _, stderr = _run("export", str(lab), "--format", "opencv", "--camera", "C9",
                           "--to", str(tmp_path / "c9"))
    assert code == 2 and "--camera C9: " in stderr and "its cameras: C1" in stderr
    port = {"xp": 0.0, "yp": 0.0, "c": 8.5, "distance": 10.0}
    out = _write_results(tmp_path / "port", {"U": ("smac+flat_port", port, [6000, 4000])})
    code, _, stderr = _run("export", str(out), "--format", "colmap")
    assert code == 2 and "camera 'U': its flat_port refraction (distance, thickness," in stderr
    older = json.loads((out / "results.json").read_text())
    del older["camera_models"]
    (out / "results.json").write_text(json.dumps(older))
    code, _, stderr = _run("export", str(out), "--format", "opencv")
    assert code == 2 and 'no "camera_models"' in stderr and "adjust the project again" in stderr
    assert not (tmp_path / "c9").exists() and not (out / "export").exists()


def test_never_over_an_input_and_again_into_an_earlier_export(lab, tmp_path):
    """A folder with other files (OUT_DIR itself, with results.json) is refused; an earlier
    export's folder is written again, its files replaced."""
    before = (lab / "results.json").read_bytes()
    code, _, stderr = _run("export", str(lab), "--format", "opencv", "--to", str(lab))
    assert code == 2 and "holds files that jaxba export did not write" in stderr
    assert (lab / "results.json").read_bytes() == before and not (lab / "C1.yml").exists()
    for coefficients in ("4", "5"):
        code, _, stderr = _run("export", str(lab), "--format", "opencv", "--to",
                               str(tmp_path), "--coefficients", coefficients)
        assert code == 0, stderr
    distortion, = _read_yaml(tmp_path / "C1.yml", "distortion_coefficients")
    assert distortion.ravel()[4] != 0  # k3: the second export's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C1.yml", "export.json"]


def test_bad_input_is_reported_before_jax_is_loaded(tmp_path):
    """No results.json: the error comes at once, from a process that never imported jax."""
    script = ("import sys; from jaxba._cli._main import main; code = main(sys.argv[1:]);"
              " print(code, 'jax' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", script, "export", str(tmp_path), "--format",
                           "opencv"], capture_output=True, text=True, timeout=60)
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert done.stderr.startswith("jaxba: error: ") and "results.json: no such file" in done.stderr
    assert not (tmp_path / "export").exists()
