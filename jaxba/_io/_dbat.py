"""DBAT script projects (Börlin & Grussenmeyer's Damped Bundle Adjustment Toolbox) for jaxba.

A DBAT script (e.g. data/script/camcaldemo/camcaldemo.xml) names its control points
(`id,label,x,y,z[,sxyz]`), images (`id,path`), mark points (`im,id,x,y,sxy`, pixels) and
cameras; a DBAT camera file (c4040z.xml) holds the camera prior. `write_dbat_project` turns
them into a project (docs/project-files.md) with one "photomodeler" camera (DBAT's lens model 3,
`PhotoModelerCamera`).

Conventions (docs/dbat.md): DBAT's pixel coordinates have their origin at the top-left
*corner* of the image (PhotoModeler's convention: DBAT's default principal point, the sensor
centre, is pixel (W/2, H/2)); jaxba's at the centre of the top-left pixel, so every mark point
is written shifted by -0.5 px. DBAT's mm are pixel × pixel size from that corner, y down;
jaxba's from the sensor centre, y up:

    xp_dbat = xp + (W/2) ps_x,   yp_dbat = (H/2) ps_y - yp.

Starting EOPs are computed here, as DBAT does before its bundle (`spatial_resection`, then
`forward_intersection`), from DBAT's default interior orientation (c = focal, principal
point at the sensor centre, no distortion): a planar resection per image from the control
points (homography by DLT, then the nearest rotation) and a least-squares intersection of
the rays of every other point. Plain NumPy; nothing here calls jax.
"""

import dataclasses
import json
import os
import pathlib
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import numpy as np

MODEL = "photomodeler"
CAMERA_PARAMETERS = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect", "skew")
# DBAT's script <io><all>true</all><skew>false</skew>: every IO parameter but skew.
FREE = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect")
PIXEL_ORIGIN_SHIFT = -0.5  # DBAT/PhotoModeler pixel (corner origin) -> jaxba pixel (centre origin)


@dataclasses.dataclass(frozen=True)
class DbatCamera:
    """A DBAT camera: sensor height (mm) and image size (W, H) in pixels, focal length (mm).

    DBAT's sensor "auto,H" means square pixels of H / image height; the pixel size is that
    of DBAT's bundle, where the aspect parameter (not the pixel size) absorbs non-square pixels.
    """

    id: str
    name: str
    sensor_height: float
    image_size: tuple[int, int]
    focal: float
    lens_model: int
    n_k: int
    n_p: int

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(ps_x, ps_y) mm per pixel."""
        ps = self.sensor_height / self.image_size[1]
        return ps, ps

    def principal_point_to_dbat(self, xp: float, yp: float) -> tuple[float, float]:
        """jaxba (xp, yp) (sensor centre, y up) -> DBAT's (top-left image corner, y down), mm."""
        (width, height), (ps_x, ps_y) = self.image_size, self.pixel_size
        return xp + width / 2 * ps_x, height / 2 * ps_y - yp

    def principal_point_from_dbat(self, xp: float, yp: float) -> tuple[float, float]:
        """DBAT's (xp, yp) (top-left image corner, y down) -> jaxba's (sensor centre, y up), mm."""
        (width, height), (ps_x, ps_y) = self.image_size, self.pixel_size
        return xp - width / 2 * ps_x, height / 2 * ps_y - yp


@dataclasses.dataclass(frozen=True)
class ControlPoint:
    """A DBAT control point: label, coordinates and σ (None: fixed, DBAT's default)."""

    id: str
    label: str
    xyz: tuple[float, float, float]
    sigma: float | None


@dataclasses.dataclass(frozen=True)
class MarkPoint:
    """One DBAT image measurement, in DBAT's pixels (corner origin, row down)."""

    image: str
    point: str
    col: float
    row: float
    sigma: float


@dataclasses.dataclass(frozen=True)
class DbatScript:
    """What a DBAT script names: its files (resolved) and its cameras."""

    path: pathlib.Path
    control_file: pathlib.Path
    images_file: pathlib.Path
    mark_points_file: pathlib.Path
    cameras: tuple[DbatCamera, ...]


@dataclasses.dataclass(frozen=True)
class DbatProject:
    """What `write_dbat_project` wrote.

    `images`: image_id -> starting (X0, Y0, Z0) in object units and (omega, phi, kappa) in
    degrees as written; `n_image_points`: measurements written (each two observations).
    """

    project_file: pathlib.Path
    camera: DbatCamera
    images: dict[str, tuple[float, ...]]
    control: dict[str, ControlPoint]
    n_image_points: int
    n_points: int


# --- DBAT's files ---------------------------------------------------------------------------


def _table(path: pathlib.Path, fields: Sequence[str]) -> list[dict[str, str]]:
    """Rows of a comma-separated DBAT table (`#` comments), as dicts named by `fields`."""
    rows = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        values = [value.strip() for value in text.split(",")]
        if len(values) != len(fields):
            raise ValueError(
                f"{path}:{number}: expected {len(fields)} comma-separated fields "
                f"({','.join(fields)}), got {len(values)}"
            )
        rows.append(dict(zip(fields, values)))
    return rows


def read_control_points(path: str | os.PathLike) -> dict[str, ControlPoint]:
    """DBAT control points, `id,label,x,y,z` (fixed) or `id,label,x,y,z,sxyz` (weighted)."""
    path = pathlib.Path(path)
    lines = [ln.split("#", 1)[0] for ln in path.read_text(encoding="utf-8").splitlines()]
    n_fields = max((len(ln.split(",")) for ln in lines if ln.strip()), default=5)
    fields = ("id", "label", "x", "y", "z", "sxyz")[:n_fields]
    points = {}
    for row in _table(path, fields):
        sigma = float(row["sxyz"]) if "sxyz" in row else None
        xyz = (float(row["x"]), float(row["y"]), float(row["z"]))
        points[row["id"]] = ControlPoint(row["id"], row["label"], xyz, sigma)
    return points


def read_images(path: str | os.PathLike) -> dict[str, str]:
    """DBAT image list `id,path` -> {DBAT image id: file stem} (the jaxba image id)."""
    rows = _table(pathlib.Path(path), ("id", "path"))
    return {row["id"]: pathlib.PurePosixPath(row["path"].replace("\\", "/")).stem for row in rows}


def read_mark_points(path: str | os.PathLike) -> list[MarkPoint]:
    """DBAT mark points `im,id,x,y,sxy` (pixels, DBAT's corner origin), in file order."""
    rows = _table(pathlib.Path(path), ("im", "id", "x", "y", "sxy"))
    return [MarkPoint(r["im"], r["id"], float(r["x"]), float(r["y"]), float(r["sxy"]))
            for r in rows]


def _text(element: ET.Element, tag: str) -> str:
    child = element.find(tag)
    if child is None or child.text is None:
        raise ValueError(f"DBAT camera: missing <{tag}>")
    return child.text.strip()


def _camera(element: ET.Element) -> DbatCamera:
    sensor = [s.strip() for s in _text(element, "sensor").split(",")]
    width, height = (int(v) for v in _text(element, "image").split(","))
    aspect = float(_text(element, "aspect")) if element.find("aspect") is not None else 1.0
    if len(sensor) != 2 or sensor[0] != "auto" or aspect != 1.0:
        raise ValueError(
            f"DBAT camera: only <sensor>auto,HEIGHT</sensor> with <aspect>1</aspect> is "
            f"supported, got sensor {','.join(sensor)!r}, aspect {aspect}"
        )
    if _text(element, "unit") != "mm":
        raise ValueError(f"DBAT camera: unit must be mm, got {_text(element, 'unit')!r}")
    return DbatCamera(
        id=_text(element, "id"),
        name=_text(element, "name"),
        sensor_height=float(sensor[1]),
        image_size=(width, height),
        focal=float(_text(element, "focal")),
        lens_model=int(_text(element, "model")),
        n_k=int(_text(element, "nK")),
        n_p=int(_text(element, "nP")),
    )


def read_cameras(path: str | os.PathLike) -> tuple[DbatCamera, ...]:
    """The <cameras><camera> blocks of a DBAT camera file or script."""
    root = ET.parse(path).getroot()
    cameras = tuple(_camera(element) for element in root.iter("camera"))
    if not cameras:
        raise ValueError(f"{path}: no <camera> block")
    return cameras


def _input_file(block: ET.Element | None, base: pathlib.Path, what: str, fmt: str) -> pathlib.Path:
    element = None if block is None else block.find("file")
    if element is None or element.text is None:
        raise ValueError(f"DBAT script: no <{what}><file>")
    if element.get("format", fmt).replace(" ", "") != fmt:
        raise ValueError(
            f"DBAT script: <{what}> format {element.get('format')!r}, expected {fmt!r}")
    return base / element.text.strip()


def read_script(path: str | os.PathLike) -> DbatScript:
    """The input block of a DBAT script (base_dir "$HERE": paths relative to the script)."""
    path = pathlib.Path(path)
    root = ET.parse(path).getroot()
    block = root.find("input")
    if block is None:
        raise ValueError(f"{path}: no <input> block")
    base = path.parent
    control = block.find("ctrl_pts")
    control_element = None if control is None else control.find("file")
    control_format = "" if control_element is None else control_element.get("format", "")
    if control_format.replace(" ", "") not in ("id,label,x,y,z", "id,label,x,y,z,sxyz"):
        raise ValueError(f"{path}: unsupported <ctrl_pts> format {control_format!r}")
    return DbatScript(
        path=path,
        control_file=_input_file(control, base, "ctrl_pts", control_format.replace(" ", "")),
        images_file=_input_file(block.find("images"), base, "images", "id,path"),
        mark_points_file=_input_file(block.find("image_pts"), base, "image_pts", "im,id,x,y,sxy"),
        cameras=read_cameras(path),
    )


# --- starting values -------------------------------------------------------------------------


def jaxba_pixels(col: float, row: float) -> tuple[float, float]:
    """DBAT pixel (corner origin) -> jaxba pixel (centre of the top-left pixel), (col, row)."""
    return col + PIXEL_ORIGIN_SHIFT, row + PIXEL_ORIGIN_SHIFT


def _image_mm(camera: DbatCamera, pixels: np.ndarray) -> np.ndarray:
    """DBAT pixels (n, 2) -> jaxba image mm (sensor centre, y up), like `PixelGrid`."""
    (width, height), (ps_x, ps_y) = camera.image_size, camera.pixel_size
    return np.c_[(pixels[:, 0] - width / 2) * ps_x, (height / 2 - pixels[:, 1]) * ps_y]


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """H with dst ~ H src (homogeneous 2D points, n ≥ 4) by Hartley-normalised DLT."""

    def normaliser(points):
        centroid = points.mean(axis=0)
        scale = np.sqrt(2) / np.mean(np.linalg.norm(points - centroid, axis=1))
        return np.array([[scale, 0, -scale * centroid[0]], [0, scale, -scale * centroid[1]],
                         [0, 0, 1]])

    t_src, t_dst = normaliser(src), normaliser(dst)
    a = np.c_[src, np.ones(len(src))] @ t_src.T
    b = np.c_[dst, np.ones(len(dst))] @ t_dst.T
    zeros = np.zeros_like(a)
    rows = np.r_[np.c_[a, zeros, -b[:, :1] * a], np.c_[zeros, a, -b[:, 1:2] * a]]
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    return np.linalg.inv(t_dst) @ h @ t_src


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def planar_resection(
    object_points: np.ndarray, image_points: np.ndarray, c: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pose (M, X0) of an image from ≥ 4 coplanar points, distortion-free, principal point 0.

    With the control plane X = o + s e1 + t e2 and (x, y, -c) ∝ M (X - X0) (docs/conventions.md),
    (x/-c, y/-c, 1) ∝ H (s, t, 1) with H ∝ [M e1, M e2, M (o - X0)]; the scale of H makes its
    first two columns unit vectors and puts the points in front of the camera (W < 0).
    """
    origin = object_points.mean(axis=0)
    _, singular, vt = np.linalg.svd(object_points - origin)
    if singular[2] > 1e-6 * singular[0]:
        raise ValueError("planar resection: the control points are not coplanar")
    e1, e2 = vt[0], vt[1]
    e3 = np.cross(e1, e2)
    plane = (object_points - origin) @ np.c_[e1, e2]
    h = _homography(plane, image_points / -c)
    scale = (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1])) / 2
    # M (X - X0) = H (s, t, 1) / scale must have W < 0 (the camera looks along -z).
    if (h @ np.r_[plane[0], 1.0])[2] > 0:
        scale = -scale
    m1, m2, t = h[:, 0] / scale, h[:, 1] / scale, h[:, 2] / scale
    m_plane = _nearest_rotation(np.c_[m1, m2, np.cross(m1, m2)])  # M [e1 e2 e3]
    rotation = m_plane @ np.c_[e1, e2, e3].T
    station = origin - rotation.T @ t
    return rotation, station


def intersect(stations: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to the rays station_i + λ direction_i, (n, 3) each."""
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    projectors = np.eye(3) - units[:, :, None] * units[:, None, :]
    return np.linalg.solve(projectors.sum(axis=0), np.einsum("nij,nj->i", projectors, stations))


def matrix_to_opk(m: np.ndarray) -> np.ndarray:
    """(omega, phi, kappa) in radians of M = R3(kappa) R2(phi) R1(omega), docs/conventions.md."""
    return np.array([
        np.arctan2(-m[2, 1], m[2, 2]),
        np.arctan2(m[2, 0], np.hypot(m[2, 1], m[2, 2])),
        np.arctan2(-m[1, 0], m[0, 0]),
    ])


# --- the project ------------------------------------------------------------------------------


def _write_table(path: pathlib.Path, header: Sequence[str], rows: list[list[str]]) -> None:
    lines = [f"# {line}" for line in header] + [" ".join(row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


def _relative(path: pathlib.Path, start: pathlib.Path) -> str:
    return pathlib.Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()


def write_dbat_project(
    script: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    project_file: str | os.PathLike | None = None,
    name: str = "dbat_camcal",
    camera_file: str | os.PathLike | None = "c4040z.xml",
    control_file: str | os.PathLike | None = None,
) -> DbatProject:
    """Write a DBAT script project as a jaxba project (docs/project-files.md).

    **Arguments:**

    - `script`: the DBAT script (camcaldemo.xml); its input block names the files read.
    - `out_dir`: where cameras.toml, orientation.txt, image_coordinates.txt and points.txt go.
    - `project_file`: the project TOML (default `out_dir/NAME.toml`); its paths are written
      relative to its folder.
    - `name`: the project name.
    - `camera_file`: a DBAT camera file (relative to the script's folder) whose camera must
      agree with the script's; None uses the script's camera alone.
    - `control_file`: a DBAT control point file instead of the script's (e.g.
      reference/camcal-weighted.txt, `id,label,x,y,z,sxyz`: weighted with σ = sxyz).

    One "photomodeler" camera with DBAT's default starting values (c = focal, principal point
    at the sensor centre, no distortion) and xp yp c K1 K2 K3 P1 P2 aspect free, skew fixed;
    image points in jaxba pixels (DBAT's - 0.5) with DBAT's σ per coordinate; control points
    fixed (no sxyz) or weighted; starting EOPs by planar resection and tie points by
    intersection (module docstring).
    """
    script = read_script(script)
    out_dir = pathlib.Path(out_dir)
    project_file = pathlib.Path(project_file) if project_file else out_dir / f"{name}.toml"
    if len(script.cameras) != 1:
        raise ValueError(f"{script.path}: expected one camera, got {len(script.cameras)}")
    camera = script.cameras[0]
    if camera_file is not None:
        prior = read_cameras(script.path.parent / camera_file)[0]
        if (prior.sensor_height, prior.image_size, prior.focal) != (
            camera.sensor_height, camera.image_size, camera.focal
        ):
            raise ValueError(f"{camera_file}: camera differs from the one in {script.path.name}")
    if (camera.lens_model, camera.n_k, camera.n_p) != (3, 3, 2):
        raise ValueError(
            f"{script.path.name}: only DBAT lens model 3 with nK = 3, nP = 2 is supported, got "
            f"model {camera.lens_model}, nK {camera.n_k}, nP {camera.n_p}"
        )
    control_path = script.control_file if control_file is None else (
        script.path.parent / control_file)
    control = read_control_points(control_path)
    image_names = read_images(script.images_file)
    marks = read_mark_points(script.mark_points_file)
    unknown = {m.image for m in marks} - set(image_names)
    if unknown:
        raise ValueError(f"{script.mark_points_file}: unknown images {sorted(unknown)}")

    # Starting EOPs: planar resection from the control points, DBAT's default IO.
    by_image: dict[str, list[MarkPoint]] = {}
    for mark in marks:
        by_image.setdefault(mark.image, []).append(mark)
    poses = {}
    for image, measured in by_image.items():
        cps = [m for m in measured if m.point in control]
        if len(cps) < 4:
            raise ValueError(f"image {image}: {len(cps)} control points, need 4 for the resection")
        xy = _image_mm(camera, np.array([[m.col, m.row] for m in cps]))
        xyz = np.array([control[m.point].xyz for m in cps])
        poses[image] = planar_resection(xyz, xy, camera.focal)

    # Tie points: least-squares intersection of their rays.
    rays: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for mark in marks:
        if mark.point in control:
            continue
        rotation, station = poses[mark.image]
        x, y = _image_mm(camera, np.array([[mark.col, mark.row]]))[0]
        direction = rotation.T @ np.array([x, y, -camera.focal])
        rays.setdefault(mark.point, []).append((station, direction))
    tie = {}
    for point, point_rays in rays.items():
        if len(point_rays) < 2:
            raise ValueError(f"point {point}: {len(point_rays)} ray, need 2 to intersect")
        tie[point] = intersect(*(np.array(v) for v in zip(*point_rays)))

    out_dir.mkdir(parents=True, exist_ok=True)
    project_file.parent.mkdir(parents=True, exist_ok=True)
    images = {}
    rows = []
    for dbat_id, image_id in image_names.items():
        if dbat_id not in poses:
            continue
        rotation, station = poses[dbat_id]
        eop = (*np.round(station, 6), *np.round(np.degrees(matrix_to_opk(rotation)), 6))
        images[image_id] = tuple(float(v) for v in eop)
        rows.append([image_id, "C1", *(f"{v:.6f}" for v in eop)])
    _write_table(out_dir / "orientation.txt", [
        "image_id camera_id X0 Y0 Z0 (m) omega phi kappa (deg); image ids: the file stems of "
        f"DBAT's {script.images_file.name}",
        "starting values: planar resection from the control points, c = focal, no distortion",
    ], rows)

    rows = []
    for pid, point in control.items():
        sigma = "0" if point.sigma is None else repr(point.sigma)
        rows.append([pid, *(repr(v) for v in point.xyz), sigma, sigma, sigma])
    for pid in sorted(tie, key=lambda p: (len(p), p)):
        rows.append([pid, *(f"{v:.6f}" for v in tie[pid]), "-", "-", "-"])
    _write_table(out_dir / "points.txt", [
        "point_id X Y Z (m) sX sY sZ (0 fixed, - free)",
        f"control: {control_path.name} (labels: "
        + ", ".join(f"{p.id} {p.label}" for p in control.values())
        + "); tie points: starting values by intersection",
    ], rows)

    rows = []
    for mark in marks:
        col, row = jaxba_pixels(mark.col, mark.row)
        sigma = repr(mark.sigma)
        rows.append([image_names[mark.image], mark.point, repr(col), repr(row), sigma, sigma])
    _write_table(out_dir / "image_coordinates.txt", [
        "image_id point_id col row sx sy (pixel; origin at the centre of the top-left pixel,",
        f"i.e. DBAT's {script.mark_points_file.name} - 0.5 px; sx = sy = DBAT's sxy)",
    ], rows)

    (ps_x, ps_y), (width, height) = camera.pixel_size, camera.image_size
    initial = {"c": camera.focal}
    lines = [
        f"# {camera.name}: DBAT camera {camera.id}, lens model {camera.lens_model} (backward).",
        f"# Pixel size {camera.sensor_height} mm / {height} px, square (DBAT's sensor 'auto').",
        "# Principal point: DBAT's = (xp + W/2 ps_x, H/2 ps_y - yp) (docs/dbat.md).",
        "[C1]",
        f'model = "{MODEL}"',
        f"pixel_size = [{ps_x!r}, {ps_y!r}]",
        f"sensor = [{width}, {height}]",
        *(f"{p} = {float(initial.get(p, 0.0))!r}" for p in CAMERA_PARAMETERS),
        f"free = {json.dumps(list(FREE))}",
    ]
    (out_dir / "cameras.toml").write_text("\n".join(lines) + "\n")

    base = project_file.parent
    default_sigma = marks[0].sigma if len({m.sigma for m in marks}) == 1 else 0.1
    project_file.write_text("\n".join([
        f"# DBAT script {script.path.name} (Börlin & Grussenmeyer, DBAT): self-calibration",
        f"# of the PhotoModeler calibration sheet. Regenerate: python configs/make_{name}.py",
        "[project]",
        f"name = {json.dumps(name)}",
        'image_units = "pixel"',
        "",
        "[files]",
        f"cameras = {json.dumps(_relative(out_dir / 'cameras.toml', base))}",
        f"images = {json.dumps(_relative(out_dir / 'orientation.txt', base))}",
        f"image_points = {json.dumps(_relative(out_dir / 'image_coordinates.txt', base))}",
        f"points = {json.dumps(_relative(out_dir / 'points.txt', base))}",
        "",
        "[adjustment]",
        "sigma0 = 1.0",
        f"image_sigma = {default_sigma!r}  # pixel, per coordinate (DBAT's sxy)",
        "max_iterations = 100",
        "rtol = 1e-10",
        "atol = 1e-10",
        "",
    ]))
    return DbatProject(
        project_file=project_file,
        camera=camera,
        images=images,
        control=control,
        n_image_points=len(marks),
        n_points=len(control) + len(tie),
    )
