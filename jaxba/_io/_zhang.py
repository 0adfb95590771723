"""Zhang's planar calibration data as a jaxba project with one "opencv" camera.

Zhang, "A flexible new technique for camera calibration", MSR-TR-98-71 / IEEE PAMI 22(11),
2000. `Model.txt`: 64 lines of 8 numbers, the 4 corners (X, Y) of each square of the target,
Z = 0, inch. `dataN.txt`: the pixel (u, v) of the same 256 corners in image N (640 x 480).

Starting EOPs come from Zhang's closed form (paper section 3.1, appendices A and B): one
homography per image by normalised DLT, intrinsics from B = K⁻ᵀ K⁻¹, one pose per image.
It ignores lens distortion, so the poses are a few degrees and pixels off the adjusted ones.
Plain NumPy; nothing here calls jax.
"""

import dataclasses
import json
import os
import pathlib
from collections.abc import Mapping

import numpy as np

from .._models._rotation_numpy import matrix_to_opk
from ._project._project_file import project_toml

N_IMAGES = 5
SENSOR = (640, 480)
FREE = ("fx", "fy", "cx", "cy", "skew", "k1", "k2")
PARAMETER_NAMES = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3")
# Rounded starting intrinsics: the adjustment, not the initialisation, finds the camera.
ROUNDED_START = {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0}
# The OpenCV camera frame (x right, y down, z forward) in the photogrammetric one: M = F R.
_CV_TO_PHOTOGRAMMETRIC = np.diag([1.0, -1.0, -1.0])


@dataclasses.dataclass(frozen=True)
class ZhangProject:
    """What `write_zhang_project` wrote.

    `closed_form`: fx, fy, cx, cy, skew (pixels) of Zhang's closed form; `images`:
    image_id -> starting (X0, Y0, Z0) inch and (omega, phi, kappa) degrees as written.
    """

    project_file: pathlib.Path
    closed_form: dict[str, float]
    images: dict[str, tuple[float, ...]]


def read_corners(path: str | os.PathLike) -> np.ndarray:
    """The (256, 2) corner coordinates of one of Zhang's files, in file order."""
    values = np.loadtxt(path, dtype=float)
    if values.shape != (64, 8):
        raise ValueError(f"{path}: expected 64 lines of 8 numbers, got shape {values.shape}")
    return values.reshape(256, 2)


def _normalising_transform(points: np.ndarray) -> np.ndarray:
    """3x3 similarity moving `points` (n, 2) to centroid 0, mean distance √2 (Hartley)."""
    centroid = points.mean(axis=0)
    scale = np.sqrt(2) / np.mean(np.linalg.norm(points - centroid, axis=1))
    return np.array([[scale, 0, -scale * centroid[0]], [0, scale, -scale * centroid[1]], [0, 0, 1]])


def homography(plane: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """H (3x3, H[2, 2] = 1) with [u, v, 1]ᵀ ~ H [X, Y, 1]ᵀ, by normalised DLT (n ≥ 4 points)."""
    t_plane, t_pixels = _normalising_transform(plane), _normalising_transform(pixels)
    src = np.c_[plane, np.ones(len(plane))] @ t_plane.T
    dst = np.c_[pixels, np.ones(len(pixels))] @ t_pixels.T
    zeros = np.zeros_like(src)
    rows_u = np.c_[src, zeros, -dst[:, :1] * src]
    rows_v = np.c_[zeros, src, -dst[:, 1:2] * src]
    _, _, vt = np.linalg.svd(np.r_[rows_u, rows_v])
    h = np.linalg.inv(t_pixels) @ vt[-1].reshape(3, 3) @ t_plane
    return h / h[2, 2]


def _v(h: np.ndarray, i: int, j: int) -> np.ndarray:
    """Zhang's v_ij: h_iᵀ B h_j = v_ijᵀ b, b = (B11, B12, B22, B13, B23, B33)."""
    a, b = h[:, i], h[:, j]
    return np.array([
        a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1],
        a[2] * b[0] + a[0] * b[2], a[2] * b[1] + a[1] * b[2], a[2] * b[2],
    ])


def intrinsics(homographies: list[np.ndarray]) -> np.ndarray:
    """K = [[α, γ, u0], [0, β, v0], [0, 0, 1]] from ≥ 3 homographies (Zhang, appendix B)."""
    v = np.array([row for h in homographies for row in (_v(h, 0, 1), _v(h, 0, 0) - _v(h, 1, 1))])
    b11, b12, b22, b13, b23, b33 = np.linalg.svd(v)[2][-1]
    if b11 < 0:  # b is found up to sign; B = λ K⁻ᵀ K⁻¹ with λ > 0 is positive definite
        b11, b12, b22, b13, b23, b33 = -b11, -b12, -b22, -b13, -b23, -b33
    v0 = (b12 * b13 - b11 * b23) / (b11 * b22 - b12**2)
    lam = b33 - (b13**2 + v0 * (b12 * b13 - b11 * b23)) / b11
    alpha = np.sqrt(lam / b11)
    beta = np.sqrt(lam * b11 / (b11 * b22 - b12**2))
    gamma = -b12 * alpha**2 * beta / lam
    u0 = gamma * v0 / beta - b13 * alpha**2 / lam
    return np.array([[alpha, gamma, u0], [0.0, beta, v0], [0.0, 0.0, 1.0]])


def pose(k: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with x_cv = R [X, Y, 0]ᵀ + t in front of the camera (Zhang, section 3.1).

    r1 = λ K⁻¹ h1, r2 = λ K⁻¹ h2, r3 = r1 × r2, t = λ K⁻¹ h3, λ = ±1/‖K⁻¹ h1‖ with the sign
    giving t_z > 0; R is then replaced by the nearest rotation (SVD).
    """
    a = np.linalg.solve(k, h)
    lam = 1.0 / np.linalg.norm(a[:, 0])
    if a[2, 2] < 0:
        lam = -lam
    r1, r2, t = lam * a[:, 0], lam * a[:, 1], lam * a[:, 2]
    u, _, vt = np.linalg.svd(np.c_[r1, r2, np.cross(r1, r2)])
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rotation, t


def eop_from_pose(rotation: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Photogrammetric EOPs of an OpenCV pose: M = diag(1, -1, -1) R, X0 = -Rᵀ t.

    Returns X0 (3,) in target units and (omega, phi, kappa) in radians (docs/conventions.md).
    """
    return -rotation.T @ t, matrix_to_opk(_CV_TO_PHOTOGRAMMETRIC @ rotation)


def table_text(header: str, rows: list[list[str]]) -> str:
    """A text table: `# header`, then one line of whitespace-separated tokens per row."""
    return "\n".join([f"# {header}", *(" ".join(row) for row in rows)]) + "\n"


def _write_table(path: pathlib.Path, header: str, rows: list[list[str]]) -> None:
    path.write_text(table_text(header, rows))


def write_zhang_project(
    data_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    name: str = "zhang",
    initial: Mapping[str, float] = ROUNDED_START,
) -> ZhangProject:
    """Write Zhang's data set as a project (docs/project-files.md) into `out_dir`.

    **Arguments:**

    - `data_dir`: folder with Model.txt and data1.txt .. data5.txt.
    - `out_dir`: where `NAME.toml`, cameras.toml, orientation.txt, image_coordinates.txt and
      target_points.txt go (created if missing).
    - `name`: the project name.
    - `initial`: starting values of the opencv camera's parameters (missing ones 0); by
      default rounded ones (fx = fy = 800, cx = 320, cy = 240), so the adjustment does the work.

    The camera has fx fy cx cy skew k1 k2 free and p1 p2 k3 fixed at 0, image_units =
    "pixel", image σ 1 px (σ̂0 is then the residual RMS per coordinate, about), all 256
    target points fixed (inch), and starting EOPs from Zhang's closed form.
    """
    data_dir, out_dir = pathlib.Path(data_dir), pathlib.Path(out_dir)
    unknown = set(initial) - set(PARAMETER_NAMES)
    if unknown:
        raise ValueError(f"initial: unknown opencv parameters {sorted(unknown)}")
    plane = read_corners(data_dir / "Model.txt")
    pixels = [read_corners(data_dir / f"data{n}.txt") for n in range(1, N_IMAGES + 1)]
    homographies = [homography(plane, uv) for uv in pixels]
    k = intrinsics(homographies)
    out_dir.mkdir(parents=True, exist_ok=True)

    point_ids = [str(n) for n in range(1, len(plane) + 1)]
    rows = [[pid, repr(float(x)), repr(float(y)), "0", "0", "0", "0"]
            for pid, (x, y) in zip(point_ids, plane)]
    _write_table(out_dir / "target_points.txt",
                 "point_id X Y Z (inch; Model.txt order) sX sY sZ (0 = fixed)", rows)

    images, rows = {}, []
    for n, h in enumerate(homographies, start=1):
        x0, opk = eop_from_pose(*pose(k, h))
        eop = (*np.round(x0, 6), *np.round(np.degrees(opk), 6))
        images[f"data{n}"] = tuple(float(value) for value in eop)
        rows.append([f"data{n}", "C1", *(f"{value:.6f}" for value in eop)])
    _write_table(out_dir / "orientation.txt",
                 "image_id camera_id X0 Y0 Z0 (inch) omega phi kappa (deg); Zhang's closed form",
                 rows)

    rows = [[f"data{n}", pid, repr(float(u)), repr(float(v))]
            for n, uv in enumerate(pixels, start=1) for pid, (u, v) in zip(point_ids, uv)]
    _write_table(out_dir / "image_coordinates.txt",
                 "image_id point_id u v (pixel: col, row; dataN.txt as published)", rows)

    lines = [
        "[C1]",
        'model = "opencv"  # pixels, distortion applied forward (computer-vision convention)',
        f"sensor = [{SENSOR[0]}, {SENSOR[1]}]",
        *(f"{p} = {float(initial.get(p, 0.0))!r}" for p in PARAMETER_NAMES),
        f"free = {json.dumps(list(FREE))}",
    ]
    (out_dir / "cameras.toml").write_text("\n".join(lines) + "\n")

    project_file = out_dir / f"{name}.toml"
    project_file.write_text(project_toml(
        name, "pixel", {"cameras": "cameras.toml", "images": "orientation.txt",
                        "image_points": "image_coordinates.txt", "points": "target_points.txt"},
        {"sigma0": 1.0, "image_sigma": 1.0, "max_iterations": 100},
        comment=["Zhang's planar calibration data (MSR-TR-98-71): 5 images of 256 target"
                 " corners.",
                 "Published: fx 832.5, fy 832.53, skew 0.204494, cx 303.959, cy 206.585,",
                 "k1 -0.228601, k2 0.190353."],
        notes={"image_sigma": "pixel"}), encoding="utf-8")
    closed_form = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "skew": k[0, 1]}
    return ZhangProject(project_file, {p: float(v) for p, v in closed_form.items()}, images)
