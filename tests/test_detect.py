"""`jaxba detect`: the board grammar, detection in real and rendered images, the project it
writes and that project's calibration.

- OpenCV's stereo sample (its SOURCES.md): each camera detected and adjusted equals OpenCV's
  `calibrateCamera` run here on the same corners.
- ChArUco boards and circle grids rendered here through a known camera with distortion, blur
  and noise: the points found lie on the true projections, and the calibration recovers the
  camera.
- Missing, truncated, non-image and board-less files among the images: each listed with its
  reason, the others calibrated as without them.
"""

import csv
import json
import os
import pathlib
import shutil
import struct
import subprocess
import sys
import tomllib

import cv2
import numpy as np
import pytest

import jaxba
from jaxba._cli._main import main
from jaxba._io._detect import Board, BoardError, charuco_board, parse_board

# OpenCV's stereo sample: a copy in tests/data where there is one, else the shared data folder
# beside the project (or beside the folder of a worktree that lies one level deeper).
HERE = pathlib.Path(__file__).resolve().parent
DATA = next((folder for folder in (HERE / "data" / "opencv_stereo",
                                   HERE.parents[1] / "shared" / "data" / "opencv_stereo",
                                   HERE.parents[2] / "shared" / "data" / "opencv_stereo")
             if folder.is_dir()), HERE / "data" / "opencv_stereo")
NAMES = jaxba.CAMERA_MODELS["opencv"].parameter_names
FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
# jaxba against calibrateCamera on the same corners, in σ of each parameter: both minimise the
# same sum of squares; jaxba stops when a step would move every unknown by < 1e-5 σ, OpenCV's
# Levenberg-Marquardt after its default 30 iterations / 2.2e-16 (DBL_EPSILON) relative change
# (seen: 1.1e-5 σ, cx).
OPENCV_AGREEMENT_SIGMAS = 1e-4
# Rendered images: the calibration against the camera that rendered them, in σ (a posteriori).
# Three σ: each parameter's test at 99.7 % (one fixed seed); the rendering itself (bilinear
# resampling of a 2x supersampled image, blur) adds no bias that shows at that level.
TRUTH_SIGMAS = 3.0
RENDER_PX = 0.15  # RMS of detected - true corner (ChArUco, circle centres), pixels


def _run(*argv: str) -> int:
    return main(list(argv))


def _read_rows(path: pathlib.Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines()
            if line.strip() and not line.startswith("#")]


def _calibration(project_file: pathlib.Path):
    """(values, stds, project, result) of the project's one camera."""
    project = jaxba.build_project(jaxba.read_project(project_file))
    result = jaxba.adjust_project(project)
    assert result.converged
    (camera,) = project.camera_rows
    model, row = project.camera_rows[camera]
    values = dict(zip(NAMES, np.asarray(result.parameters.cameras[model][row])))
    stds = dict(zip(NAMES, np.asarray(result.precision.std.cameras[model][row])))
    return values, stds, project, result


# --- the board grammar ----------------------------------------------------------------------


def test_board_grammar():
    assert parse_board("chessboard:9x6:25mm") == Board("chessboard", 9, 6, 25.0, "mm")
    assert parse_board("circles:4x5:0.02m") == Board("circles", 4, 5, 0.02, "m")
    assert parse_board("acircles:4x11:1.5") == Board("acircles", 4, 11, 1.5, "")
    board = parse_board("charuco:7x5:3cm:22mm:dict_5x5_100:first=4:legacy")
    assert board == Board("charuco", 7, 5, 3.0, "cm", 2.2, "5X5_100", 4, True)
    assert parse_board(board.text()) == board
    assert board.pattern_size == (6, 4) and board.n_markers == 17


@pytest.mark.parametrize("spec, words", [
    ("chess:9x6:25mm", "unknown board"),
    ("chessboard:9by6:25mm", "COLSxROWS"),
    ("chessboard:9x6:25furlongs", "unit"),
    ("chessboard:9x6:-1mm", "number"),
    ("chessboard:9x6", "expected"),
    ("chessboard:1x6:1", "at least"),
    ("charuco:7x5:30mm:40mm:4x4_50", "smaller"),
    ("charuco:7x5:30mm:20mm:4x4_50:firstly", "option"),
])
def test_bad_boards_are_refused_naming_the_part(spec, words):
    with pytest.raises(BoardError, match=words):
        parse_board(spec)


def test_unknown_dictionary_and_too_many_markers():
    with pytest.raises(BoardError, match="no ArUco dictionary"):
        charuco_board(parse_board("charuco:7x5:30mm:20mm:9x9_50"))
    with pytest.raises(BoardError, match="exceed"):
        charuco_board(parse_board("charuco:7x5:30mm:20mm:4x4_50:first=40"))


def test_board_points_are_opencvs():
    """ChArUco corners as OpenCV's board has them; an asymmetric grid as OpenCV's samples
    lay it out: circle (r, c) at ((2c + r mod 2) s, r s)."""
    board = parse_board("charuco:6x4:30:20:4x4_50")
    expected = np.asarray(charuco_board(board).getChessboardCorners())
    np.testing.assert_allclose(board.points(), expected, rtol=0, atol=1e-5)  # float32
    points = parse_board("acircles:4x11:2").points()
    assert points[4].tolist() == [2.0, 2.0, 0.0] and points[5].tolist() == [6.0, 2.0, 0.0]
    assert points[8].tolist() == [0.0, 4.0, 0.0]


# --- approximations -------------------------------------------------------------------------


def test_approximations_from_few_views():
    """Zhang's closed form from three views or more; from two, one focal length with the
    principal point at the centre (`focal_from_homographies`): exact on noise-free views."""
    from jaxba._io._detect._start import camera_start, focal_from_homographies

    k = np.array([[700.0, 0, 319.5], [0, 700.0, 239.5], [0, 0, 1]])
    plane = parse_board("chessboard:9x6:1").points()[:, :2]
    pixels, homographies = [], []
    for rvec, tvec in [((0.3, 0.1, 0.2), (-4, -2, 15)), ((-0.2, 0.35, -0.1), (-3, -3, 14)),
                       ((0.1, -0.3, 0.5), (-5, -1, 16))]:
        rotation = cv2.Rodrigues(np.array(rvec))[0]
        h = k @ np.c_[rotation[:, :2], tvec]
        homographies.append(h)
        uv = np.c_[plane, np.ones(len(plane))] @ h.T
        pixels.append(uv[:, :2] / uv[:, 2:])
    assert np.isclose(focal_from_homographies(homographies, np.array([319.5, 239.5])), 700.0,
                      rtol=1e-9)
    three = camera_start([plane] * 3, pixels, (640, 480))
    two = camera_start([plane] * 2, pixels[:2], (640, 480))
    assert three.method == "Zhang's closed form" and two.method.startswith("one focal length")
    for start in (three, two):
        np.testing.assert_allclose([start.fx, start.fy, start.cx, start.cy],
                                   [700, 700, 319.5, 239.5], rtol=1e-7)
    # the first view's pose: X0 = -Rᵀ t in the board frame
    rotation = cv2.Rodrigues(np.array((0.3, 0.1, 0.2)))[0]
    np.testing.assert_allclose(two.eops[0][:3], -rotation.T @ [-4, -2, 15], rtol=1e-7)


# --- OpenCV's stereo sample -----------------------------------------------------------------


def _grouped(out: pathlib.Path):
    """Board points (n, 3) float32 and pixels (n, 2) float32 of each image of the project."""
    board = {row[0]: [float(v) for v in row[1:4]] for row in _read_rows(out / "board_points.txt")}
    images: dict[str, tuple[list, list]] = {}
    for image, point, u, v in _read_rows(out / "image_coordinates.txt"):
        plane, pixels = images.setdefault(image, ([], []))
        plane.append(board[point])
        pixels.append([float(u), float(v)])
    return ([np.array(p, np.float32) for p, _ in images.values()],
            [np.array(q, np.float32) for _, q in images.values()])


def _detected(folder: pathlib.Path, camera: str) -> pathlib.Path:
    """One camera of OpenCV's stereo sample detected (two processes) into `folder`."""
    code = _run("detect", "--board", "chessboard:9x6:1", "--camera",
                f"{camera}={DATA}/{camera}*.jpg", "--out", str(folder), "--name", camera,
                "--jobs", "2", "--no-progress")
    assert code == 0
    return folder


@pytest.fixture(scope="module")
def left(tmp_path_factory):
    """The left camera of OpenCV's stereo sample: detected and adjusted."""
    out = _detected(tmp_path_factory.mktemp("left") / "project", "left")
    return out, *_calibration(out / "left.toml")


def _assert_calibrate_camera(out: pathlib.Path, values, stds, result) -> float:
    """The adjusted camera equals cv2.calibrateCamera from the project's corners; returns
    OpenCV's RMS."""
    plane, pixels = _grouped(out)
    assert len(plane) == 13 and all(len(p) == 54 for p in plane)
    rms, k, dist, _, _ = cv2.calibrateCamera(plane, pixels, (640, 480), None, None)
    opencv = dict(zip(("fx", "fy", "cx", "cy"), (k[0, 0], k[1, 1], k[0, 2], k[1, 2])))
    opencv |= dict(zip(("k1", "k2", "p1", "p2", "k3"), dist.ravel()))
    for name in FREE:
        assert abs(values[name] - opencv[name]) < OPENCV_AGREEMENT_SIGMAS * stds[name], name
    assert values["skew"] == 0.0
    # OpenCV's RMS is over corners (2-vectors): sqrt(Σ‖e‖² / 702) against σ̂0 over 1317
    residual_sum = result.sigma0**2 * result.precision.redundancy
    assert np.isclose(np.sqrt(residual_sum / 702), rms, rtol=1e-6)
    return rms


def test_opencv_sample_equals_calibrate_camera(left):
    """The adjusted left camera equals cv2.calibrateCamera from the same corners to 1e-4 σ."""
    _assert_calibrate_camera(left[0], left[1], left[2], left[4])


def test_opencv_sample_right_camera_equals_calibrate_camera(tmp_path):
    out = _detected(tmp_path / "project", "right")
    values, stds, _, result = _calibration(out / "right.toml")
    _assert_calibrate_camera(out, values, stds, result)


def test_corner_window_fits_the_squares(left):
    """OpenCV's sample refines every corner in an 11 x 11 window (23 px across); in left02,
    whose squares are about 20 px, that pulls corners up to 5.8 px onto their neighbours.
    With those corners calibrateCamera gives SOURCES.md's result (RMS 0.4080, fx 536.065);
    with jaxba's window (half the corner spacing) the RMS falls to 0.245."""
    plane, ours = _grouped(left[0])
    theirs = []
    for n in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14):
        grey = cv2.imread(str(DATA / f"left{n:02d}.jpg"), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCorners(grey, (9, 6))
        assert found
        theirs.append(cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), (3, 30, 0.01)))
    moved = [min(np.abs(a - b.reshape(-1, 2)).max(), np.abs(a[::-1] - b.reshape(-1, 2)).max())
             for a, b in zip(ours, theirs)]
    assert 5.5 < moved[1] < 6.0 and max(moved[:1] + moved[2:]) < 1e-3
    rms, k = cv2.calibrateCamera(plane, theirs, (640, 480), None, None)[:2]
    assert round(rms, 4) == 0.4080 and round(k[0, 0], 3) == 536.065
    assert cv2.calibrateCamera(plane, ours, (640, 480), None, None)[0] < 0.25


def test_opencv_sample_corners(left):
    """The corners are OpenCV's own (findChessboardCorners + cornerSubPix, 11 x 11 window
    here) in the order that puts the board's dark inner square first."""
    out = left[0]
    rows = _read_rows(out / "image_coordinates.txt")
    ours = np.array([[float(u), float(v)] for image, _, u, v in rows if image == "left01"])
    grey = cv2.imread(str(DATA / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(grey, (9, 6))
    corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), (3, 30, 0.01)).reshape(-1, 2)
    assert found
    assert min(np.abs(ours - corners).max(), np.abs(ours[::-1] - corners).max()) < 1e-4
    square = ours.reshape(6, 9, 2)
    first, last = square[:2, :2].mean(axis=(0, 1)), square[-2:, -2:].mean(axis=(0, 1))
    assert grey[round(first[1]), round(first[0])] < grey[round(last[1]), round(last[0])]


def test_opencv_sample_files(left):
    out = left[0]
    names = {p.name for p in out.iterdir()}
    assert {"left.toml", "cameras.toml", "orientation.txt", "image_coordinates.txt",
            "board_points.txt", "detections.csv", "detections.png"} <= names
    cameras = tomllib.loads((out / "cameras.toml").read_text())
    assert cameras["left"]["model"] == "opencv" and cameras["left"]["sensor"] == [640, 480]
    assert cameras["left"]["free"] == list(FREE)
    points = _read_rows(out / "board_points.txt")
    assert len(points) == 54 and all(row[4:] == ["0", "0", "0"] for row in points)
    assert points[10][1:4] == ["1.0", "1.0", "0.0"]  # row 1, column 1
    sheet = cv2.imread(str(out / "detections.png"))
    assert sheet is not None and sheet.shape[1] > 6 * 200


def test_opencv_sample_approximations(left):
    """Zhang's closed form (distortion ignored) within 3 % of the focal lengths and 15 px of
    the principal point of the adjusted camera."""
    out, values = left[0], left[1]
    start = tomllib.loads((out / "cameras.toml").read_text())["left"]
    assert abs(start["fx"] / values["fx"] - 1) < 0.03
    assert abs(start["fy"] / values["fy"] - 1) < 0.03
    assert abs(start["cx"] - values["cx"]) < 15 and abs(start["cy"] - values["cy"]) < 15


def _settings(path: pathlib.Path) -> dict[str, list[str]]:
    """A project file's lines by table, comments (whole lines and after values) left out."""
    tables: dict[str, list[str]] = {}
    table = ""
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.partition("  #")[0]
        if line.startswith("["):
            table = line
        elif line and not line.startswith("#"):
            tables.setdefault(table, []).append(line)
    return tables


def test_one_project_file_for_every_writer(left, tmp_path):
    """`jaxba detect`, `jaxba init` (the detected project copied) and `jaxba import colmap`
    write the same project file for the same content: the same lines, in the same order,
    comments aside; the rig files and points table COLMAP adds aside."""
    detected = _settings(left[0] / "left.toml")
    assert _run("init", str(left[0] / "left.toml"), "--out", str(tmp_path / "init")) == 0
    assert _settings(tmp_path / "init" / "left.toml") == detected
    colmap_dir = HERE / "data" / "colmap_rig" / "text"
    jaxba.write_colmap_project(colmap_dir, tmp_path / "colmap", name="left", warn=print)
    imported = _settings(tmp_path / "colmap" / "left.toml")
    assert imported["[project]"] == detected["[project]"] == ['name = "left"',
                                                              'image_units = "pixel"']
    assert imported["[adjustment]"] == detected["[adjustment]"]
    assert imported["[files]"][:3] == detected["[files]"][:3]


def test_board_warp_of_the_sample(left, tmp_path):
    """`--board-warp`: `board_warp = true` and every board point written; the warp adjusted
    with the camera. The printed board of OpenCV's sample is bent: kx 0.0065 ± 0.0012, ky
    -0.0067 ± 0.0009 squares, both above 5 σ, σ̂0 0.179 -> 0.172 px; fx moves by 1.2 σ of
    the flat board's calibration, every parameter by less than 2 σ."""
    out = tmp_path / "warped"
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"left={DATA}/left*.jpg",
                "--out", str(out), "--name", "left", "--board-warp", "--jobs", "1",
                "--no-progress") == 0
    assert tomllib.loads((out / "left.toml").read_text())["adjustment"]["board_warp"] is True
    assert len(_read_rows(out / "board_points.txt")) == 54
    values, stds, project, result = _calibration(out / "left.toml")
    flat_values, flat_stds, flat = left[1], left[2], left[4]
    assert project.labels[-2:] == ["board board kx", "board board ky"]
    assert result.precision.redundancy == flat.precision.redundancy - 2
    assert result.sigma0 < flat.sigma0 - 0.005
    warp = result.boards["board"]
    assert all(abs(warp[name].value) > 5 * warp[name].sigma for name in ("kx", "ky"))
    assert warp["kx"].value > 0 > warp["ky"].value
    for name in FREE:
        assert abs(values[name] - flat_values[name]) < 2 * flat_stds[name], name


# --- broken files ---------------------------------------------------------------------------


def test_broken_files_are_listed_and_the_rest_calibrated(left, tmp_path):
    """A missing file (a dangling link), a truncated JPEG, a text file named .jpg, a picture
    with no board, one with a part of the board, and one of another size: each listed with
    its reason; the 13 good images give the calibration of the clean run."""
    folder = tmp_path / "images"
    folder.mkdir()
    for path in DATA.glob("left*.jpg"):
        shutil.copy(path, folder / path.name)
    data = (DATA / "left01.jpg").read_bytes()
    (folder / "left20.jpg").write_bytes(data[: len(data) // 2])
    (folder / "left21.jpg").write_text("not a picture\n")
    os.symlink(folder / "gone.jpg", folder / "left22.jpg")
    grey = cv2.imread(str(DATA / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(folder / "left23.png"), np.full_like(grey, 128))
    cv2.imwrite(str(folder / "left24.png"), grey[:, 380:].copy())  # the board's right part
    cv2.imwrite(str(folder / "left25.png"), cv2.resize(grey, (320, 240)))
    out = tmp_path / "project"
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"left={folder}/left*",
                "--out", str(out), "--name", "left", "--jobs", "1") == 0
    with (out / "detections.csv").open() as stream:
        rows = {row["image_id"]: row for row in csv.DictReader(stream)}
    assert len(rows) == 19
    reasons = {i: rows[i]["reason"] for i in ("left20", "left21", "left22", "left23", "left24",
                                             "left25")}
    assert reasons["left20"].startswith("truncated JPEG")
    assert reasons["left21"] == "not an image"
    assert reasons["left22"] == "missing"
    assert reasons["left23"] == "no board"
    assert reasons["left24"].startswith("partial board")
    assert reasons["left25"] == "size 320x240, not the camera's 640x480"
    assert rows["left25"]["points"] == "54"  # found, then left out
    assert all(rows[f"left{n:02d}"]["used"] == "yes" for n in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11))
    values, stds = _calibration(out / "left.toml")[:2]
    for name in FREE:
        assert abs(values[name] - left[1][name]) < 1e-6 * stds[name], name


def _with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """`jpeg` with an APP1 EXIF segment holding only the Orientation tag (0x0112)."""
    tiff = (b"MM\x00\x2a\x00\x00\x00\x08" + struct.pack(">H", 1)
            + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0))
    app1 = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


def test_exif_orientation_is_ignored(tmp_path, capsys):
    """A JPEG marked "turned 90°" (EXIF orientation 6) is read as the sensor's pixels: the
    same size and corners as without the mark. (Two views: a warning says they are too few.)"""
    data = (DATA / "left01.jpg").read_bytes()
    (tmp_path / "plain01.jpg").write_bytes(data)
    (tmp_path / "turned02.jpg").write_bytes(_with_exif_orientation(data, 6))
    turned = cv2.imdecode(np.frombuffer((tmp_path / "turned02.jpg").read_bytes(), np.uint8),
                          cv2.IMREAD_GRAYSCALE)
    assert turned.shape == (640, 480)  # OpenCV turns it by default
    out = tmp_path / "project"
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"c={tmp_path}/*.jpg",
                "--out", str(out), "--jobs", "1") == 0
    with (out / "detections.csv").open() as stream:
        rows = list(csv.DictReader(stream))
    assert [(r["width"], r["height"], r["used"]) for r in rows] == [("640", "480", "yes")] * 2
    pixels = {}
    for image, _, u, v in _read_rows(out / "image_coordinates.txt"):
        pixels.setdefault(image, []).append((float(u), float(v)))
    assert pixels["plain01"] == pixels["turned02"]
    assert "warning: the board in fewer than 3 images of c (2)" in capsys.readouterr().err


# --- a rig ----------------------------------------------------------------------------------


def test_rig_files(tmp_path):
    """--rig: rigs.toml and frames.txt as docs/project-files.md says; the right camera's
    approximate pose in the left one's frame near OpenCV's stereoCalibrate (SOURCES.md: T
    (-3.3442, 0.0417, 0.0528) squares, R a rotation of 0.31°): the closed form ignores
    distortion, so within 0.3 squares and 15°."""
    out = tmp_path / "rig"
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"left={DATA}/left*.jpg",
                "--camera", f"right={DATA}/right*.jpg", "--rig", "stereo", "--out", str(out),
                "--jobs", "1") == 0
    project = tomllib.loads((out / "calibration.toml").read_text())
    assert project["files"]["rigs"] == "rigs.toml" and project["files"]["frames"] == "frames.txt"
    rigs = tomllib.loads((out / "rigs.toml").read_text())
    assert set(rigs) == {"stereo"} and rigs["stereo"]["reference"] == "left"
    right = rigs["stereo"]["right"]
    assert right["free"] == ["X0", "Y0", "Z0", "omega", "phi", "kappa"]
    # OpenCV: x_right = R x_left + T, so the right centre in the left (OpenCV) frame is
    # -Rᵀ T ≈ -T; the photogrammetric frame is diag(1, -1, -1) of OpenCV's.
    expected = np.array([3.3442, 0.0417, -0.0528])
    assert np.linalg.norm([right["X0"], right["Y0"], right["Z0"]] - expected) < 0.3
    assert max(abs(right[a]) for a in ("omega", "phi", "kappa")) < 15
    frames = _read_rows(out / "frames.txt")
    assert len(frames) == 26
    by_frame: dict[str, list[str]] = {}
    for image, frame in frames:
        by_frame.setdefault(frame, []).append(image)
    assert by_frame["7"] == ["left07", "right07"] and "10" not in by_frame
    assert all(len(images) == 2 for images in by_frame.values())
    _adjust_and_export_rig(out)


# jaxba's corners (window half the corner spacing) differ from OpenCV's 11 x 11 window by up to
# 5.8 px on some images (test_corner_window_against_opencv): the baseline differs from
# stereoCalibrate's on OpenCV's corners by a few of its σ (0.0025 squares), within 0.5 %.
BASELINE_REL = 5e-3


def _adjust_and_export_rig(out):
    """A calibrating user's path from the detected rig: `jaxba adjust` converges with the
    baseline near OpenCV's (SOURCES.md: |T| 3.3381 squares, all free), `jaxba export` writes
    OpenCV's stereo YAML with that T."""
    assert _run("adjust", str(out / "calibration.toml"), "--out", str(out / "adjusted")) == 0
    results = json.loads((out / "adjusted" / "results.json").read_text())
    baseline = results["rigs"]["stereo"]["right"]["baseline"]
    assert baseline["value"] == pytest.approx(3.3381, rel=BASELINE_REL)
    assert 0 < baseline["std"] < 0.01
    assert _run("export", str(out / "adjusted"), "--format", "opencv") == 0
    (path,) = (out / "adjusted" / "export" / "opencv").glob("stereo_*right*.yml")
    stored = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # alive while its nodes are read
    translation = stored.getNode("T").mat()
    assert np.linalg.norm(translation) == pytest.approx(baseline["value"], rel=1e-12)


def test_rig_without_its_reference_camera(tmp_path, capsys):
    """No image of the reference camera with the board: exit 2, every image still listed."""
    cv2.imwrite(str(tmp_path / "grey01.png"), np.full((48, 64), 128, np.uint8))
    out = tmp_path / "rig"
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"a={tmp_path}/grey01.png",
                "--camera", f"b={DATA}/right0[12].jpg", "--rig", "r", "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert "reference camera a" in err and "warning" not in err
    with (out / "detections.csv").open() as stream:
        rows = list(csv.DictReader(stream))
    assert [(row["image_id"], row["used"]) for row in rows] == [
        ("grey01", "no"), ("right01", "yes"), ("right02", "yes")]
    assert not (out / "calibration.toml").exists()


# --- rendered boards ------------------------------------------------------------------------

K_TRUE = {"fx": 560.0, "fy": 556.0, "cx": 322.0, "cy": 236.0}
DIST_TRUE = {"k1": -0.22, "k2": 0.06, "p1": 8e-4, "p2": -5e-4, "k3": 0.0}
SIZE = (640, 480)
BLUR_PX, NOISE_GREY = 0.6, 2.0  # Gaussian blur σ (pixels) and noise σ (grey levels)


def _camera_matrix(scale: float = 1.0) -> np.ndarray:
    """K of the true camera in an image `scale` times as large (pixel centres kept)."""
    s = scale
    return np.array([[s * K_TRUE["fx"], 0, s * K_TRUE["cx"] + (s - 1) / 2],
                     [0, s * K_TRUE["fy"], s * K_TRUE["cy"] + (s - 1) / 2], [0, 0, 1]])


def _poses(n: int, distance: float, rng) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rvec, tvec) of the board (its centre near the optical axis, `distance` away) tilted
    25° in `n` directions and turned up to 20° about the axis."""
    poses = []
    for k in range(n):
        tilt = np.radians([25 * np.cos(2 * np.pi * k / n), 25 * np.sin(2 * np.pi * k / n),
                           rng.uniform(-20, 20)])
        poses.append((tilt, np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 1.0])
                      * distance))
    return poses


def _render(picture: np.ndarray, to_picture, centre: np.ndarray, pose, rng) -> np.ndarray:
    """The board seen by the true camera at `pose` (rvec, tvec of the board moved by -centre
    (2,)), 2x supersampled, blurred, with noise: `picture` is the board's picture and
    `to_picture` maps board points (n, 2) to its pixels (the centre of its top-left pixel at
    0, 0)."""
    scale = 2
    k = _camera_matrix(scale)
    dist = np.array([DIST_TRUE[n] for n in ("k1", "k2", "p1", "p2", "k3")])
    u, v = np.meshgrid(np.arange(SIZE[0] * scale, dtype=np.float64),
                       np.arange(SIZE[1] * scale, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pixels, k, dist, criteria=(
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10))
    rays = np.c_[rays.reshape(-1, 2), np.ones(len(pixels))]
    rotation = cv2.Rodrigues(pose[0])[0]
    h = np.c_[rotation[:, :2], rotation[:, :2] @ -centre + pose[1]]  # board (X, Y, 1) -> ray
    board = rays @ np.linalg.inv(h).T
    maps = to_picture(board[:, :2] / board[:, 2:]).astype(np.float32)
    maps = maps.reshape(SIZE[1] * scale, SIZE[0] * scale, 2)
    image = cv2.remap(picture, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    image = cv2.resize(image, SIZE, interpolation=cv2.INTER_AREA).astype(np.float64)
    image = cv2.GaussianBlur(image, (0, 0), BLUR_PX) + rng.normal(0, NOISE_GREY, image.shape[:2])
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _truth(points: np.ndarray, centre: np.ndarray, pose) -> np.ndarray:
    dist = np.array([DIST_TRUE[n] for n in ("k1", "k2", "p1", "p2", "k3")])
    shifted = points - np.r_[centre, 0.0]
    return cv2.projectPoints(shifted, pose[0], pose[1], _camera_matrix(), dist)[0].reshape(-1, 2)


def _rendered_calibration(tmp_path, board: Board, picture, to_picture, centre, distance):
    """Six views of the board rendered, detected by the CLI and adjusted; returns the RMS
    error of the detected points against their true projections (pixels), the adjusted
    values and their σ."""
    points = board.points()
    rng = np.random.default_rng(7)
    folder = tmp_path / "images"
    folder.mkdir()
    truths = {}
    for n, pose in enumerate(_poses(6, distance, rng)):
        image = _render(picture, to_picture, centre, pose, rng)
        cv2.imwrite(str(folder / f"view{n}.png"), image)
        truths[f"view{n}"] = _truth(points, centre, pose)
    out = tmp_path / "project"
    assert _run("detect", "--board", board.text(), "--camera", f"cam={folder}/view*.png",
                "--out", str(out), "--jobs", "1") == 0
    errors = [np.subtract([float(u), float(v)], truths[image][int(point)])
              for image, point, u, v in _read_rows(out / "image_coordinates.txt")]
    with (out / "detections.csv").open() as stream:
        assert [row["used"] for row in csv.DictReader(stream)] == ["yes"] * 6
    values, stds = _calibration(out / "calibration.toml")[:2]
    return float(np.sqrt(np.mean(np.square(errors)))), values, stds


def _assert_truth(values, stds):
    truth = K_TRUE | DIST_TRUE
    for name in FREE:
        assert abs(values[name] - truth[name]) < TRUTH_SIGMAS * stds[name], (
            name, values[name], truth[name], stds[name])


@pytest.mark.slow
def test_rendered_charuco(tmp_path):
    """A 9 x 7 ChArUco board (5X5_100, marker ids from 3), in some views partly outside the
    image: the corners found within 0.15 px RMS of the truth, the camera within 3σ."""
    board = parse_board("charuco:9x7:20mm:15mm:5X5_100:first=3")
    board_px = 10.0  # picture pixels per mm; the board's corner at the picture's corner
    picture = charuco_board(board).generateImage((1800, 1400), marginSize=0, borderBits=1)
    centre = np.array([board.cols, board.rows]) * board.spacing / 2
    rms, values, stds = _rendered_calibration(
        tmp_path, board, picture, lambda xy: xy * board_px - 0.5, centre,
        distance=K_TRUE["fx"] * 180 / 500)
    with (tmp_path / "project" / "detections.csv").open() as stream:
        counts = [int(row["points"]) for row in csv.DictReader(stream)]
    assert min(counts) < board.n_points == max(counts)  # a partial view among them
    assert rms < RENDER_PX
    _assert_truth(values, stds)


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["circles:7x6:20mm", "acircles:4x9:15mm"])
def test_rendered_circle_grid(tmp_path, spec):
    """Symmetric and asymmetric grids of circles of radius a fifth of the spacing: the centres
    found within 0.15 px RMS of the projected centres (a circle's image is not centred on its
    centre's image, a bias of a few hundredths of a pixel here), the camera within 3σ."""
    board = parse_board(spec)
    points = board.points()
    board_px, margin = 10.0, board.spacing  # picture pixels per mm; margin around the grid
    size = np.ceil((points[:, :2].max(axis=0) + 2 * margin) * board_px).astype(int) + 1
    picture = np.full((size[1], size[0]), 255, np.uint8)
    for x, y, _ in points:  # centres and radius in 1/16 pixel
        cv2.circle(picture, (round((x + margin) * board_px * 16), round((y + margin) * board_px
                   * 16)), round(board.spacing / 5 * board_px * 16), 0, -1, cv2.LINE_AA, 4)
    extent = np.ptp(points[:, :2], axis=0) + 2 * margin
    width = max(extent[0], extent[1] * SIZE[0] / SIZE[1])  # the board's extent to fit across
    rms, values, stds = _rendered_calibration(
        tmp_path, board, picture, lambda xy: (xy + margin) * board_px,
        points[:, :2].mean(axis=0), distance=K_TRUE["fx"] * width / 450)
    assert rms < RENDER_PX
    _assert_truth(values, stds)


# --- the command line -----------------------------------------------------------------------


def test_console_script(tmp_path):
    """`python -m jaxba detect` on three images; its help names the board grammar."""
    out = tmp_path / "project"
    argv = ["detect", "--board", "chessboard:9x6:1", "--camera", f"left={DATA}/left0[1-3].jpg",
            "--out", str(out), "--name", "three"]
    done = subprocess.run([sys.executable, "-m", "jaxba", *argv], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "left: the board in 3 of 3 images" in done.stdout
    assert f"adjust it with: jaxba adjust {out / 'three.toml'}" in done.stdout
    assert len(_read_rows(out / "orientation.txt")) == 3
    done = subprocess.run([sys.executable, "-m", "jaxba", "detect", "--help"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0
    assert "charuco:COLSxROWS:SQUARE:MARKER:DICT" in " ".join(done.stdout.split())


def test_every_commands_parser_leaves_the_detection_code_alone():
    """Registering `detect` imports neither the detection code nor NumPy: every command
    builds the parser when it starts."""
    script = ("import sys; from jaxba._cli._main import _parser; _parser(); print([m for m in"
              " sys.modules if m.startswith(('jaxba._io', 'numpy', 'cv2'))])")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr


@pytest.mark.parametrize("argv, words", [
    (["--board", "chess:9x6:1", "--camera", "a=x.jpg"], "unknown board"),
    (["--board", "chessboard:9x6:1", "--camera", "a"], "NAME=GLOB"),
    (["--board", "chessboard:9x6:1", "--camera", "a b=x.jpg"], "letters"),
    (["--board", "chessboard:9x6:1", "--camera", "a=x.jpg", "--camera", "a=y.jpg"], "twice"),
    (["--board", "chessboard:9x6:1", "--camera", "a=/nowhere/*.jpg"], "matches no file"),
    (["--board", "chessboard:9x6:1", "--camera", "a=x.jpg", "--rig", "r"], "two --camera"),
    (["--board", "chessboard:9x6:1", "--camera", "a=x.jpg", "--jobs", "0"], "at least 1"),
])
def test_bad_input_exits_2_before_reading_images(tmp_path, capsys, argv, words):
    assert _run("detect", *argv, "--out", str(tmp_path / "out")) == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_used_output_folder_is_refused(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine\n")
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"a={DATA}/left01.jpg",
                "--out", str(tmp_path / "out")) == 2
    assert "not empty" in capsys.readouterr().err


def test_no_board_anywhere_still_lists_the_images(tmp_path, capsys):
    """Exit 2, with detections.csv and the contact sheet written and no project."""
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((48, 64), 128, np.uint8))
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"a={tmp_path}/grey.png",
                "--out", str(tmp_path / "out")) == 2
    assert "found in no image" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["detections.csv",
                                                                     "detections.png"]


def test_without_opencv_the_extra_is_named(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 raises ImportError
    assert _run("detect", "--board", "chessboard:9x6:1", "--camera", f"a={DATA}/left01.jpg",
                "--out", str(tmp_path / "out")) == 2
    assert "pip install 'jaxba[images]'" in capsys.readouterr().err
