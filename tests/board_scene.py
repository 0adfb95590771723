"""A synthetic chessboard calibration of one OpenCV camera, written as a jaxba project.

The board (COLS x ROWS inner corners, SPACING mm, Z = 0, all fixed) is seen from N_IMAGES
stations in front of it (+Z side), each looking at a point near the board's centre with a
roll; the corners are projected with the OpenCV model (jaxba's `OpenCVCamera`, checked
against OpenCV in test_cv_models) plus Gaussian noise of NOISE_PX. The approximations of the
poses are the truth, rounded; the camera starts from rounded values.
"""

import json
import pathlib

import numpy as np

import jaxba
from jaxba._io._synthetic import look_at, opk_from_rotation

SENSOR = (640, 480)
TRUTH = {"fx": 540.0, "fy": 538.0, "cx": 330.0, "cy": 242.0, "skew": 0.0,
         "k1": -0.25, "k2": 0.08, "p1": 0.001, "p2": -0.0005, "k3": 0.0}
FREE = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"]
COLS, ROWS, SPACING = 9, 6, 25.0
N_IMAGES = 10
NOISE_PX = 0.3


def board(spacing: float = SPACING, warp=(0.0, 0.0)) -> np.ndarray:
    """(COLS * ROWS, 3) corner coordinates, mm, row by row; `warp` (kx, ky, mm) bends the
    board as mrcal does: Z = kx (1 - x²) + ky (1 - y²), x, y from -1 to 1 over the corners."""
    cols, rows = np.meshgrid(np.arange(COLS), np.arange(ROWS))
    x, y = 2 * cols.ravel() / (COLS - 1) - 1, 2 * rows.ravel() / (ROWS - 1) - 1
    return np.column_stack([cols.ravel() * spacing, rows.ravel() * spacing,
                            warp[0] * (1 - x ** 2) + warp[1] * (1 - y ** 2)])


def stations(rng, spacing: float = SPACING) -> list[tuple[np.ndarray, np.ndarray]]:
    """(M, X0) of every image: 300-450 mm from the board (scaled with `spacing`), tilted up
    to ~35 degrees."""
    centre = board(spacing).mean(axis=0)
    scale = spacing / SPACING
    poses = []
    for _ in range(N_IMAGES):
        direction = np.array([*rng.uniform(-0.7, 0.7, 2), 1.0])
        station = centre + scale * rng.uniform(300, 450) * direction / np.linalg.norm(direction)
        target = centre + np.array([*scale * rng.uniform(-40, 40, 2), 0.0])
        poses.append((look_at(station, target, rng.uniform(-0.4, 0.4)), station))
    return poses


def project(camera: dict, poses, points) -> list[np.ndarray]:
    """Pixels (n, 2) of `points` in every image (no noise)."""
    model = jaxba.OpenCVCamera(**{k: float(v) for k, v in camera.items()})
    out = []
    for m, x0 in poses:
        p = (points - x0) @ m.T
        out.append(np.stack([np.asarray(model.image_point(q, np.zeros(2), 0.0)) for q in p]))
    return out


def write_project(out: pathlib.Path, seed: int, *, camera: dict = TRUTH,
                  noise_px: float = NOISE_PX, name: str = "board",
                  keep=lambda k: True, spacing: float = SPACING, warp=(0.0, 0.0),
                  board_warp: bool = False) -> pathlib.Path:
    """The project of a fresh calibration (new stations and noise from `seed`) of `camera`
    in `out`; `keep(k)` chooses the images. The corners are projected from the board bent
    by `warp` (`board`), the points table has the flat board; `board_warp` estimates its
    warp. Returns the project file."""
    rng = np.random.default_rng(seed)
    points, poses = board(spacing), stations(rng, spacing)
    pixels = project(camera, poses, board(spacing, warp))
    out.mkdir(parents=True, exist_ok=True)
    lines = ["[C1]", 'model = "opencv"', f"sensor = [{SENSOR[0]}, {SENSOR[1]}]"]
    start = {**camera, "fx": 520.0, "fy": 520.0, "cx": 320.0, "cy": 240.0,
             "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
    lines += [f"{k} = {v!r}" for k, v in start.items()] + [f"free = {json.dumps(FREE)}"]
    (out / "cameras.toml").write_text("\n".join(lines) + "\n")
    rows = [f"{k + 1} " + " ".join(repr(float(v)) for v in xyz) + " 0 0 0"
            for k, xyz in enumerate(points)]
    (out / "points.txt").write_text("\n".join(rows) + "\n")
    images, observed = [], []
    for k, ((m, x0), uv) in enumerate(zip(poses, pixels)):
        if not keep(k):
            continue
        opk = np.degrees(opk_from_rotation(m))
        images.append(f"i{k} C1 " + " ".join(f"{v:.1f}" for v in x0)
                      + " " + " ".join(f"{v:.2f}" for v in opk))
        noisy = uv + rng.normal(scale=noise_px, size=uv.shape)
        observed += [f"i{k} {j + 1} {float(u)!r} {float(v)!r}" for j, (u, v) in enumerate(noisy)]
    return write_pixel_project(out, name, images, observed, noise_px, board_warp)


def write_pixel_project(out: pathlib.Path, name: str, images: list[str], observed: list[str],
                        image_sigma: float, board_warp: bool = False) -> pathlib.Path:
    """orientation.txt (`images` rows), image_points.txt (`observed` rows) and NAME.toml of
    a project in pixels in `out`, beside the caller's cameras.toml and points.txt. Returns
    the project file."""
    (out / "orientation.txt").write_text("\n".join(images) + "\n")
    (out / "image_points.txt").write_text("\n".join(observed) + "\n")
    project_file = out / f"{name}.toml"
    project_file.write_text("\n".join([
        "[project]", f"name = {json.dumps(name)}", 'image_units = "pixel"', "",
        "[files]", 'cameras = "cameras.toml"', 'images = "orientation.txt"',
        'image_points = "image_points.txt"', 'points = "points.txt"', "",
        "[adjustment]", f"image_sigma = {image_sigma!r}", "max_iterations = 50",
        *(["board_warp = true"] if board_warp else []),
    ]) + "\n")
    return project_file


def adjusted(project_file: pathlib.Path):
    """(project, result) of the project file."""
    project = jaxba.build_project(jaxba.read_project(project_file))
    return project, jaxba.adjust_project(project)


__all__ = ["SENSOR", "TRUTH", "adjusted", "board", "project", "write_pixel_project",
           "write_project"]
