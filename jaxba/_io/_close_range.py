"""A synthetic close-range block as unkind as real ones, written as a project (pure NumPy).

`write_synthetic_project`'s lab is a well-posed target field; a real convergent block of
matched features is not. This block has what makes real ones hard for a solver:

- convergent images at 1.8-3.4 m from the wall of `jaxba._io._synthetic`, from all sides,
  each rolled by a random multiple of 90° plus N(0, 4°);
- tie points measured in 3 + Poisson(`mean_views` - 3) of the images that see them (like
  matched features; those seen by 2 images only on 2 rays);
- `weak_fraction` of the points far behind the wall (15-40 m) seen by two neighbouring
  images only: intersection angles below 2°, so weakly determined in depth and, being far
  from the network's centre, the coordinates a similarity moves the most;
- a lens with about 30 px of radial distortion at the format corner (K1, K2);
- `n_sparse` images that keep only `sparse_points` of the points they see.

One SMAC camera C1 (format, pixel size: `jaxba._io._synthetic`), xp, yp, c, K1, K2 free;
noise 0.25 px; approximations: stations ± 2 cm, angles ± 0.3°, wall points ± 1 cm (σ of a
normal perturbation), far points intersected from orientations with `WEAK_RAY_ERROR` of
those errors (off by decimetres to metres in depth, as a real block's), c rounded to
0.1 mm, distortion 0. Frames and units: `jaxba._io._synthetic`.
"""

import json
import math
import pathlib

import numpy as np

from ._project._project_file import project_toml
from ._synthetic import (
    DEFAULT_CAMERA,
    FIELD_CENTRE,
    IOP_NAMES,
    PIXEL_SIZE,
    SENSOR,
    SyntheticTruth,
    look_at,
    make_targets,
    observe,
    opk_from_rotation,
    project_ideal,
    rotation_matrix,
    toml_float,
    write_table,
)

# About -30 px of radial distortion at the format corner (r = 13.3 mm): x̄ (K1 r² + K2 r⁴).
CAMERA = DEFAULT_CAMERA | {"K1": -6.0e-5, "K2": 1.2e-7, "K3": 0.0, "P1": 0.0, "P2": 0.0}
FREE = ("xp", "yp", "c", "K1", "K2")
NOISE_PX = 0.25
APPROX_SIGMA = (0.02, 0.3, 0.01)  # station m, angle deg, point m
WEAK_DEPTH = (15.0, 40.0)  # m behind the wall
# Far points are intersected from orientations with this fraction of the approximations'
# errors (an earlier relative orientation): off by 0.1-10 m in depth.
WEAK_RAY_ERROR = 0.2
MIN_WEAK_ANGLE = 0.3  # degrees: below, a 2-ray point is as good as a single ray (datum check)


def corner_distortion_px(camera: dict) -> float:
    """Radial distortion x̄ (K1 r² + K2 r⁴ + K3 r⁶) at the format corner, in pixels."""
    r = math.hypot(*(np.array(SENSOR) / 2 * np.array(PIXEL_SIZE)))
    r2 = r * r
    return r * r2 * (camera["K1"] + r2 * (camera["K2"] + r2 * camera["K3"])) / PIXEL_SIZE[0]


def _stations(rng, n_images):
    """Convergent stations (n, 3) m and M (n, 3, 3): on a half ring of azimuths ±60° and
    elevations ±35° about the field centre, 1.8-3.4 m from it, aiming within 0.15 m of it,
    rolled by a random multiple of 90° plus N(0, 4°)."""
    stations, matrices = [], []
    azimuths = np.linspace(-60.0, 60.0, n_images) + rng.normal(0.0, 4.0, n_images)
    for k in range(n_images):
        azimuth = math.radians(azimuths[k])
        elevation = math.radians(rng.uniform(-35.0, 35.0))
        distance = rng.uniform(1.8, 3.4)
        direction = np.array([math.sin(azimuth) * math.cos(elevation), math.sin(elevation),
                              math.cos(azimuth) * math.cos(elevation)])
        station = FIELD_CENTRE + distance * direction
        aim = FIELD_CENTRE + rng.normal(0.0, 0.15, 3)
        roll = math.radians(90.0 * rng.integers(4) + rng.normal(0.0, 4.0))
        stations.append(station)
        matrices.append(look_at(station, aim, roll))
    return np.array(stations), np.array(matrices)


def _weak_points(rng, stations, matrices, n_weak):
    """`n_weak` points 15-40 m behind the wall, each on the ray through a random spot of
    the inner 80 % of an image's format; returns points (n, 3) and their two images (n, 2),
    the image and its nearest neighbour (the point must be in both formats, its rays at
    least `MIN_WEAK_ANGLE` apart)."""
    half = np.array(SENSOR) / 2 * np.array(PIXEL_SIZE)
    points, pairs = [], []
    while len(points) < n_weak:
        i = int(rng.integers(len(stations)))
        gaps = np.linalg.norm(stations - stations[i], axis=1)
        gaps[i] = np.inf
        j = int(np.argmin(gaps))
        xy = rng.uniform(-0.8, 0.8, 2) * half
        ray = matrices[i].T @ np.array([xy[0], xy[1], -CAMERA["c"]])  # object frame
        depth = rng.uniform(*WEAK_DEPTH)
        scale = (FIELD_CENTRE[2] - depth - stations[i][2]) / ray[2]
        if scale <= 0:
            continue
        point = stations[i] + scale * ray
        ideal, w = project_ideal(point[None], stations[j], matrices[j], CAMERA["c"])
        angle = intersection_angles(point[None], stations, [np.array([i, j])])[0]
        if w[0] < 0 and np.all(np.abs(ideal[0]) < 0.9 * half) and angle > MIN_WEAK_ANGLE:
            points.append(point)
            pairs.append((i, j))
    return np.array(points).reshape(-1, 3), np.array(pairs, dtype=int).reshape(-1, 2)


def _measured(points, station, m) -> dict:
    """Noise-free measurements of one image: point index -> (x, y) mm (`observe`, given
    only the points whose ideal image lies within 1.2 x the format)."""
    ideal, _ = project_ideal(points, station, m, CAMERA["c"])
    half = np.array(SENSOR) / 2 * np.array(PIXEL_SIZE)
    near = np.flatnonzero(np.all(np.abs(ideal) < 1.2 * half, axis=1))
    index, xy = observe(points[near], station, m, CAMERA)
    return dict(zip(near[index].tolist(), xy))


def _intersect(point, stations, matrices, approx_eops) -> np.ndarray:
    """The approximation of `point` (3,) a real block has: the least-squares intersection of
    its rays from approximate orientations `approx_eops` (k, 6; m, degrees), each ray
    through the point's ideal image in its true image (`stations` (k, 3), `matrices`
    (k, 3, 3)). For a far point on two rays its error is mostly in depth, metres."""
    normal, right = np.zeros((3, 3)), np.zeros(3)
    for station, m, eop in zip(stations, matrices, approx_eops):
        ideal, _ = project_ideal(point[None], station, m, CAMERA["c"])
        ray = rotation_matrix(*np.radians(eop[3:])).T @ np.array([*ideal[0], -CAMERA["c"]])
        across = np.eye(3) - np.outer(ray, ray) / (ray @ ray)
        normal += across
        right += across @ eop[:3]
    return np.linalg.solve(normal, right)


def intersection_angles(points, stations, views) -> np.ndarray:
    """The largest angle (degrees) between the rays of each point: `points` (n, 3),
    `stations` (m, 3), `views` a list of n index arrays into `stations`."""
    angles = np.zeros(len(points))
    for k, images in enumerate(views):
        rays = stations[images] - points[k]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        angles[k] = math.degrees(math.acos(np.clip(np.min(rays @ rays.T), -1.0, 1.0)))
    return angles


def write_close_range_project(
    directory,
    *,
    name="close_range",
    seed=0,
    n_images=16,
    n_points=900,
    mean_views=3.5,
    weak_fraction=0.055,
    n_sparse=2,
    sparse_points=15,
    datum="dependent",
    approximations=True,
) -> SyntheticTruth:
    """Write a convergent close-range block with the faults of real ones (module docstring)
    into `directory`: `{name}.toml`, `cameras.toml`, `orientation.txt`,
    `image_coordinates.txt`, `ground_points.txt` (docs/project-files.md).

    `n_points` wall points plus `weak_fraction` of them far behind it; `datum`:
    "dependent" or "free" (no control, no distances); `approximations` False: none (every
    EOP `-`, the points table empty: the block from nothing, the same block otherwise). The
    images "img01".. are those that measure a point; wall points seen by fewer than 3 are
    dropped. Returns the truth (`SyntheticTruth`; angles in degrees)."""
    if datum not in ("dependent", "free"):
        raise ValueError(f"datum must be 'dependent' or 'free', got {datum!r}")
    if n_sparse >= n_images or n_images < 3:
        raise ValueError(f"n_images ({n_images}) must be at least 3 and above n_sparse "
                         f"({n_sparse})")
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    stations, matrices = _stations(rng, n_images)
    wall = make_targets(rng, n_points)
    weak, weak_images = _weak_points(rng, stations, matrices,
                                     max(1, round(weak_fraction * n_points)))
    points = np.concatenate([wall, weak])
    measured = [_measured(points, s, m) for s, m in zip(stations, matrices)]

    sparse = rng.choice(n_images, size=n_sparse, replace=False)
    for i in sparse:
        keep = set(rng.permutation(sorted(p for p in measured[i] if p < len(wall)))
                   [:sparse_points].tolist())
        measured[i] = {p: xy for p, xy in measured[i].items() if p in keep}
    views: dict[int, list[int]] = {}
    for p in range(len(wall)):
        seen = [i for i in range(n_images) if p in measured[i]]
        if len(seen) >= 3:
            k = min(3 + rng.poisson(mean_views - 3), len(seen))
            views[p] = sorted(rng.choice(seen, size=k, replace=False).tolist())
    for q, pair in enumerate(weak_images):
        if all(len(wall) + q in measured[i] for i in pair):
            views[len(wall) + q] = sorted(pair.tolist())
    for i in sparse:  # a sparse image measures every point it keeps
        for p in measured[i]:
            if p in views and i not in views[p]:
                views[p] = sorted([*views[p], int(i)])
    used = sorted(views)

    image_ids = [f"img{k + 1:02d}" for k in range(n_images)]
    noise = NOISE_PX * PIXEL_SIZE[0]
    rows = [[image_ids[i], str(p + 1), *(f"{v:.8f}" for v in measured[i][p]
                                         + rng.normal(0.0, noise, 2))]
            for i in range(n_images) for p in used if i in views[p]]
    write_table(directory / "image_coordinates.txt", "image_id point_id x y (mm)", rows)

    truth_eops, approx_eops, rows = {}, [], []
    sigma6 = np.repeat(APPROX_SIGMA[:2], 3)
    for k, (station, m) in enumerate(zip(stations, matrices)):
        eop = np.array([*station, *np.degrees(opk_from_rotation(m))])
        truth_eops[image_ids[k]] = tuple(map(float, eop))
        eop = eop + rng.normal(0.0, 1.0, 6) * sigma6
        approx_eops.append(eop)
        rows.append([image_ids[k], "C1", *(f"{v:.9f}" for v in eop[:3]),
                     *(f"{v:.8f}" for v in eop[3:])] if approximations
                    else [image_ids[k], "C1", *["-"] * 6])
    write_table(directory / "orientation.txt",
                "image_id camera_id X0 Y0 Z0 (m) omega phi kappa (deg)", rows)

    approx = points + rng.normal(0.0, APPROX_SIGMA[2], points.shape)
    truth = np.array(list(truth_eops.values()))
    earlier = truth + WEAK_RAY_ERROR * (np.array(approx_eops) - truth)
    for p in range(len(wall), len(points)):
        if p in views:
            approx[p] = _intersect(points[p], stations[views[p]], matrices[views[p]],
                                   earlier[views[p]])
    rows = [[str(p + 1), *(f"{v:.9f}" for v in approx[p]), "-", "-", "-"]
            for p in used if approximations]
    write_table(directory / "ground_points.txt", "point_id X Y Z (m) sX sY sZ (tie points)",
                rows)

    lines = ["[C1]", 'model = "smac"', f"pixel_size = [{', '.join(map(toml_float, PIXEL_SIZE))}]",
             f"sensor = [{SENSOR[0]}, {SENSOR[1]}]",
             *(f"{p} = {toml_float(round(CAMERA['c'], 1) if p == 'c' else 0.0)}"
               for p in IOP_NAMES),
             f"free = {json.dumps(list(FREE))}", ""]
    (directory / "cameras.toml").write_text("\n".join(lines))
    files = {"cameras": "cameras.toml", "images": "orientation.txt",
             "image_points": "image_coordinates.txt", "points": "ground_points.txt"}
    project_file = directory / f"{name}.toml"
    project_file.write_text(project_toml(
        name, "mm", files, {"sigma0": 1.0, "image_sigma": float(toml_float(noise)),
                            "max_iterations": 100, "datum": datum},
        comment=[f"Synthetic close-range block (jaxba.write_close_range_project, seed {seed})."],
        notes={"image_sigma": "mm"}), encoding="utf-8")
    return SyntheticTruth(
        cameras={"C1": {p: float(CAMERA[p]) for p in IOP_NAMES}},
        images=truth_eops,
        points={str(p + 1): tuple(map(float, points[p])) for p in used},
        project_file=project_file,
    )
