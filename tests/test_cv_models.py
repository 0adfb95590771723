"""The computer-vision set: COLMAP's camera models imported as jaxba models, OpenCV's
rational and thin-prism terms ("opencv_full"), pixel models without a pixel size, and the
export of calibrated cameras to OpenCV and COLMAP.

Blocks are simulated here in NumPy with OpenCV's and COLMAP's formulas written out again
(not jaxba's models); `cv2.projectPoints` checks the formulas and the exported cameras.
"""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._io import write_colmap_project

WIDTH, HEIGHT = 640, 480
NOISE_PX = 0.5  # image noise of the simulated blocks, and their image_sigma
TRUTH_SIGMAS = 4.0  # |estimate - truth| <= 4 σ of the estimate
SIGMA0_TOL = 0.15  # |σ̂0 - 1|; σ̂0's own σ is 1/√(2r) ≈ 0.03 at the blocks' redundancy r
CV2_ATOL_PX = 1e-9  # cv2.projectPoints against the model (float64 both)
EXACT_MISFIT_PX = 1e-8  # export of a camera that OpenCV's model holds exactly
OPENCV_TERMS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")

# COLMAP's model, its true parameters (COLMAP pixels), true terms COLMAP lacks, and a free
# list that replaces the importer's default (None: the default).
COLMAP_TRUTH = {
    "SIMPLE_PINHOLE": ("SIMPLE_PINHOLE", (500.0, 320.7, 240.2), {}, None),
    "PINHOLE": ("PINHOLE", (505.0, 498.0, 321.0, 239.5), {}, None),
    "SIMPLE_RADIAL": ("SIMPLE_RADIAL", (500.0, 320.7, 240.2, -0.12), {}, None),
    "RADIAL": ("RADIAL", (500.0, 320.7, 240.2, -0.12, 0.04), {}, None),
    "OPENCV": ("OPENCV", (505.0, 498.0, 321.0, 239.5, -0.12, 0.04, 1e-3, -8e-4), {}, None),
    # k1..k6 free together are one near-null direction short over a 65° field (the rational
    # terms nearly repeat k1..k3): the block estimates k1..k4 and keeps k5 = k6 = 0.
    "FULL_OPENCV": ("FULL_OPENCV", (505.0, 498.0, 321.0, 239.5, -0.12, 0.04, 1e-3, -8e-4,
                                    0.01, 0.05, 0.0, 0.0), {},
                    ("fx", "fy", "k1", "k2", "p1", "p2", "k3", "k4")),
    "OPENCV_FISHEYE": ("OPENCV_FISHEYE", (500.0, 502.0, 321.0, 239.5, 0.02, -0.01, 3e-3, -1e-3),
                       {}, None),
    # OpenCV's thin prism: an "opencv_full" camera (imported as FULL_OPENCV) with s1..s4 free
    "thin_prism": ("FULL_OPENCV", (505.0, 498.0, 321.0, 239.5, -0.12, 0.04, 1e-3, -8e-4, 0.01,
                                   0.0, 0.0, 0.0),
                   {"s1": 2e-3, "s2": -1e-3, "s3": -1.5e-3, "s4": 5e-4},
                   ("fx", "fy", "k1", "k2", "p1", "p2", "k3", "s1", "s2", "s3", "s4")),
}
COLMAP_NAMES = {  # COLMAP's parameter names ("f": one focal length)
    "SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"), "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}


def _opencv_distort(x, y, c):
    """OpenCV's distortion of normalised points with coefficients `c` (name -> value)."""
    k = {name: c.get(name, 0.0) for name in OPENCV_TERMS}
    r2 = x * x + y * y
    radial = ((1 + k["k1"] * r2 + k["k2"] * r2**2 + k["k3"] * r2**3)
              / (1 + k["k4"] * r2 + k["k5"] * r2**2 + k["k6"] * r2**3))
    xd = (x * radial + 2 * k["p1"] * x * y + k["p2"] * (r2 + 2 * x * x)
          + k["s1"] * r2 + k["s2"] * r2**2)
    yd = (y * radial + k["p1"] * (r2 + 2 * y * y) + 2 * k["p2"] * x * y
          + k["s3"] * r2 + k["s4"] * r2**2)
    return xd, yd


def _colmap_pixels(model, values, p_cv):
    """COLMAP's projection (COLMAP pixels) of points (n, 3) in its camera frame (z forward);
    `values`: COLMAP's parameters by name plus any thin-prism terms."""
    v = dict(values)
    if "f" in v:
        v["fx"] = v["fy"] = v["f"]
    x, y = p_cv[:, 0] / p_cv[:, 2], p_cv[:, 1] / p_cv[:, 2]
    if model == "OPENCV_FISHEYE":
        r = np.hypot(x, y)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (v["k1"] + t2 * (v["k2"] + t2 * (v["k3"] + t2 * v["k4"]))))
        xd, yd = theta_d / r * x, theta_d / r * y
    else:
        xd, yd = _opencv_distort(x, y, v)
    return np.c_[v["fx"] * xd + v["cx"], v["fy"] * yd + v["cy"]]


def _rotation_to_quaternion(m):
    rvec = cv2.Rodrigues(m)[0][:, 0]
    angle = np.linalg.norm(rvec)
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * rvec / angle]


def _write_colmap_block(directory, cameras, rng, images_per_camera=5, n_points=70):
    """A COLMAP text model: points in a 4 m cube seen from a ring 4.5 m from its centre by
    `images_per_camera` images of each of `cameras` (id -> (COLMAP model, true values by
    name)), interleaved round the ring and rolled differently; noisy pixels (NOISE_PX). Which
    points an image sees is decided by a fixed pinhole, the same for every model.
    cameras.txt starts the focal length(s) 2 % off and the distortion at half its truth;
    points start 2 cm off; the poses are true."""
    directory.mkdir(parents=True, exist_ok=True)
    points = rng.uniform(-2.0, 2.0, (n_points, 3))
    lines = []
    for camera_id, (model, values) in cameras.items():
        start = [values[n] * (1.02 if n in ("f", "fx", "fy") else 1.0 if n in ("cx", "cy")
                              else 0.5) for n in COLMAP_NAMES[model]]
        lines.append(f"{camera_id} {model} {WIDTH} {HEIGHT} " + " ".join(map(repr, start)))
    (directory / "cameras.txt").write_text("\n".join(lines) + "\n")
    image_lines, tracks = [], {j: [] for j in range(n_points)}
    n_images = images_per_camera * len(cameras)
    for k in range(n_images):
        camera_id = list(cameras)[k % len(cameras)]
        model, values = cameras[camera_id]
        angle = 2 * np.pi * k / n_images
        centre = np.array([4.5 * np.cos(angle), 4.5 * np.sin(angle), 1.0 + 0.3 * np.sin(3 * k)])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        roll = 0.6 * np.sin(2.0 * k)
        down = np.cross(forward, right)
        right, down = (np.cos(roll) * right + np.sin(roll) * down,
                       -np.sin(roll) * right + np.cos(roll) * down)
        rotation = np.stack([right, down, forward])  # rows: the camera's x, y (down), z
        t = -rotation @ centre
        p_cv = points @ rotation.T + t
        pinhole = 500.0 * p_cv[:, :2] / p_cv[:, 2:] + [320.0, 240.0]
        seen = np.all((pinhole > 5) & (pinhole < [WIDTH - 5, HEIGHT - 5]), axis=1)
        uv = _colmap_pixels(model, values, p_cv) + rng.normal(0.0, NOISE_PX, (n_points, 2))
        entries = []
        for j in np.flatnonzero(seen):
            tracks[j].append((k + 1, len(entries)))
            entries.append((uv[j, 0], uv[j, 1], j + 1))
        pose = " ".join(map(repr, np.r_[_rotation_to_quaternion(rotation), t].tolist()))
        image_lines += [f"{k + 1} {pose} {camera_id} img{k}",
                        " ".join(f"{float(u)!r} {float(v)!r} {pid}" for u, v, pid in entries)]
    (directory / "images.txt").write_text("\n".join(image_lines) + "\n")
    start_points = points + rng.normal(0.0, 0.02, points.shape)
    (directory / "points3D.txt").write_text("".join(
        f"{j + 1} " + " ".join(map(repr, start_points[j].tolist())) + " 0 0 0 0.5 "
        + " ".join(f"{i} {idx}" for i, idx in tracks[j]) + "\n"
        for j in range(n_points) if len(tracks[j]) >= 2))


def _true_values(case):
    model, params, extra, _ = COLMAP_TRUTH[case]
    return model, dict(zip(COLMAP_NAMES[model], params)) | extra


@pytest.fixture(scope="module")
def colmap_block(tmp_path_factory):
    """One block of all COLMAP_TRUTH cases, one camera each (ids 1, 2, ...), adjusted."""
    directory = tmp_path_factory.mktemp("colmap_block")
    cameras = {str(k): _true_values(case) for k, case in enumerate(COLMAP_TRUTH, start=1)}
    _write_colmap_block(directory / "colmap", cameras, np.random.default_rng(40))
    free = {str(k): truth[3] for k, truth in enumerate(COLMAP_TRUTH.values(), start=1)
            if truth[3] is not None}
    written = write_colmap_project(directory / "colmap", directory / "project",
                                   image_sigma=NOISE_PX, free=free)
    project = jaxba.build_project(jaxba.read_project(written.project_file))
    return project, jaxba.adjust_project(project)


def test_colmap_block_fits_its_noise(colmap_block):
    _, result = colmap_block
    assert result.converged, result.message
    assert abs(result.sigma0 - 1) < SIGMA0_TOL


@pytest.mark.parametrize("case", list(COLMAP_TRUTH))
def test_colmap_model_recovers_its_truth(colmap_block, case):
    project, result = colmap_block
    model, values = _true_values(case)
    free = COLMAP_TRUTH[case][3]
    camera_id = str(list(COLMAP_TRUTH).index(case) + 1)
    jaxba_model, row = project.camera_rows[camera_id]
    assert jaxba_model == {"OPENCV_FISHEYE": "fisheye", "FULL_OPENCV": "opencv_full"}.get(
        model, "opencv")
    names = jaxba.CAMERA_MODELS[jaxba_model].parameter_names
    estimate = dict(zip(names, np.asarray(result.parameters.cameras[jaxba_model][row])))
    std = dict(zip(names, np.asarray(result.precision.std.cameras[jaxba_model][row])))
    truth = dict.fromkeys(names, 0.0) | values
    if "f" in values:  # COLMAP's one focal length: fy tied to fx
        truth["fx"] = truth["fy"] = values["f"]
        assert estimate["fy"] == estimate["fx"] and std["fy"] == std["fx"]
    truth["cx"], truth["cy"] = values["cx"] - 0.5, values["cy"] - 0.5  # COLMAP's pixel origin
    expected = free or [n for n in COLMAP_NAMES[model] if n not in ("cx", "cy")]
    assert {n for n in names if std[n] > 0} == {
        n for f in expected for n in (("fx", "fy") if f == "f" else (f,))}
    for name in names:
        if std[name] > 0:
            assert abs(estimate[name] - truth[name]) <= TRUTH_SIGMAS * std[name], name
        else:  # fixed: COLMAP's principal point, 0 for the terms the COLMAP model lacks
            assert estimate[name] == pytest.approx(truth[name] if name in ("cx", "cy") else 0.0)


def test_opencv_full_matches_cv2_project_points():
    rng = np.random.default_rng(41)
    p_cv = np.c_[rng.uniform(-0.7, 0.7, (80, 2)), np.ones(80)] * rng.uniform(1, 5, (80, 1))
    coefficients = dict(zip(OPENCV_TERMS, (-0.2, 0.05, 1e-3, -2e-3, 0.01, 0.1, -0.02, 5e-3,
                                           1e-3, -5e-4, 2e-3, 1e-4)))
    values = {"fx": 800.0, "fy": 790.0, "cx": 320.0, "cy": 240.0, "skew": 0.0} | coefficients
    camera = jaxba.OpenCVFullCamera(**{n: jnp.asarray(v) for n, v in values.items()})
    p_camera = jnp.asarray(p_cv * [1.0, -1.0, -1.0])
    # one compiled projection (op by op: ~20 small programs)
    ours = jax.jit(jax.vmap(lambda c, p: c.image_point(p, jnp.zeros(2), 0.0), (None, 0)))(
        camera, p_camera)
    k = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
    theirs, _ = cv2.projectPoints(p_cv[:, None], np.zeros(3), np.zeros(3), k,
                                  np.array([coefficients[n] for n in OPENCV_TERMS]))
    np.testing.assert_allclose(ours, theirs[:, 0], rtol=0, atol=CV2_ATOL_PX)
    # and the NumPy formulas of this file are OpenCV's too
    np.testing.assert_allclose(_colmap_pixels("FULL_OPENCV", values, p_cv), theirs[:, 0],
                               rtol=0, atol=CV2_ATOL_PX)


# --- export ------------------------------------------------------------------------------------

GRID = jaxba.PixelGrid((0.006, 0.006), (1200, 800))
SMAC = {"xp": 0.05, "yp": -0.03, "c": 8.0, "K1": 2e-4, "K2": -3e-7, "P1": 5e-6, "P2": -3e-6}
METROLOGY = {"xh": 0.05, "yh": -0.03, "c": 8.0, "A1": -2e-4, "A2": 3e-7, "A3": -1e-9,
             "B1": 5e-6, "B2": -3e-6}
R0 = 2.0  # mm


def _camera(cls, values, **constants):
    names = cls.parameter_names
    return cls.from_parameters(jnp.array([values.get(n, 0.0) for n in names]), **constants)


def _grid_pixels(step=50):
    cols, rows = np.meshgrid(np.arange(0.0, 1200.0, step), np.arange(0.0, 800.0, step))
    return np.c_[cols.ravel(), rows.ravel()]


def _to_mm(pixels):
    return np.c_[(pixels[:, 0] - 599.5) * 0.006, (399.5 - pixels[:, 1]) * 0.006]


def _cv2_pixels(export, p_cv):
    pixels, _ = cv2.projectPoints(p_cv[:, None], np.zeros(3), np.zeros(3),
                                  export.camera_matrix, export.distortion)
    return pixels[:, 0]


def test_metrology_camera_exports_exactly():
    """The metrology model distorts forward: with C1 = C2 = 0 it is OpenCV's k1 k2 k3 p1 p2
    up to scale, so the fit is exact; cv2 projects its rays onto its pixels."""
    export = jaxba.fit_opencv(_camera(jaxba.MetrologyCamera, METROLOGY, r0=R0), GRID.sensor,
                              GRID)
    assert export.model == "opencv" and export.distortion.shape == (5,)
    assert export.max_misfit_px < EXACT_MISFIT_PX
    # the metrology projection in NumPy: ideal (x', y') = -c (U, V)/W -> distorted, mm
    rng = np.random.default_rng(42)
    p_cv = np.c_[rng.uniform(-0.4, 0.4, (50, 2)), np.ones(50)]
    v = METROLOGY
    x, y = v["c"] * p_cv[:, 0], -v["c"] * p_cv[:, 1]
    r2 = x * x + y * y
    d = v["A1"] * (r2 - R0**2) + v["A2"] * (r2**2 - R0**4) + v["A3"] * (r2**3 - R0**6)
    xd = v["xh"] + x + x * d + v["B1"] * (r2 + 2 * x * x) + 2 * v["B2"] * x * y
    yd = v["yh"] + y + y * d + v["B2"] * (r2 + 2 * y * y) + 2 * v["B1"] * x * y
    pixels = np.c_[xd / 0.006 + 599.5, 399.5 - yd / 0.006]
    np.testing.assert_allclose(_cv2_pixels(export, p_cv), pixels, rtol=0, atol=1e-6)


@pytest.mark.parametrize("coefficients", [4, 5, 8])
def test_smac_camera_exports_within_its_misfit(coefficients):
    """SMAC corrects the measured point (x̄ - Δ(x̄) = -c (U, V)/W): OpenCV's forward model
    holds it nearly, and cv2 projects each pixel's ray within the reported misfit."""
    export = jaxba.fit_opencv(_camera(jaxba.SmacCamera, SMAC), GRID.sensor, GRID,
                              coefficients=coefficients)
    assert export.distortion.shape == (coefficients,)
    assert export.max_misfit_px < 0.01
    assert export.rms_misfit_px <= export.max_misfit_px
    pixels = _grid_pixels()
    reduced = _to_mm(pixels) - [SMAC["xp"], SMAC["yp"]]
    x, y = reduced.T
    r2 = x * x + y * y
    radial = SMAC["K1"] * r2 + SMAC["K2"] * r2**2
    ideal = np.c_[x - x * radial - SMAC["P1"] * (r2 + 2 * x * x) - 2 * SMAC["P2"] * x * y,
                  y - y * radial - 2 * SMAC["P1"] * x * y - SMAC["P2"] * (r2 + 2 * y * y)]
    p_cv = np.c_[ideal[:, 0] / SMAC["c"], -ideal[:, 1] / SMAC["c"], np.ones(len(ideal))]
    misfit = np.hypot(*(_cv2_pixels(export, p_cv) - pixels).T)
    assert misfit.max() <= export.max_misfit_px * (1 + 1e-6)
    line = export.colmap_line(7).split()
    assert line[:4] == ["7", {4: "OPENCV", 5: "FULL_OPENCV", 8: "FULL_OPENCV"}[coefficients],
                        "1200", "800"]
    assert float(line[6]) == pytest.approx(export.values["cx"] + 0.5)  # COLMAP's pixel origin


def test_export_refuses_what_it_cannot_map():
    with pytest.raises(ValueError, match="coefficients"):
        jaxba.fit_opencv(_camera(jaxba.SmacCamera, SMAC), GRID.sensor, GRID, coefficients=6)
    with pytest.raises(ValueError, match="bal"):
        jaxba.fit_opencv(_camera(jaxba.BalCamera, {"f": 500.0}), (640, 480))
    with pytest.raises(ValueError, match="pixel_grid"):
        jaxba.fit_opencv(_camera(jaxba.SmacCamera, SMAC), GRID.sensor)
    # r0 as in test_metrology_camera_exports_exactly: the same compiled ray tracing
    folding = _camera(jaxba.MetrologyCamera, METROLOGY | {"A1": -0.05}, r0=R0)
    with pytest.raises(ValueError, match="folds"):
        jaxba.fit_opencv(folding, GRID.sensor, GRID)


def test_pixel_models_need_no_pixel_size_and_pixels_means_pixel(colmap_block):
    project, _ = colmap_block
    folder = project.spec.path.parent
    assert "pixel_size" not in (folder / "cameras.toml").read_text()
    assert all(camera.pixel_size is None for camera in project.spec.cameras.values())
    text = project.spec.path.read_text()
    renamed = folder / "pixels.toml"
    renamed.write_text(text.replace('image_units = "pixel"', 'image_units = "pixels"'))
    assert jaxba.read_project(renamed).image_units == "pixel"
    with (folder / "cameras.toml").open("a") as cameras:  # a mm camera still needs one
        cameras.write('\n[99]\nmodel = "smac"\nc = 8.0\nsensor = [640, 480]\n')
    with pytest.raises(jaxba.ProjectError, match=r"\[99\] pixel_size: missing.*'smac' needs"):
        jaxba.read_project(renamed)


def test_pixel_model_table_matches_the_models():
    """The jax-free table that lets pixel models go without pixel_size is the models' own."""
    from jaxba._models._cameras._names import PIXEL_MODELS

    assert PIXEL_MODELS == {name for name, model in jaxba.CAMERA_MODELS.items()
                            if model.image_units == "pixel"}
