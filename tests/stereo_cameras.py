"""OpenCV's stereo sample (`tests/data/opencv_stereo`: 13 pairs of 640 x 480 images of a
9 x 6 chessboard) as jaxba projects of one camera each: corners by cv2.findChessboardCorners and
cornerSubPix (as its SOURCES.md), the board on a unit grid (fixed), approximations of the
poses from cv2.calibrateCamera of the same images."""

import json
import pathlib

import numpy as np
from board_scene import write_pixel_project

from jaxba._io._synthetic import opk_from_rotation

DATA = pathlib.Path(__file__).resolve().parent / "data" / "opencv_stereo"
PATTERN = (9, 6)
SENSOR = (640, 480)
FREE = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]  # OpenCV's default set
NUMBERS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14)


def corners(cv2, side: str) -> dict[int, np.ndarray]:
    """{image number: (54, 2) refined corners} of the `side` ("left", "right") images."""
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    found = {}
    for n in NUMBERS:
        image = cv2.imread(str(DATA / f"{side}{n:02d}.jpg"), cv2.IMREAD_GRAYSCALE)
        ok, points = cv2.findChessboardCorners(image, PATTERN)
        if ok:
            refined = cv2.cornerSubPix(image, points, (11, 11), (-1, -1), criteria)
            found[n] = refined.reshape(-1, 2).astype(float)
    return found


def board() -> np.ndarray:
    """(54, 3) corners on a unit grid, in findChessboardCorners' order."""
    return np.array([[x, y, 0.0] for y in range(PATTERN[1]) for x in range(PATTERN[0])])


def write_project(cv2, out: pathlib.Path, found: dict[int, np.ndarray], numbers,
                  name: str) -> pathlib.Path:
    """A project of the images `numbers` of `found` in `out`; returns the project file."""
    numbers = [n for n in numbers if n in found]
    objects = [board().astype(np.float32)] * len(numbers)
    images = [found[n].astype(np.float32) for n in numbers]
    _, k, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, SENSOR, None, None)
    out.mkdir(parents=True, exist_ok=True)
    values = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "skew": 0.0,
              "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}
    lines = ["[C1]", 'model = "opencv"', f"sensor = [{SENSOR[0]}, {SENSOR[1]}]"]
    lines += [f"{key} = {float(v)!r}" for key, v in values.items()]
    lines.append(f"free = {json.dumps(FREE)}")
    (out / "cameras.toml").write_text("\n".join(lines) + "\n")
    (out / "points.txt").write_text("\n".join(
        f"{j + 1} {x!r} {y!r} {z!r} 0 0 0" for j, (x, y, z) in enumerate(board().tolist()))
        + "\n")
    flip = np.diag([1.0, -1.0, -1.0])  # OpenCV's camera frame -> jaxba's (y up, -z ahead)
    rows, observed = [], []
    for n, rvec, tvec in zip(numbers, rvecs, tvecs):
        rotation = cv2.Rodrigues(rvec)[0]
        station = -rotation.T @ tvec.ravel()
        opk = np.degrees(opk_from_rotation(flip @ rotation))
        rows.append(f"i{n} C1 " + " ".join(repr(float(v)) for v in (*station, *opk)))
        observed += [f"i{n} {j + 1} {u!r} {v!r}" for j, (u, v) in enumerate(found[n].tolist())]
    return write_pixel_project(out, name, rows, observed, 0.3)
