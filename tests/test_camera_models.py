"""The "bal" and "fisheye" camera models: formulas in NumPy, cv2.fisheye, finite differences,
and a synthetic fisheye block adjusted through cameras.toml (free, fixed and weighted IOPs)."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_ATOL, FD_RTOL, FORMULA_RTOL, assert_jacobian_matches_fd

import jaxba
from jaxba._io._synthetic import look_at, opk_from_rotation

BalCamera = jaxba.CAMERA_MODELS["bal"]
FisheyeCamera = jaxba.CAMERA_MODELS["fisheye"]
CV_FROM_CAMERA = np.diag([1.0, -1.0, -1.0])  # p_cv = F p_camera, and F = F⁻¹
CV2_RTOL = 1e-12  # cv2.fisheye.projectPoints (double precision) against the model
TRUTH_RTOL = 1e-8  # noise-free synthetic block: recovered parameters against the truth
FISHEYE_TRUTH = {"fx": 310.0, "fy": 305.0, "cx": 512.3, "cy": 380.7,
                 "k1": 0.05, "k2": -0.01, "k3": 0.004, "k4": -0.001}
SENSOR = (1024, 768)
# Differences of ~500 px values: rounding noise 1e-16 * 500 / 1e-6 ≈ 5e-8 in near-zero entries.
FD_ATOL_NEAR_AXIS = 1e-6
LINEAR_FD_STEP = 1e-2


def _project(model, values, p_camera):
    """`model.image_point` on (n, 3) points in the photogrammetric camera frame, vmapped."""
    camera = model.from_parameters(jnp.asarray(values))
    one = lambda p: camera.image_point(p, jnp.zeros(2), jnp.asarray(0.0))  # noqa: E731
    return np.asarray(jax.vmap(one)(jnp.asarray(p_camera)))


def _random_cv_points(rng, n=60, max_angle=1.3):
    """Points in the OpenCV frame (z forward) at angles up to `max_angle` rad off the axis."""
    theta = rng.uniform(0.0, max_angle, n)
    azimuth = rng.uniform(-np.pi, np.pi, n)
    depth = rng.uniform(0.5, 10.0, n)
    direction = np.c_[np.sin(theta) * np.cos(azimuth), np.sin(theta) * np.sin(azimuth),
                      np.cos(theta)]
    return direction * depth[:, None]


# --- fisheye ---------------------------------------------------------------------------------


def _fisheye_numpy(p_cv, iop):
    """OpenCV's fisheye projection (Kannala-Brandt), written out again: (n, 3) -> (n, 2) px."""
    fx, fy, cx, cy, k1, k2, k3, k4 = iop
    a, b = p_cv[:, 0] / p_cv[:, 2], p_cv[:, 1] / p_cv[:, 2]
    r = np.hypot(a, b)
    theta = np.arctan(r)
    theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    scale = np.where(r > 0, theta_d / np.where(r > 0, r, 1.0), 1.0)
    return np.c_[fx * scale * a + cx, fy * scale * b + cy]


def _random_fisheye_iop(rng):
    base = np.array(list(FISHEYE_TRUTH.values()))
    spread = np.array([30.0, 30.0, 20.0, 20.0, 0.05, 0.02, 0.01, 0.002])
    return base + spread * rng.uniform(-1.0, 1.0, 8)


def test_fisheye_matches_its_formulas():
    rng = np.random.default_rng(20)
    p_cv, iop = _random_cv_points(rng), _random_fisheye_iop(rng)
    np.testing.assert_allclose(_project(FisheyeCamera, iop, p_cv @ CV_FROM_CAMERA),
                               _fisheye_numpy(p_cv, iop), rtol=FORMULA_RTOL)


def test_fisheye_matches_cv2_fisheye_project_points():
    rng = np.random.default_rng(21)
    p_cv, iop = _random_cv_points(rng), _random_fisheye_iop(rng)
    fx, fy, cx, cy, *k = iop
    camera_matrix = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    pixels, _ = cv2.fisheye.projectPoints(
        p_cv[:, None, :], np.zeros(3), np.zeros(3), camera_matrix, np.array(k))
    np.testing.assert_allclose(_project(FisheyeCamera, iop, p_cv @ CV_FROM_CAMERA),
                               pixels[:, 0, :], rtol=CV2_RTOL)


def test_fisheye_on_the_axis_is_the_principal_point_with_finite_derivatives():
    iop = np.array(list(FISHEYE_TRUTH.values()))
    on_axis = np.array([0.0, 0.0, -2.0])  # photogrammetric frame: straight ahead
    np.testing.assert_array_equal(_project(FisheyeCamera, iop, on_axis[None])[0], iop[2:4])
    jacobian = jax.jacfwd(lambda p: FisheyeCamera.from_parameters(jnp.asarray(iop)).image_point(
        p, jnp.zeros(2), jnp.asarray(0.0)))(jnp.asarray(on_axis))
    # At the axis the model is the pinhole: d(u, v)/d(X, Y) = (fx, -fy) / 2 (Y up, depth 2).
    np.testing.assert_allclose(np.asarray(jacobian)[:, :2], np.diag([iop[0], -iop[1]]) / 2,
                               rtol=FORMULA_RTOL)
    assert_jacobian_matches_fd(
        lambda p: FisheyeCamera.from_parameters(jnp.asarray(iop)).image_point(
            jnp.asarray(p), jnp.zeros(2), jnp.asarray(0.0)),
        on_axis + np.array([1e-5, -2e-5, 0.0]), FD_RTOL, FD_ATOL_NEAR_AXIS)


def test_fisheye_jacobian_matches_finite_differences():
    rng = np.random.default_rng(22)
    p_cv, iop = _random_cv_points(rng, n=5), _random_fisheye_iop(rng)
    for p_camera in p_cv @ CV_FROM_CAMERA:
        def of_iop(values, p_camera=p_camera):
            camera = FisheyeCamera.from_parameters(jnp.asarray(values))
            return camera.image_point(jnp.asarray(p_camera), jnp.zeros(2), jnp.asarray(0.0))

        def of_point(p, iop=iop):
            camera = FisheyeCamera.from_parameters(jnp.asarray(iop))
            return camera.image_point(jnp.asarray(p), jnp.zeros(2), jnp.asarray(0.0))

        # (u, v) is linear in every IOP: central differences are exact but for rounding
        # (~1e-16 * 500 px / step), so take a long step.
        assert_jacobian_matches_fd(of_iop, iop, FD_RTOL, FD_ATOL, step=LINEAR_FD_STEP)
        assert_jacobian_matches_fd(of_point, p_camera, FD_RTOL, FD_ATOL)


# --- bal ---------------------------------------------------------------------------------------


def _bal_numpy(p_bal, iop):
    """Snavely's projection written out again: P (n, 3) in BAL's camera frame -> (n, 2) px."""
    f, k1, k2 = iop
    p = -p_bal[:, :2] / p_bal[:, 2:]
    r2 = np.sum(p**2, axis=1, keepdims=True)
    return f * (1 + k1 * r2 + k2 * r2**2) * p


def test_bal_matches_its_formulas():
    rng = np.random.default_rng(23)
    p_bal = _random_cv_points(rng, max_angle=0.6) @ CV_FROM_CAMERA  # in front: P[2] < 0
    iop = np.array([520.0, -0.08, 0.02])
    computed = _project(BalCamera, iop, p_bal)
    np.testing.assert_allclose(computed, _bal_numpy(p_bal, iop), rtol=FORMULA_RTOL)


def test_bal_jacobian_matches_finite_differences():
    rng = np.random.default_rng(24)
    p_bal = _random_cv_points(rng, n=5, max_angle=0.6) @ CV_FROM_CAMERA
    iop = np.array([520.0, -0.08, 0.02])
    for p_camera in p_bal:
        def of_iop(values, p_camera=p_camera):
            camera = BalCamera.from_parameters(jnp.asarray(values))
            return camera.image_point(jnp.asarray(p_camera), jnp.zeros(2), jnp.asarray(0.0))

        def of_point(p):
            camera = BalCamera.from_parameters(jnp.asarray(iop))
            return camera.image_point(jnp.asarray(p), jnp.zeros(2), jnp.asarray(0.0))

        assert_jacobian_matches_fd(of_iop, iop, FD_RTOL, FD_ATOL)
        assert_jacobian_matches_fd(of_point, p_camera, FD_RTOL, FD_ATOL)


def test_new_models_are_registered_in_pixels():
    assert jaxba.CAMERA_MODELS["bal"].parameter_names == ("f", "k1", "k2")
    assert FisheyeCamera.parameter_names == ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")
    assert BalCamera.image_units == FisheyeCamera.image_units == "pixel"


# --- a synthetic fisheye block through cameras.toml ------------------------------------------


def _fisheye_block(directory, rng):
    """A room of targets seen by 6 fisheye images from its middle; noise-free pixels.

    Returns (project file, true EOPs (6, 6) with angles in degrees, true points (n, 3), ids of
    the tie points). Every third target is a free tie point (started 5 cm off), the rest fixed
    control; starting EOPs are 3 cm and 1 degree off, fx, fy, cx, cy, k1, k2 start rounded.
    """
    points = rng.uniform([-5.0, -5.0, -2.0], [5.0, 5.0, 3.0], (120, 3))
    iop = np.array(list(FISHEYE_TRUTH.values()))
    eops, observed = [], {}
    for k in range(6):
        station = np.array([0.4 * np.cos(k), 0.4 * np.sin(k), 0.2 * k - 0.5])
        target = station + np.array([np.cos(1.1 * k + 0.3), np.sin(1.1 * k + 0.3), 0.3 * np.sin(k)])
        m = look_at(station, target, roll=0.2 * k)
        eops.append(np.r_[station, np.degrees(opk_from_rotation(m))])
        p_cv = (points - station) @ m.T @ CV_FROM_CAMERA
        theta = np.arccos(p_cv[:, 2] / np.linalg.norm(p_cv, axis=1))
        uv = _fisheye_numpy(p_cv, iop)
        inside = (theta < np.radians(75)) & np.all((uv > 0) & (uv < np.array(SENSOR) - 1), axis=1)
        for j in np.flatnonzero(inside):
            observed.setdefault(j, []).append((f"img{k}", uv[j]))
    eops = np.array(eops)
    kept = [j for j, seen in observed.items() if len(seen) >= 2]
    tie = {f"T{j}" for j in kept[::3]}

    start = eops + np.r_[rng.normal(0, 0.03, 3), rng.normal(0, 1.0, 3)] * np.ones((6, 1))
    (directory / "orientation.txt").write_text(
        "# image camera X0 Y0 Z0 omega phi kappa\n" + "".join(
            f"img{k} F1 " + " ".join(repr(float(v)) for v in start[k]) + "\n" for k in range(6)))
    lines = ["# point X Y Z sX sY sZ"]
    for j in kept:
        pid = f"T{j}"
        if pid in tie:
            lines.append(f"{pid} " + " ".join(repr(float(v)) for v in points[j] + 0.05) + " - - -")
        else:
            lines.append(f"{pid} " + " ".join(repr(float(v)) for v in points[j]) + " 0 0 0")
    (directory / "points.txt").write_text("\n".join(lines) + "\n")
    (directory / "image_points.txt").write_text("# image point u v\n" + "".join(
        f"{image} T{j} {float(uv[0])!r} {float(uv[1])!r}\n"
        for j in kept for image, uv in observed[j]))
    (directory / "cameras.toml").write_text("\n".join([
        "[F1]",
        'model = "fisheye"',
        "pixel_size = [1.0, 1.0]",
        f"sensor = [{SENSOR[0]}, {SENSOR[1]}]",
        "fx = 300.0", "fy = 300.0", "cx = 512.0", "cy = 384.0",
        "k1 = 0.0", "k2 = 0.0",
        f"k3 = {FISHEYE_TRUTH['k3']!r}  # weighted prior at its true value",
        f"k4 = {FISHEYE_TRUTH['k4']!r}  # fixed (left out of free and sigma)",
        'free = ["fx", "fy", "cx", "cy", "k1", "k2"]',
        "[F1.sigma]",
        "k3 = 0.01",
    ]) + "\n")
    project = directory / "fisheye.toml"
    project.write_text("\n".join([
        "[project]", 'name = "fisheye"', 'image_units = "pixel"', "",
        "[files]", 'cameras = "cameras.toml"', 'images = "orientation.txt"',
        'image_points = "image_points.txt"', 'points = "points.txt"', "",
        "[adjustment]", "image_sigma = 0.5", "max_iterations = 50", "rtol = 1e-12", "atol = 1e-12",
    ]) + "\n")
    return project, eops, {f"T{j}": points[j] for j in kept}, tie


def test_synthetic_fisheye_block_recovers_its_truth(tmp_path):
    project_file, eops, points, tie = _fisheye_block(tmp_path, np.random.default_rng(25))
    project = jaxba.build_project(jaxba.read_project(project_file))
    result = jaxba.adjust_project(project)
    assert result.converged, result.message
    model, row = project.camera_rows["F1"]
    assert model == "fisheye"
    values = np.asarray(result.parameters.cameras[model][row])
    stds = np.asarray(result.precision.std.cameras[model][row])
    np.testing.assert_allclose(values, list(FISHEYE_TRUTH.values()), rtol=TRUTH_RTOL, atol=1e-10)
    names = FisheyeCamera.parameter_names
    assert stds[names.index("k4")] == 0.0  # fixed
    assert 0 < stds[names.index("k3")] < 0.01  # weighted: the prior σ and the data
    assert np.all(stds[:6] > 0)  # free
    images = np.asarray(result.parameters.images)
    np.testing.assert_allclose(images[:, :3], eops[:, :3], atol=1e-8)
    for adjusted_opk, true_opk in zip(images[:, 3:], np.radians(eops[:, 3:])):
        np.testing.assert_allclose(jaxba.opk_to_matrix(jnp.asarray(adjusted_opk)),
                                   jaxba.opk_to_matrix(jnp.asarray(true_opk)), atol=1e-9)
    adjusted = dict(zip(project.point_ids, np.asarray(result.parameters.points)))
    for pid in tie:
        np.testing.assert_allclose(adjusted[pid], points[pid], atol=1e-8)
    assert result.sigma0 < 1e-6


@pytest.mark.parametrize("model", ["bal", "fisheye"])
def test_new_models_refuse_a_mm_project_and_refraction(tmp_path, model):
    project_file, *_ = _fisheye_block(tmp_path, np.random.default_rng(26))
    text = (tmp_path / "cameras.toml").read_text()
    if model == "bal":
        text = "\n".join(["[F1]", 'model = "bal"', "pixel_size = [1.0, 1.0]",
                          f"sensor = [{SENSOR[0]}, {SENSOR[1]}]", "f = 300.0"]) + "\n"
    (tmp_path / "cameras.toml").write_text(text)
    project = project_file.read_text()
    project_file.write_text(project.replace('image_units = "pixel"', 'image_units = "mm"'))
    with pytest.raises(jaxba.ProjectError, match=f"model '{model}' works in pixel"):
        jaxba.build_project(jaxba.read_project(project_file))
    project_file.write_text(project.replace("image_sigma", "refraction = true\nimage_sigma"))
    with pytest.raises(jaxba.ProjectError, match=f"model '{model}' has no atmospheric"):
        jaxba.build_project(jaxba.read_project(project_file))


def test_parameter_name_table_matches_the_models():
    """The jax-free name table that project files are checked against is the models' own."""
    from jaxba._models._cameras import CAMERA_MODELS, CAMERA_PARAMETER_NAMES

    assert {name: model.parameter_names for name, model in CAMERA_MODELS.items()} == (
        CAMERA_PARAMETER_NAMES)
