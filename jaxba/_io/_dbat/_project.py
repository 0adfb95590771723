"""DBAT script projects (Börlin & Grussenmeyer's Damped Bundle Adjustment Toolbox) for jaxba.

`write_dbat_project` turns a DBAT XML script (`_script.py`) into a project
(docs/project-files.md) with one "photomodeler" camera (DBAT's lens model 3,
`PhotoModelerCamera`). Mark points are written in jaxba pixels: DBAT's - 0.5 px (DBAT's origin
is the top-left *corner* of the image, jaxba's the centre of the top-left pixel; docs/dbat.md).

Starting values: the IO of `set_initial_values` (DBAT's default: c = focal, principal point at
the sensor centre, no distortion; or the camera's loaded values). EOPs from `<prior_eo>` where
given; else, as DBAT's `spatial_resection`, a planar resection from 4 or more coplanar control
points the image sees; else none (`-`): `jaxba adjust` computes them (resection from control
that is not coplanar, relative orientation without control). Tie points by intersection of
the rays of the images with EOPs (DBAT's `forward_intersection`); a point with fewer than two
such rays is left out, and jaxba computes it. Plain NumPy; nothing here calls jax.
"""

import dataclasses
import json
import os
import pathlib
from collections.abc import Sequence

import numpy as np

from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from .._project._project_file import project_toml
from ._camera import DbatCamera, read_cameras
from ._geometry import intersect, planar_resection
from ._script import DbatScript, read_script
from ._tables import ControlPoint, read_control_points

MODEL = "photomodeler"
CAMERA_PARAMETERS = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect", "skew")
PIXEL_ORIGIN_SHIFT = -0.5  # DBAT/PhotoModeler pixel (corner origin) -> jaxba pixel (centre origin)
_EOP_COLUMNS = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


@dataclasses.dataclass(frozen=True)
class DbatProject:
    """What `write_dbat_project` wrote.

    `images`: image_id -> starting (X0, Y0, Z0) in object units and (omega, phi, kappa) in
    degrees as written (images left to jaxba, `-`, are absent); `control`, `check`: the
    control and check points (check points are written as free points, their given
    coordinates the approximations); `n_image_points`: measurements written (each two
    observations); `n_points`: points written.
    """

    project_file: pathlib.Path
    camera: DbatCamera
    images: dict[str, tuple[float, ...]]
    control: dict[str, ControlPoint]
    n_image_points: int
    n_points: int
    check: dict[str, ControlPoint] = dataclasses.field(default_factory=dict)


def jaxba_pixels(col: float, row: float) -> tuple[float, float]:
    """DBAT pixel (corner origin) -> jaxba pixel (centre of the top-left pixel), (col, row)."""
    return col + PIXEL_ORIGIN_SHIFT, row + PIXEL_ORIGIN_SHIFT


def _image_mm(camera: DbatCamera, pixels: np.ndarray) -> np.ndarray:
    """DBAT pixels (n, 2) -> jaxba image mm (sensor centre, y up), like `PixelGrid`."""
    (width, height), (ps_x, ps_y) = camera.image_size, camera.pixel_size
    return np.c_[(pixels[:, 0] - width / 2) * ps_x, (height / 2 - pixels[:, 1]) * ps_y]


def _numbers(value, count: int, what: str, where: str) -> list[float]:
    try:
        values = [float(v) for v in str(value).split(",")]
    except ValueError:
        values = []
    if len(values) != count:
        raise ValueError(f"{where}: <set_initial_values><io><{what}>: expected {count} numbers,"
                         f" default or loaded, got {value!r}")
    return values


def initial_camera(camera: DbatCamera, io_initial: dict[str, object], where: str = "script"
                   ) -> dict[str, float]:
    """jaxba's starting values of the "photomodeler" parameters: per IO field of
    `set_initial_values` "default" (c = focal, principal point at the sensor centre, the rest
    0), "loaded" (the camera's) or given numbers; a field not named: loaded where the camera
    gives it, else default."""
    loaded = {"cc": camera.cc, "pp": camera.pp, "K": camera.k or None, "P": camera.p or None,
              "aspect": camera.aspect, "skew": camera.skew}
    values = {"c": camera.focal}
    for field, given in loaded.items():
        choice = io_initial.get(field, "loaded" if given is not None else "default")
        if choice == "default":
            continue
        if choice == "loaded":
            if given is None:
                raise ValueError(f"{where}: <set_initial_values><io><{field}>: loaded, but the"
                                 f" camera has no <{field}>")
            value = given
        else:
            count = {"pp": 2, "K": camera.n_k, "P": camera.n_p}.get(field, 1)
            value = _numbers(choice, count, field, where)
            value = value if field in ("pp", "K", "P") else value[0]
        if field == "cc":
            values["c"] = float(value)
        elif field == "pp":
            values["xp"], values["yp"] = camera.principal_point_from_dbat(*value)
        elif field in ("K", "P"):
            values.update({f"{field}{k + 1}": float(v) for k, v in enumerate(value)})
        elif field == "aspect":
            values["aspect"] = 1.0 - float(value)  # DBAT's <aspect> is 1 - as (docs/dbat.md)
        else:
            values["skew"] = float(value)
    return values


def _free_parameters(camera: DbatCamera, io_free: dict[str, bool]) -> list[str]:
    """The estimated IO parameters in jaxba's order; K and P beyond nK, nP stay fixed at 0."""
    absent = {f"K{k}" for k in range(camera.n_k + 1, 4)} | {f"P{k}" for k in
                                                           range(camera.n_p + 1, 3)}
    return [p for p in CAMERA_PARAMETERS if io_free.get(p, False) and p not in absent]


def _sigma_text(value: float, estimate: str) -> str:
    """A σ column entry from DBAT's prior σ (0: none) and its estimate flag."""
    if estimate == "false" or (estimate == "default" and value == 0):
        return "0"
    if estimate == "default" or value:
        return repr(float(value))
    return "-"


def _write_table(path: pathlib.Path, header: Sequence[str], rows: list[list[str]]) -> None:
    lines = [f"# {line}" for line in header] + [" ".join(row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


def _relative(path: pathlib.Path, start: pathlib.Path) -> str:
    return pathlib.Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()


def _starting_poses(script: DbatScript, camera: DbatCamera, initial: dict[str, float],
                    control: dict[str, ControlPoint]) -> dict[str, tuple]:
    """DBAT image id -> (rotation M, station X0, how) for the images it can orient."""
    by_image: dict[str, list] = {}
    for mark in script.marks:
        by_image.setdefault(mark.image, []).append(mark)
    principal = np.array([initial.get("xp", 0.0), initial.get("yp", 0.0)])
    poses = {}
    for image, measured in by_image.items():
        prior = script.prior_eo.get(image)
        if prior is not None and prior.angles is None:
            raise ValueError(f"{script.path.name}: <prior_eo>: image {image} has no omega,"
                             " phi, kappa; a prior EO without angles is not supported")
        if prior is not None:
            m = opk_to_matrix(np.radians(prior.angles))
            poses[image] = (m, np.array(prior.station), "prior EO")
            continue
        cps = [m for m in measured if m.point in control]
        if len(cps) < 4:
            continue
        xy = _image_mm(camera, np.array([[m.col, m.row] for m in cps])) - principal
        xyz = np.array([control[m.point].xyz for m in cps])
        try:
            rotation, station = planar_resection(xyz, xy, initial["c"])
        except ValueError:  # not coplanar: jaxba's resection does it
            continue
        poses[image] = (rotation, station, "planar resection")
    return poses


def _check_rays(script: DbatScript, control: dict) -> None:
    """DBAT's check_ray_count: every point but the control seen in `min_rays` images."""
    minimum = script.operations.min_rays
    if minimum is None:
        return
    rays: dict[str, int] = {}
    for mark in script.marks:
        rays[mark.point] = rays.get(mark.point, 0) + 1
    few = [f"{p} ({n})" for p, n in rays.items() if n < minimum and p not in control]
    if few:
        raise ValueError(f"{script.path.name}: check_ray_count (min_rays {minimum}): "
                         f"{len(few)} points have fewer rays: {', '.join(few[:10])}")


def write_dbat_project(
    script: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    project_file: str | os.PathLike | None = None,
    name: str = "dbat_camcal",
    camera_file: str | os.PathLike | None = None,
    control_file: str | os.PathLike | None = None,
) -> DbatProject:
    """Write a DBAT script project as a jaxba project (docs/project-files.md, docs/dbat.md).

    **Arguments:**

    - `script`: the DBAT XML script; its input block names the files read, its operations
      the starting values, the estimated parameters and the datum.
    - `out_dir`: where cameras.toml, orientation.txt, image_coordinates.txt and points.txt go.
    - `project_file`: the project TOML (default `out_dir/NAME.toml`); its paths are written
      relative to its folder.
    - `name`: the project name.
    - `camera_file`: a DBAT camera file (relative to the script's folder) whose camera must
      agree with the script's (sensor, image size, focal length); None: no check.
    - `control_file`: a DBAT control point file instead of the script's (e.g.
      reference/camcal-weighted.txt), `id,label,x,y,z` or `id,label,x,y,z,sxyz`.

    One "photomodeler" camera; image points in jaxba pixels (DBAT's - 0.5) with their σ per
    coordinate; control points fixed (σ 0) or weighted per coordinate, check points free;
    starting values as the module docstring says. Raises `ValueError` naming the file and the
    element or line of anything it cannot read or does not support.
    """
    script = read_script(script)
    where = script.path.name
    out_dir = pathlib.Path(out_dir)
    project_file = pathlib.Path(project_file) if project_file else out_dir / f"{name}.toml"
    if len(script.cameras) != 1:
        raise ValueError(f"{where}: <cameras>: one camera is supported, got "
                         f"{len(script.cameras)}")
    camera = script.cameras[0]
    if camera_file is not None:
        prior = read_cameras(script.path.parent / camera_file)[0]
        if (prior.sensor_height, prior.image_size, prior.focal) != (
            camera.sensor_height, camera.image_size, camera.focal
        ):
            raise ValueError(f"{camera_file}: camera differs from the one in {where}")
    control, control_path = script.control, script.control_file
    if control_file is not None:
        control_path = script.path.parent / control_file
        fields = len(next(line for line in control_path.read_text("utf-8").splitlines()
                          if line.strip() and not line.lstrip().startswith("#")).split(","))
        control = read_control_points(
            control_path, "id,label,x,y,z,sxyz" if fields == 6 else "id,label,x,y,z")
    ops = script.operations
    unknown = sorted({m.image for m in script.marks} - set(script.images))
    if unknown:
        raise ValueError(f"{where}: <image_pts>: unknown images {unknown[:5]}")
    _check_rays(script, control)
    datum_image = ops.datum_image
    if datum_image is not None and control:
        raise ValueError(f"{where}: <set_datum> depend with control points: jaxba's dependent"
                         " datum uses no control; remove one of them")
    estimate_op = ops.op_estimate
    control_datum = any(s > 0 or e != "true" for p in control.values()
                        for s, e in zip(p.sigma, estimate_op))
    eo_datum = any(s > 0 or e != "true" for eo in script.prior_eo.values()
                   for s, e in zip(eo.sigma, ops.eo_estimate))
    if datum_image is None and not (control_datum or eo_datum):
        raise ValueError(f"{where}: no control points, no fixed or weighted prior EO and no "
                         '<set_datum ref_cam="1">depend</set_datum>: the datum is undefined')
    initial = initial_camera(camera, ops.io_initial, where)
    free = _free_parameters(camera, ops.io_free)

    poses = _starting_poses(script, camera, initial, control)
    principal = np.array([initial.get("xp", 0.0), initial.get("yp", 0.0)])
    rays: dict[str, list] = {}
    for mark in script.marks:
        if mark.point in control or mark.image not in poses:
            continue
        rotation, station, _ = poses[mark.image]
        x, y = _image_mm(camera, np.array([[mark.col, mark.row]]))[0] - principal
        rays.setdefault(mark.point, []).append((station, rotation.T @ np.array(
            [x, y, -initial["c"]])))
    tie = {p: intersect(*(np.array(v) for v in zip(*r))) for p, r in rays.items()
           if len(r) >= 2 and p not in script.check}

    out_dir.mkdir(parents=True, exist_ok=True)
    project_file.parent.mkdir(parents=True, exist_ok=True)
    images, rows, methods = {}, [], set()
    weighted_eo = any(e != "true" for e in ops.eo_estimate) or any(
        any(p.sigma) for p in script.prior_eo.values())
    measured = {m.image for m in script.marks}
    for dbat_id, image_id in script.images.items():
        if dbat_id not in measured:
            continue
        prior = script.prior_eo.get(dbat_id)
        if dbat_id in poses:
            rotation, station, how = poses[dbat_id]
            methods.add(how)
            if how == "prior EO":
                eop = (*station, *prior.angles)
            else:
                eop = (*np.round(station, 6), *np.round(np.degrees(matrix_to_opk(rotation)), 6))
            images[image_id] = tuple(float(v) for v in eop)
            row = [image_id, "C1", *(repr(float(v)) if how == "prior EO" else f"{v:.6f}"
                                     for v in eop)]
        else:
            methods.add("none (computed by jaxba adjust)")
            row = [image_id, "C1", *["-"] * 6]
        if weighted_eo and datum_image is None:
            sigma = prior.sigma if prior is not None else (0.0,) * 6
            if dbat_id not in poses and any(e != "true" for e in ops.eo_estimate):
                raise ValueError(f"{where}: image {dbat_id}: no <prior_eo> to fix or weight")
            row += [_sigma_text(s, e) for s, e in zip(sigma, ops.eo_estimate)]
        rows.append(row)
    header = "image_id camera_id X0 Y0 Z0 (m) omega phi kappa (deg)" + (
        " sX0 sY0 sZ0 somega sphi skappa" if weighted_eo and datum_image is None else "")
    _write_table(out_dir / "orientation.txt", [
        f"{header}; image ids: the labels or file stems of DBAT's {script.images_file.name}",
        "starting values: " + {"planar resection": "planar resection from the control points,"
                               f" c = {initial['c']:g}, no distortion"}.get(
            ", ".join(sorted(methods)), ", ".join(sorted(methods))),
    ], rows)

    rows = []
    for pid, point in control.items():
        sigma = [_sigma_text(s, e) for s, e in zip(point.sigma, estimate_op)]
        rows.append([pid, *(repr(v) for v in point.xyz), *sigma])
    for pid, point in script.check.items():
        rows.append([pid, *(repr(v) for v in point.xyz), "-", "-", "-"])
    for pid in sorted(tie, key=lambda p: (len(p), p)):
        rows.append([pid, *(f"{v:.6f}" for v in tie[pid]), "-", "-", "-"])
    labels = ", ".join(f"{p.id} {p.label}" for p in control.values() if p.label)
    comments = ["point_id X Y Z (m) sX sY sZ (0 fixed, - free)"]
    if control:
        comments.append(f"control: {control_path.name}" + (f" (labels: {labels})" if labels
                                                           else "")
                        + "; tie points: starting values by intersection")
    if script.check:
        comments.append(f"check points (free, given coordinates as approximations): "
                        f"{', '.join(script.check)}")
    _write_table(out_dir / "points.txt", comments, rows)

    rows = []
    for mark in script.marks:
        col, row = jaxba_pixels(mark.col, mark.row)
        sx, sy = (repr(s) for s in mark.sigma)
        rows.append([script.images[mark.image], mark.point, repr(col), repr(row), sx, sy])
    _write_table(out_dir / "image_coordinates.txt", [
        "image_id point_id col row sx sy (pixel; origin at the centre of the top-left pixel,",
        f"i.e. DBAT's {', '.join(p.name for p in script.mark_files)} - 0.5 px; sx, sy: DBAT's"
        " sxy or sx, sy)",
    ], rows)

    (ps_x, ps_y), (width, height) = camera.pixel_size, camera.image_size
    sensor = (f"{camera.sensor_height} mm / {height} px, square (DBAT's sensor 'auto')"
              if camera.sensor_width is None else
              f"{camera.sensor_width} x {camera.sensor_height} mm / {width} x {height} px")
    lines = [
        f"# {camera.name}: DBAT camera {camera.id}, lens model {camera.lens_model} (backward).",
        f"# Pixel size {sensor}.",
        "# Principal point: DBAT's = (xp + W/2 ps_x, H/2 ps_y - yp) (docs/dbat.md).",
        "[C1]",
        f'model = "{MODEL}"',
        f"pixel_size = [{ps_x!r}, {ps_y!r}]",
        f"sensor = [{width}, {height}]",
        *(f"{p} = {float(initial.get(p, 0.0))!r}" for p in CAMERA_PARAMETERS),
        f"free = {json.dumps(free)}",
    ]
    (out_dir / "cameras.toml").write_text("\n".join(lines) + "\n")

    base = project_file.parent
    sigmas = [s for m in script.marks for s in m.sigma]
    default_sigma = max(set(sigmas), key=sigmas.count)
    datum = {}
    if datum_image is not None:
        datum = {"datum": "dependent", "datum_image": script.images[datum_image]}
    files = {"cameras": "cameras.toml", "images": "orientation.txt",
             "image_points": "image_coordinates.txt", "points": "points.txt"}
    project_file.write_text(project_toml(
        name, "pixel", {key: _relative(out_dir / file, base) for key, file in files.items()},
        {"sigma0": 1.0, "image_sigma": default_sigma, "max_iterations": 100, "rtol": 1e-10,
         "atol": 1e-10, **datum},
        comment=[f"DBAT script {where} (Börlin & Grussenmeyer, DBAT), imported by jaxba."],
        notes={"image_sigma": "pixel, per coordinate (DBAT's sxy)",
               "datum_image": "DBAT's ref_cam"}), encoding="utf-8")
    return DbatProject(
        project_file=project_file,
        camera=camera,
        images=images,
        control=control,
        n_image_points=len(script.marks),
        n_points=len(control) + len(script.check) + len(tie),
        check=script.check,
    )
