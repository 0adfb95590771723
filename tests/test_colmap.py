"""COLMAP text models in and out of jaxba projects, and cameras as OpenCV YAML.

The synthetic COLMAP model is written here by hand from NumPy projections in COLMAP's own
conventions (world-to-camera (q, t), +z forward, pixel centre (0.5, 0.5)); the imported project
must reproduce its pixels through jaxba's models with zero residual.
"""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._io import (
    read_colmap_model,
    write_colmap,
    write_colmap_model,
    write_colmap_project,
    write_opencv_yaml,
    write_project_camera_yaml,
)
from jaxba._io._colmap import camera_to_colmap, colmap_pose_to_eop, eop_to_colmap_pose

RESIDUAL_ATOL_PX = 1e-9  # imported project at its starting values: exact up to rounding
ROUND_TRIP_RTOL = 1e-12  # values through COLMAP text and back (repr, ±0.5 px, opk <-> q)
POSE_ATOL = 1e-12  # quaternions and rotation matrices through opk and back
POSITION_ATOL = 1e-11  # stations, translations and points (object units, |X| ~ 10)
CAMERAS = {  # COLMAP's parameters, COLMAP pixels
    1: ("OPENCV", 1000, 750, (820.0, 815.0, 501.3, 372.9, -0.12, 0.05, 1e-3, -5e-4)),
    2: ("OPENCV_FISHEYE", 1024, 768, (300.0, 302.0, 511.6, 383.2, 0.03, -0.01, 2e-3, -4e-4)),
    3: ("SIMPLE_RADIAL", 800, 600, (700.0, 400.5, 300.5, -0.08)),
}


def _distort_opencv(x, y, k1=0.0, k2=0.0, p1=0.0, p2=0.0):
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def _colmap_pixels(model, params, p_cam):
    """COLMAP's projection of camera-frame points (n, 3) (z forward) to COLMAP pixels."""
    x, y = p_cam[:, 0] / p_cam[:, 2], p_cam[:, 1] / p_cam[:, 2]
    if model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = params
        xd, yd = _distort_opencv(x, y, k1, k2, p1, p2)
    elif model == "SIMPLE_RADIAL":
        f, cx, cy, k = params
        fx = fy = f
        xd, yd = _distort_opencv(x, y, k)
    else:  # OPENCV_FISHEYE
        fx, fy, cx, cy, k1, k2, k3, k4 = params
        r = np.hypot(x, y)
        theta = np.arctan(r)
        theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
        xd, yd = theta_d / r * x, theta_d / r * y
    return np.c_[fx * xd + cx, fy * yd + cy]


def _write_scene(directory, rng, n_images=6, n_points=40):
    """A COLMAP text model of points round the origin seen by cameras 8-10 m away.

    Returns {image name: (q, t)} as written. Every image also has two untriangulated points.
    """
    directory.mkdir(parents=True, exist_ok=True)
    points = rng.uniform(-2.0, 2.0, (n_points, 3))
    (directory / "cameras.txt").write_text("# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n" + "".join(
        f"{cid} {model} {w} {h} " + " ".join(map(repr, params)) + "\n"
        for cid, (model, w, h, params) in CAMERAS.items()))
    image_lines, tracks, poses = [], {j: [] for j in range(n_points)}, {}
    for k in range(n_images):
        camera_id = 1 + k % 3
        model, width, height, params = CAMERAS[camera_id]
        angle = 2 * np.pi * k / n_images
        centre = np.array([9 * np.cos(angle), 9 * np.sin(angle), 3.0 + 0.3 * k])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        rotation = np.stack([right, np.cross(forward, right), forward])  # rows: x, y (down), z
        rvec = cv2.Rodrigues(rotation)[0][:, 0]
        theta = np.linalg.norm(rvec)
        q = np.r_[np.cos(theta / 2), np.sin(theta / 2) * rvec / theta]
        t = -rotation @ centre
        uv = _colmap_pixels(model, params, points @ rotation.T + t)
        inside = np.all((uv > 0) & (uv < [width, height]), axis=1)
        entries = [(0.25, 0.75, -1)]
        for j in np.flatnonzero(inside):
            tracks[j].append((k + 1, len(entries)))
            entries.append((uv[j, 0], uv[j, 1], 100 + j))
        entries.append((width - 1.0, 3.0, -1))
        name = f"img_{k:02d}.jpg"
        poses[name] = (q, t)
        pose = " ".join(map(repr, np.r_[q, t].tolist()))
        image_lines += [f"{k + 1} {pose} {camera_id} {name}",
                        " ".join(f"{float(u)!r} {float(v)!r} {pid}" for u, v, pid in entries)]
    (directory / "images.txt").write_text(
        "# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n"
        + "\n".join(image_lines) + "\n")
    (directory / "points3D.txt").write_text("# POINT3D_ID X Y Z R G B ERROR TRACK[]\n" + "".join(
        f"{100 + j} " + " ".join(map(repr, points[j].tolist())) + " 10 20 30 0.5 "
        + " ".join(f"{i} {idx}" for i, idx in tracks[j]) + "\n"
        for j in range(n_points) if len(tracks[j]) >= 2))
    return poses


@pytest.fixture
def scene(tmp_path):
    poses = _write_scene(tmp_path / "colmap", np.random.default_rng(30))
    written = write_colmap_project(tmp_path / "colmap", tmp_path / "project")
    return tmp_path, poses, written


def _project_values(project, parameters=None):
    """Comparable values of a project: cameras by id, EOPs (matrix, station) and points by id,
    image points by (image, point)."""
    parameters = project.problem.initial if parameters is None else parameters
    cameras = {cid: np.asarray(parameters.cameras[model][row])
               for cid, (model, row) in project.camera_rows.items()}
    eops = np.asarray(parameters.images)
    images = {iid: (np.asarray(jaxba.opk_to_matrix(jnp.asarray(eops[k, 3:]))), eops[k, :3])
              for k, iid in enumerate(project.image_ids)}
    points = dict(zip(project.point_ids, np.asarray(parameters.points)))
    observed = {(m.image, m.point): np.array(m.xy) for m in project.spec.image_points}
    return cameras, images, points, observed


def _assert_same_project_values(a, b):
    for one, other in zip(a[0::2], b[0::2]):  # cameras, points
        assert one.keys() == other.keys()
        for key in one:
            np.testing.assert_allclose(one[key], other[key], rtol=ROUND_TRIP_RTOL,
                                       atol=POSITION_ATOL, err_msg=key)
    for one, other in ((a[1], b[1]), (a[3], b[3])):  # images, image points
        assert one.keys() == other.keys()
    for key in a[1]:
        np.testing.assert_allclose(a[1][key][0], b[1][key][0], atol=POSE_ATOL, err_msg=key)
        np.testing.assert_allclose(a[1][key][1], b[1][key][1], atol=POSITION_ATOL)
    for key in a[3]:
        np.testing.assert_allclose(a[3][key], b[3][key], rtol=ROUND_TRIP_RTOL, err_msg=key)


def test_import_writes_the_conventions(scene):
    tmp_path, poses, written = scene
    assert (written.n_cameras, written.n_images) == (3, 6)
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    cameras = {cid: project.spec.cameras[cid] for cid in project.camera_rows}
    assert {c.model for c in cameras.values()} == {"opencv", "fisheye"}
    # COLMAP's principal point (pixel-corner origin) moves by -0.5 px; f -> fx = fy, fy tied.
    assert cameras["1"].values["cx"] == 501.3 - 0.5 and cameras["1"].values["cy"] == 372.9 - 0.5
    assert cameras["3"].values["fx"] == cameras["3"].values["fy"] == 700.0
    assert cameras["3"].values["k1"] == -0.08
    assert cameras["2"].values["k4"] == -4e-4
    assert cameras["3"].free == {"fx", "k1"} and cameras["3"].ties == {"fy": ("3", "fx")}
    assert cameras["1"].free == {"fx", "fy", "k1", "k2", "p1", "p2"} and not cameras["1"].ties
    # Untriangulated 2D points are dropped; the rest shift by -0.5 px.
    assert len(project.spec.image_points) == written.n_image_points
    first = read_colmap_model(tmp_path / "colmap").images[1].points2d[1]
    m = next(m for m in project.spec.image_points if m.image == "img_00.jpg")
    assert (m.point, m.xy) == (str(first[2]), (first[0] - 0.5, first[1] - 0.5))
    # Datum: first image fixed, one station coordinate of the second.
    assert all(s == 0 for s in project.spec.images["img_00.jpg"].eop_sigma)
    assert sum(s == 0 for s in project.spec.images["img_01.jpg"].eop_sigma) == 1


def test_imported_project_reproduces_colmap_pixels(scene):
    """Poses, pixel origin and camera models together: jaxba's residuals at the start are 0."""
    _, _, written = scene
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    residuals = project.problem.residuals(project.problem.initial)
    image_residuals = [np.asarray(r) for r, g in zip(residuals, project.problem.groups)
                       if isinstance(g, jaxba.ImagePoints)]
    assert sum(len(r) for r in image_residuals) == written.n_image_points
    assert max(np.abs(r).max() for r in image_residuals) < RESIDUAL_ATOL_PX


def test_pose_conversion_round_trip():
    rng = np.random.default_rng(31)
    for _ in range(20):
        q = rng.normal(size=4)
        q = q / np.linalg.norm(q) * np.sign(q[0])
        t = rng.normal(size=3) * 10
        q2, t2 = eop_to_colmap_pose(colmap_pose_to_eop(q, t))
        np.testing.assert_allclose(q2, q, atol=POSE_ATOL)
        np.testing.assert_allclose(t2, t, atol=POSITION_ATOL)


def test_colmap_text_round_trip_keeps_the_model(scene):
    tmp_path, poses, written = scene
    original = read_colmap_model(tmp_path / "colmap")
    write_colmap_model(original, tmp_path / "copy")
    assert read_colmap_model(tmp_path / "copy") == original


def test_export_then_import_gives_the_same_project(scene):
    tmp_path, poses, written = scene
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    exported = write_colmap(project, tmp_path / "exported")
    # Cameras go back to their COLMAP models and values (pixel origin restored).
    for cid, (model, width, height, params) in CAMERAS.items():
        camera = exported.cameras[cid]
        assert (camera.model, camera.width, camera.height) == (model, width, height)
        np.testing.assert_allclose(camera.params, params, rtol=ROUND_TRIP_RTOL)
    for image in exported.images.values():
        q, t = poses[image.name]
        np.testing.assert_allclose(image.qvec, q, atol=POSE_ATOL)
        np.testing.assert_allclose(image.tvec, t, atol=POSITION_ATOL)
    again = write_colmap_project(tmp_path / "exported", tmp_path / "again")
    reimported = jaxba.build_project(jaxba.read_project(again.project_file))
    _assert_same_project_values(_project_values(project), _project_values(reimported))


def test_adjusted_project_exports_its_adjusted_values(scene):
    tmp_path, _, written = scene
    # Perturb the image points: the adjustment then moves every free unknown.
    path = written.project_file.parent / "image_coordinates.txt"
    rng = np.random.default_rng(32)
    lines = []
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            lines.append(line)
            continue
        image, point, u, v = line.split()
        du, dv = rng.normal(0.0, 0.3, 2)
        lines.append(f"{image} {point} {float(u) + float(du)!r} {float(v) + float(dv)!r}")
    path.write_text("\n".join(lines) + "\n")
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    result = jaxba.adjust_project(project)
    assert result.converged, result.message
    assert 0.15 < result.sigma0 < 0.6  # σ = 1 px a priori, 0.3 px noise
    write_colmap(project, tmp_path / "adjusted", result.parameters)
    again = write_colmap_project(tmp_path / "adjusted", tmp_path / "again")
    reimported = jaxba.build_project(jaxba.read_project(again.project_file))
    # fy tied to fx: SIMPLE_RADIAL's one focal length stays one, and the model comes back.
    assert read_colmap_model(tmp_path / "adjusted").cameras[3].model == "SIMPLE_RADIAL"
    _assert_same_project_values(_project_values(project, result.parameters),
                                _project_values(reimported))


def test_export_refuses_what_colmap_cannot_hold():
    with pytest.raises(ValueError, match="skew"):
        camera_to_colmap("opencv", {"fx": 800.0, "fy": 800.0, "skew": 0.2})
    with pytest.raises(ValueError, match="no COLMAP equivalent"):
        camera_to_colmap("smac", {"c": 8.0})
    assert camera_to_colmap("opencv", {"fx": 8.0, "fy": 8.0, "cx": 1.5, "cy": 2.5}) == (
        "SIMPLE_PINHOLE", (8.0, 2.0, 3.0))
    assert camera_to_colmap("opencv", {"fx": 8.0, "fy": 9.0, "k1": 0.1, "k3": 0.01})[0] == (
        "FULL_OPENCV")


def test_import_names_bad_input(tmp_path):
    _write_scene(tmp_path, np.random.default_rng(33))
    text = (tmp_path / "cameras.txt").read_text()
    (tmp_path / "cameras.txt").write_text(text.replace("SIMPLE_RADIAL", "FOV"))
    with pytest.raises(ValueError, match=r"cameras.txt:4: unsupported camera model 'FOV'"):
        read_colmap_model(tmp_path)
    (tmp_path / "cameras.txt").write_text(
        text.replace("OPENCV ", "FULL_OPENCV "))
    with pytest.raises(ValueError, match=r"cameras.txt:2: FULL_OPENCV has 12 parameters, got 8"):
        read_colmap_model(tmp_path)


# --- OpenCV YAML -------------------------------------------------------------------------------


def _read_yaml(path):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        return (storage.getNode("camera_matrix").mat(),
                storage.getNode("distortion_coefficients").mat(),
                int(storage.getNode("image_width").real()),
                int(storage.getNode("image_height").real()),
                storage.getNode("camera_model").string())
    finally:
        storage.release()


def test_opencv_yaml_reads_back_with_cv2(tmp_path):
    values = {"fx": 832.4998, "fy": 832.5319, "cx": 303.9589, "cy": 206.5851,
              "skew": 0.2044986, "k1": -0.228601, "k2": 0.190354, "p1": 1e-17, "p2": -3e-5}
    write_opencv_yaml(tmp_path / "camera.yml", "opencv", values, (640, 480))
    k, d, width, height, model = _read_yaml(tmp_path / "camera.yml")
    np.testing.assert_array_equal(k, [[832.4998, 0.2044986, 303.9589], [0, 832.5319, 206.5851],
                                      [0, 0, 1]])
    np.testing.assert_array_equal(d, [[-0.228601, 0.190354, 1e-17, -3e-5, 0.0]])
    assert (width, height, model) == (640, 480, "opencv")


def test_project_camera_yaml_is_the_camera_and_drives_cv2_fisheye(scene):
    tmp_path, _, written = scene
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    model, row = project.camera_rows["2"]
    values = np.asarray(project.problem.initial.cameras[model][row])
    write_project_camera_yaml(project, "2", tmp_path / "fisheye.yaml")
    k, d, width, height, name = _read_yaml(tmp_path / "fisheye.yaml")
    fx, fy, cx, cy, *dist = values
    np.testing.assert_array_equal(k, [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(d[:, 0], dist)
    assert (width, height, name) == (1024, 768, "fisheye")
    # cv2.fisheye with the file's K and D projects as jaxba's fisheye model does.
    p_cv = np.array([[0.3, -0.2, 1.0], [-1.5, 0.8, 1.2], [0.01, 0.02, 3.0]])
    pixels, _ = cv2.fisheye.projectPoints(p_cv[:, None], np.zeros(3), np.zeros(3), k, d)
    camera = jaxba.CAMERA_MODELS["fisheye"].from_parameters(jnp.asarray(values))
    computed = jax.vmap(lambda p: camera.image_point(p, jnp.zeros(2), jnp.asarray(0.0)))(
        jnp.asarray(p_cv * [1.0, -1.0, -1.0]))
    np.testing.assert_allclose(np.asarray(computed), pixels[:, 0], rtol=1e-12)
