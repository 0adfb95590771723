"""OpenCV's stereo sample (../data/opencv_stereo, 13 chessboard pairs) as OpenCV sees it and as a
jaxba project: corners by `cv2.findChessboardCorners` + `cv2.cornerSubPix`, each camera by
`cv2.calibrateCamera`, the pair by `cv2.stereoCalibrate`, and the project files that say the
same (model `opencv`, pixels, the board fixed on a unit grid, approximations from OpenCV's
single-camera calibrations)."""

import dataclasses
import pathlib

import numpy as np

BOARD = (9, 6)  # inner corners
PAIRS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14)
FLIP = np.diag([1.0, -1.0, -1.0])  # OpenCV's camera frame <-> jaxba's (docs/conventions.md)
STRICT = (3, 500, 1e-15)  # (COUNT + EPS, iterations, ε): OpenCV iterates to convergence


def data_folder() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parent / "data" / "opencv_stereo"


@dataclasses.dataclass(frozen=True)
class Stereo:
    """OpenCV's view: board points (n, 3), corners per camera (13, n, 2), the single-camera
    calibrations (K, dist, rvecs, tvecs) and `stereoCalibrate`'s (K1, D1, K2, D2, R, T)."""

    board: np.ndarray
    corners: dict
    single: dict
    stereo: tuple


def opencv_stereo() -> Stereo:
    import cv2

    board = np.zeros((BOARD[0] * BOARD[1], 3), np.float32)
    board[:, :2] = np.mgrid[0:BOARD[0], 0:BOARD[1]].T.reshape(-1, 2)
    corners, single = {}, {}
    for side in ("left", "right"):
        found = []
        for k in PAIRS:
            image = cv2.imread(str(data_folder() / f"{side}{k:02d}.jpg"), cv2.IMREAD_GRAYSCALE)
            ok, xy = cv2.findChessboardCorners(image, BOARD)
            assert ok, f"{side}{k:02d}"
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
            found.append(cv2.cornerSubPix(image, xy, (11, 11), (-1, -1), criteria))
        corners[side] = np.array(found, dtype=np.float64).reshape(len(PAIRS), -1, 2)
        single[side] = cv2.calibrateCamera([board] * len(PAIRS), found, (640, 480), None, None,
                                           criteria=STRICT)[1:]
    (k1, d1), (k2, d2) = (single[s][:2] for s in ("left", "right"))
    stereo = cv2.stereoCalibrate(
        [board] * len(PAIRS), [c.astype(np.float32) for c in corners["left"]],
        [c.astype(np.float32) for c in corners["right"]], k1.copy(), d1.copy(), k2.copy(),
        d2.copy(), (640, 480), flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=STRICT)
    return Stereo(board.astype(float), corners, single, stereo[1:7])


def image_row(rvec, tvec) -> list[float]:
    """A jaxba images row (X0, Y0, Z0, omega, phi, kappa degrees) from OpenCV's pose."""
    import cv2

    from jaxba._models._rotation_numpy import matrix_to_opk

    rotation = cv2.Rodrigues(np.asarray(rvec, float))[0]
    station = -rotation.T @ np.ravel(tvec)
    return [*station, *np.degrees(matrix_to_opk(FLIP @ rotation))]


def write_project(folder: pathlib.Path, scene: Stereo, *, rig: bool = True,
                  intrinsics: dict | None = None) -> pathlib.Path:
    """The jaxba project of `scene` in `folder`: both cameras `opencv` with OpenCV's free set
    (fx fy cx cy k1 k2 p1 p2 k3) from their single-camera calibrations, every image's pose
    from them, the board fixed; with `rig` the pairs are frames of rig "stereo" (reference
    left, the right camera's pose in the rig free and computed from the images').
    `intrinsics`: {camera: the nine values}, fixed, instead."""
    folder.mkdir(parents=True, exist_ok=True)
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    cameras, images, frames, points = [], [], [], []
    for side in ("left", "right"):
        matrix, dist, rvecs, tvecs = scene.single[side]
        dist = np.ravel(dist)
        values = [matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], *dist[[0, 1, 2, 3, 4]]]
        free = list(names) if intrinsics is None else []
        values = values if intrinsics is None else intrinsics[side]
        cameras += [f"[{side}]", 'model = "opencv"', "sensor = [640, 480]",
                    *(f"{n} = {v!r}" for n, v in zip(names, map(float, values))),
                    f"free = {free!r}".replace("'", '"'), ""]
        for k, pair in enumerate(PAIRS):
            row = image_row(rvecs[k], tvecs[k])
            images.append(f"{side}{pair:02d} {side} " + " ".join(repr(float(v)) for v in row))
            frames.append(f"{side}{pair:02d} pair{pair:02d}")
            points += [f"{side}{pair:02d} {p} {x!r} {y!r}"
                       for p, (x, y) in enumerate(scene.corners[side][k].tolist())]
    (folder / "cameras.toml").write_text("\n".join(cameras))
    (folder / "images.txt").write_text("\n".join(images) + "\n")
    (folder / "image_points.txt").write_text("\n".join(points) + "\n")
    (folder / "points.txt").write_text("".join(
        f"{k} {x!r} {y!r} {z!r} 0 0 0\n" for k, (x, y, z) in enumerate(scene.board.tolist())))
    files = ['cameras = "cameras.toml"', 'images = "images.txt"',
             'image_points = "image_points.txt"', 'points = "points.txt"']
    if rig:
        (folder / "frames.txt").write_text("\n".join(frames) + "\n")
        (folder / "rigs.toml").write_text('[stereo]\nreference = "left"\n[stereo.right]\n')
        files += ['rigs = "rigs.toml"', 'frames = "frames.txt"']
    project = folder / "stereo.toml"
    project.write_text('[project]\nname = "stereo"\nimage_units = "pixel"\n\n[files]\n'
                       + "\n".join(files) + "\n\n[adjustment]\nimage_sigma = 0.5\n")
    return project
