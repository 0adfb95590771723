"""Synthetic photogrammetric blocks of realistic shape, written as jaxba projects (FORMATS.md).

    python benchmarks/blocks.py close-range DIR [--free] [--seed N]
    python benchmarks/blocks.py free-network DIR [--seed N]
    python benchmarks/blocks.py unkind DIR [--free] [--seed N] [--images N] [--points N]

Two shapes, both with one SMAC camera (mm, BASC lab format 6000 x 4000 px of 3.69 µm) in front
of the target wall of `jaxba._io._synthetic` (4 x 3 m with boxes), measurement noise 0.25 px:

- close-range: 60 convergent, rolled images; 26,200 tie points, each measured in 2 + Poisson(1.45)
  of the images that see it (3.45 on average, like matched features), ~181,000 image coordinates,
  ~79,000 unknowns; c, xp, yp, K1, K2 free; no control. Datum by dependent relative orientation:
  the first image's six EOPs fixed and X0 of the image farthest from it fixed (true values), or
  `free=True`: `datum = "free"` (inner constraints over all points), nothing fixed.
- free-network: 115 images, 150 targets, each image measuring a random 58 % of the targets it
  sees (~20,000 image coordinates); xp, yp, c, K1..K3, P1, P2 free; `datum = "free"` and one
  scale bar (the longest target pair, σ 0.1 mm).

- unkind: `jaxba.write_close_range_project` (far 2-ray points under 2°, sparse images, 25 px of
  distortion; default 60 images, 26,000 wall points), datum "dependent" or, with --free, "free".
  At that size (seed 0) both datums stop at σ̂0² ≈ 1.14, a local minimum: more far points
  with approximations metres off than the solve recovers from; 30 images, 3,000 points: 1.003.

Approximations (close-range, free-network): stations ± 2 cm, angles ± 0.3°, points ± 1 cm
(normal σ), c rounded to 0.1 mm, the other IOPs 0; fixed EOPs keep their true values.
Deterministic for a given seed.
"""

import argparse
import dataclasses
import json
import pathlib

import numpy as np

from jaxba._io._close_range import write_close_range_project
from jaxba._io._synthetic import (
    DEFAULT_CAMERA,
    PIXEL_SIZE,
    SENSOR,
    distance_pairs,
    make_stations,
    make_targets,
    observe,
    opk_from_rotation,
    project_ideal,
    toml_float,
    write_table,
)

NOISE_PX = 0.25
APPROX_SIGMA = (0.02, 0.3, 0.01)  # station m, angle deg, point m
SCALE_BAR_SIGMA = 0.0001  # m
LAB_FREE = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2")


@dataclasses.dataclass(frozen=True)
class Shape:
    """A block shape: sizes, camera truth (IOP dict, mm) and free IOPs.

    `mean_views`: mean number of images measuring a point (None: every image measures a
    `keep` fraction of the points it sees).
    """

    name: str
    n_images: int
    n_points: int
    camera: dict
    free: tuple[str, ...]
    mean_views: float | None = None
    keep: float = 1.0


CLOSE_RANGE = Shape(
    name="close_range",
    n_images=60,
    n_points=26_200,
    camera=DEFAULT_CAMERA | {"K3": 0.0, "P1": 0.0, "P2": 0.0},
    free=("xp", "yp", "c", "K1", "K2"),
    mean_views=3.45,
)
FREE_NETWORK = Shape(
    name="free_network",
    n_images=115,
    n_points=150,
    camera=DEFAULT_CAMERA,
    free=LAB_FREE,
    keep=0.58,
)
SHAPES = {"close-range": CLOSE_RANGE, "free-network": FREE_NETWORK}


def visible(points, stations, matrices, iop) -> list[dict[int, np.ndarray]]:
    """Noise-free measurements per image: for each image, point index -> (x, y) mm.

    `points` (n, 3) m, `stations` (m, 3) m, `matrices` (m, 3, 3); only points in front of the
    camera and inside the sensor (`jaxba._io._synthetic.observe`, given only the points whose ideal
    image lies within 1.2 x the format: far outside it the distortion has no inverse).
    """
    half = np.array(SENSOR) / 2 * np.array(PIXEL_SIZE)
    seen = []
    for station, m in zip(stations, matrices):
        ideal, _ = project_ideal(points, station, m, iop["c"])
        near = np.flatnonzero(np.all(np.abs(ideal) < 1.2 * half, axis=1))
        index, xy = observe(points[near], station, m, iop)
        seen.append(dict(zip(near[index].tolist(), xy)))
    return seen


def choose_views(rng, seen, shape: Shape) -> list[tuple[int, int]]:
    """(image, point) pairs to measure, sorted by image: points seen by < 2 images are dropped.

    With `shape.mean_views`, each point is measured in min(2 + Poisson(mean - 2), n_seen) random
    images of those that see it; otherwise each image keeps each point with probability
    `shape.keep`, then points left in < 2 images get a second random image.
    """
    images_of: dict[int, list[int]] = {}
    for image, points in enumerate(seen):
        for point in points:
            images_of.setdefault(point, []).append(image)
    pairs = []
    for point, images in sorted(images_of.items()):
        if len(images) < 2:
            continue
        if shape.mean_views is not None:
            k = min(2 + rng.poisson(shape.mean_views - 2), len(images))
            chosen = rng.choice(images, size=k, replace=False)
        else:
            chosen = [i for i in images if rng.uniform() < shape.keep]
            while len(chosen) < 2:
                chosen = sorted({*chosen, int(rng.choice(images))})
        pairs += [(int(i), point) for i in chosen]
    return sorted(pairs)


def datum_fixed(stations, free: bool) -> np.ndarray:
    """(m, 6) bool: EOPs fixed by dependent relative orientation, none for a free network.

    Image 0's six EOPs and X0 of the image farthest from it (stations (m, 3) m).
    """
    fixed = np.zeros((len(stations), 6), dtype=bool)
    if not free:
        farthest = int(np.argmax(np.linalg.norm(stations - stations[0], axis=1)))
        fixed[0], fixed[farthest, 0] = True, True
    return fixed


def write_cameras(path: pathlib.Path, camera: dict, free: tuple[str, ...]) -> None:
    """cameras.toml with one SMAC camera C1: c rounded to 0.1 mm, other IOPs 0, `free` free."""
    lines = [
        "[C1]",
        'model = "smac"',
        f"pixel_size = [{', '.join(map(toml_float, PIXEL_SIZE))}]",
        "sensor = [6000, 4000]",
        *(f"{name} = {toml_float(round(camera['c'], 1) if name == 'c' else 0.0)}"
          for name in camera),
        f"free = {json.dumps(list(free))}",
    ]
    path.write_text("\n".join(lines) + "\n")


def write_project(path: pathlib.Path, name: str, files: dict, datum: str, seed: int) -> None:
    """The project TOML: mm image units, image σ 0.25 px, the given datum."""
    lines = [
        f"# Synthetic {name} block (benchmarks/blocks.py, seed {seed}).",
        "[project]",
        f"name = {json.dumps(name)}",
        'image_units = "mm"',
        "",
        "[files]",
        *(f"{key} = {json.dumps(value)}" for key, value in files.items()),
        "",
        "[adjustment]",
        "sigma0 = 1.0",
        f"image_sigma = {toml_float(NOISE_PX * PIXEL_SIZE[0])}  # mm",
        "max_iterations = 50",
        f"datum = {json.dumps(datum)}",
    ]
    path.write_text("\n".join(lines) + "\n")


def write_block(directory, shape: Shape | str, *, seed: int = 0, free: bool = False) -> dict:
    """Write one block into `directory` (created); returns its sizes and the project path.

    `shape`: a `Shape` or a key of `SHAPES`. `free`: close-range block with `datum = "free"`
    instead of dependent relative orientation (the free-network shape is always free).
    Returns {"project", "n_images", "n_points", "n_image_points", "n_coordinates"}.
    """
    shape = SHAPES[shape] if isinstance(shape, str) else shape
    free = free or shape is FREE_NETWORK
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    points = make_targets(rng, shape.n_points)
    stations, matrices = make_stations(rng, shape.n_images, 1)
    seen = visible(points, stations, matrices, shape.camera)
    pairs = choose_views(rng, seen, shape)
    used = sorted({p for _, p in pairs})
    noise = rng.normal(0.0, NOISE_PX * PIXEL_SIZE[0], (len(pairs), 2))
    rows = [
        [f"img{i + 1:03d}", str(p + 1), *(f"{v:.8f}" for v in seen[i][p] + e)]
        for (i, p), e in zip(pairs, noise)
    ]
    write_table(directory / "image_coordinates.txt", "image_id point_id x y (mm)", rows)

    fixed = datum_fixed(stations, free)
    sigma6 = np.repeat(APPROX_SIGMA[:2], 3)
    rows = []
    for k, (station, m) in enumerate(zip(stations, matrices)):
        eop = np.array([*station, *np.degrees(opk_from_rotation(m))])
        eop = np.where(fixed[k], eop, eop + rng.normal(0.0, 1.0, 6) * sigma6)
        rows.append([f"img{k + 1:03d}", "C1", *(f"{v:.9f}" for v in eop[:3]),
                     *(f"{v:.8f}" for v in eop[3:]), *("0" if f else "-" for f in fixed[k])])
    header = "image_id camera_id X0 Y0 Z0 (m) omega phi kappa (deg) sX0..skappa (0 fixed)"
    write_table(directory / "orientation.txt", header, rows)

    approx = points + rng.normal(0.0, APPROX_SIGMA[2], points.shape)
    rows = [[str(p + 1), *(f"{v:.9f}" for v in approx[p]), "-", "-", "-"] for p in used]
    write_table(directory / "ground_points.txt", "point_id X Y Z (m) sX sY sZ (tie points)", rows)

    files = {
        "cameras": "cameras.toml",
        "images": "orientation.txt",
        "image_points": "image_coordinates.txt",
        "points": "ground_points.txt",
    }
    if shape is FREE_NETWORK:
        (a, b), = distance_pairs(points[used], 1)
        a, b = used[a], used[b]
        length = np.linalg.norm(points[a] - points[b]) + rng.normal(0.0, SCALE_BAR_SIGMA)
        rows = [[str(a + 1), str(b + 1), f"{length:.9f}", f"{SCALE_BAR_SIGMA:.6g}"]]
        write_table(directory / "distances.txt", "point_a point_b distance sigma (m)", rows)
        files["distances"] = "distances.txt"
    write_cameras(directory / "cameras.toml", shape.camera, shape.free)
    name = shape.name + ("_free" if free and shape is not FREE_NETWORK else "")
    project = directory / f"{name}.toml"
    write_project(project, name, files, "free" if free else "control", seed)
    return {
        "project": str(project),
        "n_images": shape.n_images,
        "n_points": len(used),
        "n_image_points": len(pairs),
        "n_coordinates": 2 * len(pairs),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shape", choices=sorted([*SHAPES, "unkind"]))
    parser.add_argument("directory", type=pathlib.Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--free", action="store_true", help='close-range with datum = "free"')
    parser.add_argument("--images", type=int, default=60, help="unkind: number of images")
    parser.add_argument("--points", type=int, default=26_000, help="unkind: wall points")
    args = parser.parse_args()
    if args.shape == "unkind":
        truth = write_close_range_project(args.directory, seed=args.seed, n_images=args.images,
                                          n_points=args.points,
                                          datum="free" if args.free else "dependent")
        print(json.dumps({"project": str(truth.project_file), "n_images": len(truth.images),
                          "n_points": len(truth.points)}))
        return
    print(json.dumps(write_block(args.directory, args.shape, seed=args.seed, free=args.free)))


if __name__ == "__main__":
    main()
