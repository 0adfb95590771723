"""Synthetic self-calibration blocks written as project files (pure NumPy).

An independent implementation of the forward model of docs/conventions.md that writes test
projects in the docs/project-files.md layout with a known truth: a replica of the BASC
self-calibration lab (a 3D target field on a wall, convergent and rolled images, a datum of six
fixed coordinates and measured distances for the scale). Nothing here imports jax or jaxba's
camera models, so that the JAX model can be checked against it; the rotation is jaxba's NumPy
one (`jaxba._models._rotation_numpy`, itself checked against the product of the elementary
rotations).

Frames and units: object space X right, Y up, Z towards the cameras, metres; image space x right,
y up, mm, origin at the sensor centre; the camera looks along its -z axis; (U, V, W) = M (X - X0)
with M = R3(kappa) R2(phi) R1(omega).
"""

import dataclasses
import json
import math
import pathlib

import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from ._project._project_file import project_toml

IOP_NAMES = ("xp", "yp", "c", "K0", "K1", "K2", "K3", "P1", "P2", "P3", "A1", "A2")
# The BASC lab camera: mm, SMAC distortion with r in mm; about -5 % radial distortion at
# the format corner (r = 13.3 mm). Stronger lenses inflate the residual noise: the SMAC
# correction is evaluated at the noisy measurement, so v ≈ (I - ∂dist/∂x̄) n.
DEFAULT_CAMERA = {
    "xp": 0.012, "yp": -0.008, "c": 8.52, "K0": 0.0, "K1": -8.0e-4, "K2": 3.0e-6,
    "K3": -1.0e-8, "P1": 2.0e-5, "P2": -1.5e-5, "P3": 0.0, "A1": 0.0, "A2": 0.0,
}  # fmt: skip
PIXEL_SIZE = (0.00369, 0.00369)  # mm, x and y
SENSOR = (6000, 4000)  # columns, rows
MARGIN_PX = 20  # observations closer than this to the sensor edge are not written
WALL = (4.0, 3.0)  # m, width (X) and height (Y) of the target field
# Boxes standing out of the wall: X range and Y range as fractions of WALL, depth in m.
BOXES = (
    (0.15, 0.40, 0.15, 0.45, 0.35),
    (0.60, 0.85, 0.55, 0.85, 0.60),
    (0.55, 0.80, 0.10, 0.35, 0.20),
)
FIELD_CENTRE = np.array([WALL[0] / 2, WALL[1] / 2, 0.3])


@dataclasses.dataclass(frozen=True)
class SyntheticTruth:
    """The true parameters of a synthetic block.

    `cameras`: camera id -> all 12 IOPs (`IOP_NAMES`, mm). `images`: image id ->
    (X0, Y0, Z0 in m, omega, phi, kappa in degrees). `points`: target id -> (X, Y, Z) in m.
    `project_file`: the written project TOML.
    """

    cameras: dict[str, dict[str, float]]
    images: dict[str, tuple[float, float, float, float, float, float]]
    points: dict[str, tuple[float, float, float]]
    project_file: pathlib.Path


def rotation_matrix(omega, phi, kappa):
    """M = R3(kappa) R2(phi) R1(omega) (3, 3), rotating object-space vectors into the image
    frame (jaxba's `opk_to_matrix`). Angles in radians."""
    return opk_to_matrix(np.array([omega, phi, kappa]))


def opk_from_rotation(m):
    """(omega, phi, kappa) in radians of M (3, 3), for |phi| < 90 degrees (jaxba's
    `matrix_to_opk`), as a tuple of floats."""
    return tuple(float(angle) for angle in matrix_to_opk(m))


def look_at(station, target, roll):
    """M of a camera at `station` (3,) looking at `target` (3,), rolled by `roll` radians.

    The camera z axis points from the target to the station (it looks along -z), x = Y_up x z
    (horizontal, to the right) and y = z x x (up); the rows of M are x, y, z, then
    M = R3(roll) M. Positions in m; returns (3, 3).
    """
    z = (station - target) / np.linalg.norm(station - target)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return rotation_matrix(0.0, 0.0, roll) @ np.stack([x, np.cross(z, x), z])


def smac_correction(x_bar, y_bar, iop):
    """SMAC corrections (dx, dy) in mm at reduced coordinates x̄ = x - xp, ȳ = y - yp (mm).

    With r² = x̄² + ȳ²: radial x̄ (K0 + K1 r² + K2 r⁴ + K3 r⁶), ȳ (same); decentering
    (1 + P3 r²)(P1 (r² + 2x̄²) + 2 P2 x̄ȳ), (1 + P3 r²)(2 P1 x̄ȳ + P2 (r² + 2ȳ²)); affine
    -A1 x̄ + A2 ȳ, A1 ȳ. `x_bar`, `y_bar`: arrays of one shape; `iop`: dict of IOP_NAMES.
    """
    r2 = x_bar**2 + y_bar**2
    radial = iop["K0"] + r2 * (iop["K1"] + r2 * (iop["K2"] + r2 * iop["K3"]))
    p3 = 1.0 + iop["P3"] * r2
    dx = (
        x_bar * radial
        + p3 * (iop["P1"] * (r2 + 2 * x_bar**2) + 2 * iop["P2"] * x_bar * y_bar)
        + (-iop["A1"] * x_bar + iop["A2"] * y_bar)
    )
    dy = (
        y_bar * radial
        + p3 * (2 * iop["P1"] * x_bar * y_bar + iop["P2"] * (r2 + 2 * y_bar**2))
        + iop["A1"] * y_bar
    )
    return dx, dy


def project_ideal(points, station, m, c):
    """Reduced ideal image coordinates -c (U, V) / W, with (U, V, W) = M (X - X0).

    `points` (n, 3) m, `station` (3,) m, `m` (3, 3), `c` mm. Returns (n, 2) mm and W (n,) m
    (W < 0: the point is in front of the camera).
    """
    uvw = (points - station) @ m.T
    return -c * uvw[:, :2] / uvw[:, 2:], uvw[:, 2]


def solve_measured(ideal, iop, *, tol=1e-12, max_iter=50):
    """Reduced measured coordinates x̄ solving x̄ = x̄0 + dist(x̄) (dist = `smac_correction`).

    Newton iteration from x̄ = x̄0 with a central-difference Jacobian of dist (plain fixed-point
    iteration diverges near the format corners of strongly distorted lenses, where |d dist/dx̄|
    exceeds 1). `ideal` x̄0 (n, 2) mm; returns (n, 2) mm with |x̄ - x̄0 - dist(x̄)| < tol mm.
    """

    def residual(xy):
        return xy - ideal - np.stack(smac_correction(xy[:, 0], xy[:, 1], iop), axis=-1)

    xy, h = ideal.copy(), 1e-4
    for _ in range(max_iter):
        f = residual(xy)
        if np.max(np.abs(f), initial=0.0) < tol:
            return xy
        jac = np.stack(
            [(residual(xy + h * e) - residual(xy - h * e)) / (2 * h) for e in np.eye(2)], axis=-1
        )
        xy = xy - np.linalg.solve(jac, f[..., None])[..., 0]
    raise RuntimeError(f"image coordinates did not converge to {tol} mm in {max_iter} iterations")


def image_to_pixel(xy, pixel_size, sensor):
    """(col, row) = (x / ps_x + (ncols - 1) / 2, (nrows - 1) / 2 - y / ps_y).

    Pixel origin at the centre of the top-left pixel, row down. `xy` (n, 2) mm,
    `pixel_size` (ps_x, ps_y) mm, `sensor` (ncols, nrows). Returns (n, 2) pixels.
    """
    (ps_x, ps_y), (ncols, nrows) = pixel_size, sensor
    return np.stack([xy[:, 0] / ps_x + (ncols - 1) / 2, (nrows - 1) / 2 - xy[:, 1] / ps_y], axis=-1)


def observe(points, station, m, iop):
    """Noise-free measurements of the points in front of the camera and inside the sensor.

    x = xp + x̄ with x̄ from `solve_measured`; kept when |x|, |y| are at least MARGIN_PX inside
    the SENSOR edges. `points` (n, 3) m. Returns indices (k,) into `points` and (k, 2) mm.
    """
    ideal, w = project_ideal(points, station, m, iop["c"])
    front = np.flatnonzero(w < 0)
    xy = solve_measured(ideal[front], iop) + [iop["xp"], iop["yp"]]
    half = (np.array(SENSOR) / 2 - MARGIN_PX) * np.array(PIXEL_SIZE)
    inside = np.all(np.abs(xy) <= half, axis=1)
    return front[inside], xy[inside]


def make_targets(rng, n_targets):
    """Targets (n, 3) in m: a jittered grid over the WALL, on the plane Z in [0, 0.02] or raised
    to the front faces of the BOXES (Z up to 0.62).

    The grid has nx = ceil(sqrt(n W / H)) by ny = ceil(n / nx) cells, of which n random ones hold
    a target, placed in the middle 60 % of its cell.
    """
    width, height = WALL
    nx = math.ceil(math.sqrt(n_targets * width / height))
    ny = math.ceil(n_targets / nx)
    cells = np.sort(rng.choice(nx * ny, size=n_targets, replace=False))
    x = (cells % nx + rng.uniform(0.2, 0.8, n_targets)) * width / nx
    y = (cells // nx + rng.uniform(0.2, 0.8, n_targets)) * height / ny
    z = rng.uniform(0.0, 0.02, n_targets)
    for x0, x1, y0, y1, depth in BOXES:
        z[(x > x0 * width) & (x < x1 * width) & (y > y0 * height) & (y < y1 * height)] += depth
    return np.stack([x, y, z], axis=1)


def make_stations(rng, n_images, n_cameras):
    """Convergent stations in front of the wall, all looking at FIELD_CENTRE.

    Image i stands at cell i mod 9 of a 3 x 3 grid (X0 = centre + {-1.6, 0, 1.6} m, Y0 = centre +
    {-1, 0, 1} m, jittered by 0.15 m) at Z0 in [2.0, 2.6] m, so the field fills the format; it
    aims within 0.1 m of the centre and is
    rolled by kappa = 90° ((i // n_cameras) mod 4), so that every camera has all four rolls.
    Returns stations (n, 3) m and M (n, 3, 3).
    """
    stations, matrices = [], []
    for i in range(n_images):
        offset = [1.6 * (i % 3 - 1), 1.0 * ((i % 9) // 3 - 1), 0.0]
        station = FIELD_CENTRE + offset + rng.normal(0.0, 0.15, 3) * [1.0, 1.0, 0.0]
        station[2] = rng.uniform(2.0, 2.6)
        aim = FIELD_CENTRE + rng.normal(0.0, 0.1, 3)
        stations.append(station)
        matrices.append(look_at(station, aim, math.radians(90.0 * ((i // n_cameras) % 4))))
    return np.array(stations), np.array(matrices)


def camera_truths(camera, n_cameras):
    """True IOPs per camera id "C1".."Cn", all IOP_NAMES (missing ones are 0).

    `camera`: None (DEFAULT_CAMERA), one IOP dict, or a dict camera id -> IOP dict. From one dict,
    camera Ck with k >= 2 gets c + 0.03 (k-1), xp + 0.01 (k-1), yp - 0.006 (k-1) mm and
    K1 (1 + 0.1 (k-1)), so that every camera has its own truth.
    """
    camera = DEFAULT_CAMERA if camera is None else camera
    ids = [f"C{k + 1}" for k in range(n_cameras)]
    one_for_all = not all(isinstance(v, dict) for v in camera.values())
    if not one_for_all and sorted(camera) != sorted(ids):
        raise ValueError(f"camera: expected the ids {ids}, got {sorted(camera)}")
    truths = {}
    for k, cid in enumerate(ids):
        iop = camera if one_for_all else camera[cid]
        unknown = set(iop) - set(IOP_NAMES)
        if unknown or iop.get("c", 0.0) <= 0:
            raise ValueError(f"camera {cid}: unknown IOPs {sorted(unknown)} or no positive c")
        truth = {name: float(iop.get(name, 0.0)) for name in IOP_NAMES}
        if one_for_all:
            truth |= {
                "c": truth["c"] + 0.03 * k,
                "xp": truth["xp"] + 0.01 * k,
                "yp": truth["yp"] - 0.006 * k,
            }
            truth["K1"] *= 1 + 0.1 * k
        truths[cid] = truth
    return truths


def datum_targets(points):
    """Indices of the targets nearest the wall corners (0, 0), (W, 0), (0, H) in X, Y: A, B, C."""
    corners = np.array([[0.0, 0.0], [WALL[0], 0.0], [0.0, WALL[1]]])
    a, b, c = [int(np.argmin(np.linalg.norm(points[:, :2] - corner, axis=1))) for corner in corners]
    assert len({a, b, c}) == 3, "datum targets must be distinct"
    return a, b, c


def distance_pairs(points, n_distances):
    """The longest target pairs, taken greedily, no target twice: (n_distances, 2) indices."""
    i, j = np.triu_indices(len(points), 1)
    lengths = np.linalg.norm(points[i] - points[j], axis=1)
    pairs, used = [], set()
    for k in np.argsort(-lengths):
        if len(pairs) < n_distances and not {i[k], j[k]} & used:
            pairs.append((int(i[k]), int(j[k])))
            used |= {i[k], j[k]}
    return np.array(pairs, dtype=int).reshape(-1, 2)


def toml_float(value):
    """A TOML float literal of `value` with at most 12 significant digits."""
    return repr(float(f"{value:.12g}"))


def write_table(path, header, rows):
    """Write `rows` (lists of already formatted fields) under a `# header` line."""
    path.write_text("\n".join([f"# {header}", *(" ".join(row) for row in rows)]) + "\n")


def write_synthetic_project(
    directory,
    *,
    name="lab",
    seed=0,
    n_images=18,
    n_targets=80,
    camera=None,
    noise_px=0.25,
    image_sigma_px=None,
    datum="lab",
    n_distances=4,
    distance_sigma=0.0002,
    image_units="mm",
    n_cameras=1,
    camera_noise_px=None,
    blunders=(),
    approx_error=(0.05, 2.0, 0.02),
    free=("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"),
    gnss_sigma=None,
) -> SyntheticTruth:
    """Write a synthetic self-calibration block (BASC lab replica) into `directory`.

    Files: `{name}.toml`, `cameras.toml`, `orientation.txt`, `image_coordinates.txt`,
    `ground_points.txt` and, when `n_distances` > 0, `distances.txt` (docs/project-files.md).

    Measurements solve x = xp - c U/W + dist(x - xp, y - yp) (SMAC, docs/conventions.md) plus
    N(0, (noise_px ps)²) per coordinate (`camera_noise_px[k]` for camera k+1 if given). Images
    img01.. alternate between cameras C1..Cn. `image_sigma_px` (default `noise_px`, or 0.25 when
    `noise_px` is 0) is the prior σ written to the project, in mm or pixels per `image_units`.
    `datum="lab"` fixes X, Y, Z of target A, Y, Z of B and Z of C (the targets nearest the wall's
    lower left, lower right and upper left corners) at their true values; `"none"` fixes nothing.
    `n_distances` distances between the farthest targets get noise and σ `distance_sigma` (m).
    `blunders`: (image_id, point_id, axis 0/1, size in mm) added to a measurement.
    `approx_error`: σ of the approximations' perturbation (station m, angle deg, point m).
    `free`: the IOPs left free in cameras.toml (approximations c rounded to 0.1 mm, all else 0).
    `gnss_sigma` = (σXYZ m, σangle deg): the images table then holds noisy EOP observations with
    these σ, which are also the approximations. Returns the truth.
    """
    if datum not in ("lab", "none") or image_units not in ("mm", "pixel"):
        raise ValueError(
            f"datum must be 'lab' or 'none' and image_units 'mm' or 'pixel', "
            f"got {datum!r} and {image_units!r}"
        )
    if set(free) - set(IOP_NAMES):
        raise ValueError(f"free: unknown IOPs {sorted(set(free) - set(IOP_NAMES))}")
    if not 0 <= n_distances <= n_targets // 2:
        raise ValueError(f"n_distances must be in [0, n_targets // 2], got {n_distances}")
    camera_noise_px = [noise_px] * n_cameras if camera_noise_px is None else list(camera_noise_px)
    if len(camera_noise_px) != n_cameras:
        raise ValueError(f"camera_noise_px needs {n_cameras} entries, got {len(camera_noise_px)}")
    image_sigma_px = image_sigma_px if image_sigma_px is not None else (noise_px or 0.25)
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    cameras = camera_truths(camera, n_cameras)
    camera_ids = list(cameras)
    points = make_targets(rng, n_targets)
    point_ids = [str(k + 1) for k in range(n_targets)]
    stations, matrices = make_stations(rng, n_images, n_cameras)
    image_ids = [f"img{k + 1:0{max(2, len(str(n_images)))}d}" for k in range(n_images)]
    image_camera = [camera_ids[k % n_cameras] for k in range(n_images)]

    # Truth EOPs, and the measurements with noise.
    eops, observations, seen = {}, {}, np.zeros(n_targets, dtype=int)
    for k, (iid, cid) in enumerate(zip(image_ids, image_camera)):
        opk = opk_from_rotation(matrices[k])
        assert np.allclose(rotation_matrix(*opk), matrices[k], atol=1e-12), (
            "omega-phi-kappa round trip"
        )
        eops[iid] = (*map(float, stations[k]), *map(math.degrees, opk))
        index, xy = observe(points, stations[k], matrices[k], cameras[cid])
        xy = xy + rng.normal(0.0, camera_noise_px[k % n_cameras] * PIXEL_SIZE[0], xy.shape)
        seen[index] += 1
        observations.update({(iid, point_ids[p]): xy_p for p, xy_p in zip(index, xy)})
    if seen.min() < 3:
        raise AssertionError(
            f"targets {[point_ids[p] for p in np.flatnonzero(seen < 3)]} are seen by < 3 images"
        )
    for iid, pid, axis, size in blunders:
        if (iid, pid) not in observations:
            raise ValueError(f"blunder: image {iid} does not observe point {pid}")
        observations[(iid, pid)][axis] += size

    # Image points, in mm or pixels.
    keys = list(observations)
    xy = np.array([observations[key] for key in keys]).reshape(-1, 2)
    if image_units == "pixel":
        xy, image_sigma, unit = image_to_pixel(xy, PIXEL_SIZE, SENSOR), image_sigma_px, "pixels"
    else:
        image_sigma, unit = image_sigma_px * PIXEL_SIZE[0], "mm"
    rows = [[iid, pid, f"{x:.8f}", f"{y:.8f}"] for (iid, pid), (x, y) in zip(keys, xy)]
    write_table(directory / "image_coordinates.txt", f"image_id point_id x y ({unit})", rows)

    # Images: approximations, or GNSS/INS observations with their sigma.
    header = "image_id camera_id X0 Y0 Z0 (m) omega phi kappa (deg)"
    sigma6 = np.repeat(approx_error[:2] if gnss_sigma is None else gnss_sigma, 3)
    rows = []
    for iid, cid in zip(image_ids, image_camera):
        eop = np.array(eops[iid]) + rng.normal(0.0, 1.0, 6) * sigma6
        rows.append([iid, cid, *(f"{v:.9f}" for v in eop[:3]), *(f"{v:.8f}" for v in eop[3:])])
        if gnss_sigma is not None:
            rows[-1] += [f"{s:.6g}" for s in sigma6]
    if gnss_sigma is not None:
        header += " sX0 sY0 sZ0 (m) somega sphi skappa (deg)"
    write_table(directory / "orientation.txt", header, rows)

    # Ground points: fixed datum coordinates exact, all else perturbed approximations.
    fixed = np.zeros((n_targets, 3), dtype=bool)
    if datum == "lab":
        a, b, c = datum_targets(points)
        fixed[a], fixed[b, 1:], fixed[c, 2] = True, True, True
    approx = np.where(fixed, points, points + rng.normal(0.0, approx_error[2], points.shape))
    rows = [
        [pid, *(f"{v:.9f}" for v in approx[k]), *("0" if f else "-" for f in fixed[k])]
        for k, pid in enumerate(point_ids)
    ]
    write_table(
        directory / "ground_points.txt", "point_id X Y Z (m) sX sY sZ (m; 0 fixed, - free)", rows
    )

    files = {
        "cameras": "cameras.toml",
        "images": "orientation.txt",
        "image_points": "image_coordinates.txt",
        "points": "ground_points.txt",
    }
    if n_distances:
        rows = []
        for i, j in distance_pairs(points, n_distances):
            length = np.linalg.norm(points[i] - points[j]) + rng.normal(0.0, distance_sigma)
            rows.append([point_ids[i], point_ids[j], f"{length:.9f}", f"{distance_sigma:.6g}"])
        write_table(directory / "distances.txt", "point_a point_b distance sigma (m)", rows)
        files["distances"] = "distances.txt"

    # cameras.toml and the project file.
    lines = []
    for cid, iop in cameras.items():
        lines += [
            f"[{cid}]",
            'model = "smac"',
            f"pixel_size = [{', '.join(map(toml_float, PIXEL_SIZE))}]",
        ]
        lines += [f"sensor = [{SENSOR[0]}, {SENSOR[1]}]"]
        lines += [f"{p} = {toml_float(round(iop['c'], 1) if p == 'c' else 0.0)}" for p in IOP_NAMES]
        lines += [f"free = {json.dumps(list(free))}", ""]
    (directory / "cameras.toml").write_text("\n".join(lines))
    project_file = directory / f"{name}.toml"
    project_file.write_text(project_toml(
        name, image_units, files,
        {"sigma0": 1.0, "image_sigma": float(toml_float(image_sigma)), "max_iterations": 50},
        comment=[f"Synthetic self-calibration block (jaxba.write_synthetic_project, seed {seed})."],
        notes={"image_sigma": unit}), encoding="utf-8")
    return SyntheticTruth(
        cameras=cameras,
        images=eops,
        points={pid: tuple(map(float, points[k])) for k, pid in enumerate(point_ids)},
        project_file=project_file,
    )
