"""A BAL problem written as a jaxba project (docs/project-files.md): `jaxba import bal`.

BAL's camera row (r, t, f, k1, k2) becomes an image (P = R X + t: M = R(r), X0 = -Rᵀ t, the
angles ω φ κ of M = R3(κ) R2(φ) R1(ω)) and a camera of the `"bal"` model (f, k1, k2 free),
one per image, in a `"pixel"` project: BAL's observations are the model's image frame (origin
at the image centre, y up), σ 1 pixel. BAL has no control: the datum is `"dependent"` (the
first image's EOPs and one station coordinate of the longest base fixed). The solve stops as
`jaxba bal` and Ceres stop BAL problems (`stop = "cost"`: an accepted step lowered the cost by
at most 1e-6 of it, damped steps; guarded by a loose statistical test). Points measured in
fewer than 2 images, and images left without measurements, are left out (a free point needs
two rays). Plain NumPy; no jax.
"""

import dataclasses
import os
import pathlib

import numpy as np

from ..._models._rotation_numpy import matrix_to_opk
from .._project._project_file import project_toml
from ._reader import BalProblem, read_bal


@dataclasses.dataclass(frozen=True)
class BalProject:
    """What `write_bal_project` wrote: the project file and how many images, points and
    image points it holds; `dropped_points`: points left out (fewer than 2 measurements)."""

    project_file: pathlib.Path
    n_images: int
    n_points: int
    n_image_points: int
    dropped_points: int


def rodrigues_matrix(r: np.ndarray) -> np.ndarray:
    """R(r) = I + sinθ K + (1 - cosθ) K², K the cross-product matrix of r/θ, θ = |r|."""
    theta = float(np.linalg.norm(r))
    if theta < 1e-12:
        return np.eye(3)
    k = np.asarray(r, dtype=float) / theta
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * skew + (1 - np.cos(theta)) * skew @ skew


def _table(path: pathlib.Path, header: str, rows) -> None:
    path.write_text(f"# {header}\n" + "".join(" ".join(row) + "\n" for row in rows))


def write_bal_project(
    problem: str | os.PathLike | BalProblem, out_dir: str | os.PathLike, *, name: str = "bal",
) -> BalProject:
    """Write the BAL problem `problem` (a file, plain, .bz2 or .gz, or a `BalProblem`) as a
    jaxba project into `out_dir` (created if missing): `NAME.toml`, cameras.toml,
    orientation.txt, image_coordinates.txt, points.txt. Images are `img<k>` with camera
    `C<k>` (k the BAL camera index), points keep BAL's index. See the module docstring."""
    bal = problem if isinstance(problem, BalProblem) else read_bal(problem)
    out_dir = pathlib.Path(out_dir)
    rays = np.bincount(bal.point_index, minlength=bal.n_points)
    keep = rays[bal.point_index] >= 2
    cameras = np.unique(bal.camera_index[keep])
    points = np.unique(bal.point_index[keep])
    width = len(str(bal.n_cameras - 1))
    image_id = [f"img{k:0{width}d}" for k in range(bal.n_cameras)]
    out_dir.mkdir(parents=True, exist_ok=True)

    camera_lines = ["# BAL cameras: f (pixels), k1, k2; the sensor is not used by the bal model",
                    "# (BAL gives none): it spans the observations."]
    image_rows = []
    for k in cameras:
        r, t, intrinsics = bal.cameras[k, :3], bal.cameras[k, 3:6], bal.cameras[k, 6:]
        rotation = rodrigues_matrix(r)
        station = -rotation.T @ t
        angles = np.degrees(matrix_to_opk(rotation))
        image_rows.append([image_id[k], f"C{k}", *(repr(float(v)) for v in (*station, *angles))])
        extent = np.abs(bal.observed[bal.camera_index == k]).max(axis=0)
        sensor = [2 * int(np.ceil(e)) + 2 for e in extent]
        camera_lines += [
            f"[C{k}]", 'model = "bal"',
            f"sensor = [{sensor[0]}, {sensor[1]}]",
            *(f"{p} = {float(v)!r}" for p, v in zip(("f", "k1", "k2"), intrinsics)),
            'free = ["f", "k1", "k2"]', "",
        ]
    (out_dir / "cameras.toml").write_text("\n".join(camera_lines))
    source = bal.path.name if bal.path is not None else "a BAL problem"
    _table(out_dir / "orientation.txt",
           f"image_id camera_id X0 Y0 Z0 omega phi kappa (deg), from {source}: X0 = -R^T t",
           image_rows)
    _table(out_dir / "points.txt", "point_id X Y Z (free tie points)",
           ([str(p), *(repr(float(v)) for v in bal.points[p])] for p in points))
    _table(out_dir / "image_coordinates.txt",
           "image_id point_id x y (pixels, BAL's frame: origin at the image centre, y up)",
           ([image_id[c], str(p), repr(float(x)), repr(float(y))]
            for c, p, (x, y) in zip(bal.camera_index[keep], bal.point_index[keep],
                                   bal.observed[keep])))
    project_file = out_dir / f"{name}.toml"
    project_file.write_text(project_toml(
        name, "pixel", {"cameras": "cameras.toml", "images": "orientation.txt",
                        "image_points": "image_coordinates.txt", "points": "points.txt"},
        {"image_sigma": 1.0, "datum": "dependent", "stop": "cost"},
        comment=[f"BAL problem {source} (jaxba import bal): one bal camera per image, no control."],
        notes={"image_sigma": "pixel", "stop": "as Ceres and jaxba bal stop BAL problems"}),
        encoding="utf-8")
    return BalProject(project_file, len(cameras), len(points), int(keep.sum()),
                      int(np.count_nonzero((rays > 0) & (rays < 2))))
