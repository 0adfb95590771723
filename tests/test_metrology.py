"""The "metrology" camera model (forward distortion at the computed point, balanced radial term
zero at the constant r0): its formula in NumPy, finite differences, the exact and approximate
relations to SMAC and their conversions, a synthetic block adjusted with it (and, biased, with
SMAC), its r0 in the reports; and the datum check that refuses SMAC's K0 freed with c."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from helpers import FD_ATOL, FD_RTOL, FORMULA_RTOL, assert_jacobian_matches_fd

import jaxba
from jaxba._io._synthetic import PIXEL_SIZE, rotation_matrix
from jaxba._models._cameras._metrology import metrology_image, smac_correction

MetrologyCamera = jaxba.CAMERA_MODELS["metrology"]
NAMES = ("xh", "yh", "c", "A1", "A2", "A3", "B1", "B2", "C1", "C2")
# A close-range metrology camera: 24.5 mm lens on a 36 x 24 mm format, balanced at r0 = 15 mm;
# about 90 µm of distortion at the format corner.
FORMAT = (36.0, 24.0)
R0 = 15.0
CAMERA = dict(xh=0.05, yh=-0.03, c=24.5, A1=-1.2e-4, A2=2e-7, A3=-1e-10, B1=1e-5, B2=-8e-6,
              C1=5e-5, C2=-2e-5)
# Conversions of CAMERA (fitted over the format, checked at other points of it): SMAC's residuals
# of metrology image points and the metrology model's of SMAC image points (measured: 0.52 and
# 0.5 µm), the image points of a round trip (measured: 0.10 µm), its parameters (relative; A3
# 0.7 %).
CONVERSION_ATOL = 1e-3  # mm
ROUND_TRIP_ATOL = 2e-4  # mm
ROUND_TRIP_RTOL = 1e-2
EXACT_ATOL = 1e-12  # mm, and parameters: relations that hold exactly


def _metrology_numpy(values, r0, p_camera, k=0.0):
    """The model written out again: (n, 3) camera-frame points -> (n, 2) image points, mm."""
    v = values
    x = -v["c"] * p_camera[:, 0] / p_camera[:, 2]
    y = -v["c"] * p_camera[:, 1] / p_camera[:, 2]
    r2 = x**2 + y**2
    d = v["A1"] * (r2 - r0**2) + v["A2"] * (r2**2 - r0**4) + v["A3"] * (r2**3 - r0**6)
    d = d + k * (1 + r2 / v["c"] ** 2)
    xs = v["xh"] + x + x * d + v["B1"] * (r2 + 2 * x**2) + 2 * v["B2"] * x * y + v["C1"] * x \
        + v["C2"] * y
    ys = v["yh"] + y + y * d + v["B2"] * (r2 + 2 * y**2) + 2 * v["B1"] * x * y
    return np.stack([xs, ys], axis=-1)


def _image_points(model, values, p_camera, measured=None, k=0.0, **constants):
    """`image_point` of `model` (values by name) on (n, 3) points, vmapped."""
    vector = jnp.asarray([values[n] for n in model.parameter_names])
    camera = model.from_parameters(vector, **constants)
    measured = np.zeros((len(p_camera), 2)) if measured is None else measured
    one = lambda p, m: camera.image_point(p, m, jnp.asarray(k))  # noqa: E731
    return np.asarray(jax.vmap(one)(jnp.asarray(p_camera), jnp.asarray(measured)))


def _rays(rng, n=200):
    """(n, 3) camera-frame points in front of the camera (W < 0) over the format."""
    ideal = rng.uniform(-1, 1, (n, 2)) * np.array(FORMAT) / 2 / CAMERA["c"]
    depth = rng.uniform(0.5, 20.0, n)
    return np.c_[ideal * depth[:, None], -depth]


def _format_points(rng, n=2000):
    """(n, 2) points spread over the image format, mm, not on the conversions' grid."""
    return rng.uniform(-1, 1, (n, 2)) * np.array(FORMAT) / 2


# --- the model ------------------------------------------------------------------------------


def test_registered_with_its_names_units_and_constant():
    assert MetrologyCamera is jaxba.MetrologyCamera
    assert MetrologyCamera.parameter_names == NAMES
    assert MetrologyCamera.constant_names == ("r0",)
    assert MetrologyCamera.image_units == "mm"
    camera = MetrologyCamera.from_parameters(jnp.arange(1.0, 11.0), r0=12.5)
    assert camera.r0 == 12.5
    np.testing.assert_array_equal(camera.parameters(), np.arange(1.0, 11.0))
    with pytest.raises(TypeError, match="needs its constant r0"):
        MetrologyCamera.from_parameters(jnp.arange(1.0, 11.0))


def test_model_matches_its_formula_with_refraction():
    p_camera = _rays(np.random.default_rng(1))
    for k in (0.0, 3e-5):
        expected = _metrology_numpy(CAMERA, R0, p_camera, k)
        np.testing.assert_allclose(
            _image_points(MetrologyCamera, CAMERA, p_camera, k=k, r0=R0), expected,
            rtol=FORMULA_RTOL)
    # The distortion is that of the computed point: the measurement does not enter.
    measured = np.random.default_rng(2).normal(0, 5, (len(p_camera), 2))
    np.testing.assert_array_equal(
        _image_points(MetrologyCamera, CAMERA, p_camera, measured, r0=R0),
        _image_points(MetrologyCamera, CAMERA, p_camera, r0=R0))


def test_radial_term_is_zero_at_r0():
    """On the circle r = r0 only the principal point, decentering and affinity remain."""
    angle = np.linspace(0, 2 * np.pi, 17)
    ideal = R0 * np.c_[np.cos(angle), np.sin(angle)]
    radial_only = dict(CAMERA, B1=0.0, B2=0.0, C1=0.0, C2=0.0)
    np.testing.assert_allclose(metrology_image(radial_only, R0, ideal), ideal, atol=EXACT_ATOL)


def test_jacobian_matches_finite_differences():
    p_camera = _rays(np.random.default_rng(3), n=4)
    iop = np.array([CAMERA[n] for n in NAMES])
    for p in p_camera:
        def of_iop(values, p=p):
            camera = MetrologyCamera.from_parameters(jnp.asarray(values), r0=R0)
            return camera.image_point(jnp.asarray(p), jnp.zeros(2), jnp.asarray(1e-5))

        def of_point(point):
            camera = MetrologyCamera.from_parameters(jnp.asarray(iop), r0=R0)
            return camera.image_point(jnp.asarray(point), jnp.zeros(2), jnp.asarray(1e-5))

        assert_jacobian_matches_fd(of_iop, iop, FD_RTOL, FD_ATOL)
        assert_jacobian_matches_fd(of_point, p, FD_RTOL, FD_ATOL)


def test_r0_is_exactly_a_change_of_scale():
    """(c, Ak, B, C, r0) is the camera (s c, Ak / s^(2k+1), B / s², C / s, 0), s = 1 + D0."""
    s = 1 - (CAMERA["A1"] * R0**2 + CAMERA["A2"] * R0**4 + CAMERA["A3"] * R0**6)
    unbalanced = dict(CAMERA, c=s * CAMERA["c"], A1=CAMERA["A1"] / s**3, A2=CAMERA["A2"] / s**5,
                      A3=CAMERA["A3"] / s**7, B1=CAMERA["B1"] / s**2, B2=CAMERA["B2"] / s**2,
                      C1=CAMERA["C1"] / s, C2=CAMERA["C2"] / s)
    p_camera = _rays(np.random.default_rng(4))
    np.testing.assert_allclose(_metrology_numpy(unbalanced, 0.0, p_camera),
                               _metrology_numpy(CAMERA, R0, p_camera), rtol=0, atol=EXACT_ATOL)


# --- conversion to and from SMAC ------------------------------------------------------------


def test_metrology_to_smac_agrees_over_the_format():
    smac = jaxba.metrology_to_smac(CAMERA, r0=R0, format_mm=FORMAT)
    assert smac["xp"] == CAMERA["xh"] and smac["yp"] == CAMERA["yh"]
    assert smac["K0"] == smac["P3"] == 0.0
    ideal = _format_points(np.random.default_rng(5)) - [CAMERA["xh"], CAMERA["yh"]]
    rays = np.c_[ideal / CAMERA["c"], -np.ones(len(ideal))]
    measured = _image_points(MetrologyCamera, CAMERA, rays, r0=R0)
    residuals = measured - _image_points(jaxba.SmacCamera, smac, rays, measured)
    assert np.abs(residuals).max() < CONVERSION_ATOL
    # The same camera passed as a MetrologyCamera.
    camera = MetrologyCamera.from_parameters(jnp.asarray([CAMERA[n] for n in NAMES]), r0=R0)
    assert jaxba.metrology_to_smac(camera, format_mm=FORMAT) == smac


def test_smac_to_metrology_agrees_over_the_format():
    smac = {"xp": 0.05, "yp": -0.03, "c": 24.9, "K0": 0.0, "K1": -1.2e-4, "K2": 2e-7,
            "K3": -1e-10, "P1": 1e-5, "P2": -8e-6, "P3": 0.0, "A1": -2.5e-5, "A2": -2e-5}
    metrology = jaxba.smac_to_metrology(smac, R0, format_mm=FORMAT)
    assert (metrology["xh"], metrology["yh"]) == (smac["xp"], smac["yp"])
    measured = _format_points(np.random.default_rng(6))
    reduced = measured - [smac["xp"], smac["yp"]]
    # SMAC's ray of each measured point, exactly: x̄ - Δ(x̄) = c (U, V) for W = -1.
    rays = np.c_[(reduced - smac_correction(smac, reduced)) / smac["c"], -np.ones(len(reduced))]
    np.testing.assert_allclose(
        _image_points(jaxba.SmacCamera, smac, rays, measured), measured, atol=EXACT_ATOL)
    computed = _image_points(MetrologyCamera, metrology, rays, r0=R0)
    assert np.abs(measured - computed).max() < CONVERSION_ATOL


def test_round_trip_returns_the_original():
    smac = jaxba.metrology_to_smac(CAMERA, r0=R0, format_mm=FORMAT)
    back = jaxba.smac_to_metrology(smac, R0, format_mm=FORMAT)
    np.testing.assert_allclose([back[n] for n in NAMES], [CAMERA[n] for n in NAMES],
                               rtol=ROUND_TRIP_RTOL, atol=1e-12)
    p_camera = _rays(np.random.default_rng(7))
    np.testing.assert_allclose(_metrology_numpy(back, R0, p_camera),
                               _metrology_numpy(CAMERA, R0, p_camera), atol=ROUND_TRIP_ATOL)


def test_linear_terms_convert_exactly_both_ways():
    """Affinity and shear alone (A = B = 0): c_s = 2 a c / (1 + a), a = 1 + C1, SMAC A1 =
    -C1 / (2 + C1), SMAC A2 = 2 C2 / (2 + C1); every other term 0; and back exactly."""
    linear = dict(CAMERA, A1=0.0, A2=0.0, A3=0.0, B1=0.0, B2=0.0, C1=2e-3, C2=-1e-3)
    smac = jaxba.metrology_to_smac(linear, r0=R0, format_mm=FORMAT)
    a = 1 + linear["C1"]
    expected = dict(xp=linear["xh"], yp=linear["yh"], c=2 * a * linear["c"] / (1 + a), K0=0.0,
                    K1=0.0, K2=0.0, K3=0.0, P1=0.0, P2=0.0, P3=0.0,
                    A1=-linear["C1"] / (2 + linear["C1"]), A2=2 * linear["C2"] / (2 + linear["C1"]))
    np.testing.assert_allclose([smac[n] for n in expected], list(expected.values()),
                               rtol=1e-13, atol=EXACT_ATOL)
    back = jaxba.smac_to_metrology(smac, R0, format_mm=FORMAT)
    np.testing.assert_allclose([back[n] for n in NAMES], [linear[n] for n in NAMES],
                               rtol=1e-12, atol=EXACT_ATOL)


def test_first_order_relations_for_a_weak_lens():
    """K1 ≈ A1, K2 ≈ A2, P1 ≈ B1, P2 ≈ B2, c_s ≈ c (1 + D0) (r0 = 0: D0 = 0)."""
    weak = dict(CAMERA, A1=-1e-6, A2=1e-9, A3=0.0, B1=1e-7, B2=-1e-7, C1=0.0, C2=0.0)
    smac = jaxba.metrology_to_smac(weak, r0=0.0, format_mm=FORMAT)
    for k, a in (("K1", "A1"), ("K2", "A2"), ("P1", "B1"), ("P2", "B2")):
        assert smac[k] == pytest.approx(weak[a], rel=0.02), (k, smac[k], weak[a])
    assert smac["c"] == pytest.approx(weak["c"], rel=1e-6)
    balanced = jaxba.metrology_to_smac(weak, r0=R0, format_mm=FORMAT)
    d0 = -(weak["A1"] * R0**2 + weak["A2"] * R0**4)
    assert balanced["c"] == pytest.approx(weak["c"] * (1 + d0), rel=1e-6)


def test_smac_to_metrology_with_another_r0_is_the_exact_change_of_scale():
    smac = jaxba.metrology_to_smac(CAMERA, r0=R0, format_mm=FORMAT)
    balanced = jaxba.smac_to_metrology(smac, R0, format_mm=FORMAT)
    unbalanced = jaxba.smac_to_metrology(smac, 0.0, format_mm=FORMAT)
    p_camera = _rays(np.random.default_rng(8))
    np.testing.assert_allclose(_metrology_numpy(balanced, R0, p_camera),
                               _metrology_numpy(unbalanced, 0.0, p_camera), atol=EXACT_ATOL)


def test_conversion_arguments_are_checked():
    with pytest.raises(ValueError, match="r0"):
        jaxba.metrology_to_smac(CAMERA, format_mm=FORMAT)
    with pytest.raises(ValueError, match="unknown metrology parameters"):
        jaxba.metrology_to_smac(dict(CAMERA, K1=0.0), r0=R0, format_mm=FORMAT)
    with pytest.raises(ValueError, match="format_mm"):
        jaxba.smac_to_metrology({"c": 24.0}, R0, format_mm=(0.0, 24.0))
    with pytest.raises(ValueError, match="expected a smac camera"):
        camera = MetrologyCamera.from_parameters(jnp.asarray([CAMERA[n] for n in NAMES]), r0=R0)
        jaxba.smac_to_metrology(camera, R0, format_mm=FORMAT)


# --- a synthetic block through cameras.toml -------------------------------------------------

# The synthetic lab's wide-angle geometry (c 8.5 mm, 22 x 15 mm format) with a metrology lens,
# balanced at r0 = 6 mm; 0.1 px of noise (0.37 µm), as the project's image σ says. Adjusted as
# SMAC, σ̂0 comes out 1.087 (the "8 % high"): SMAC cannot reproduce the lens to that
# precision.
BLOCK_R0 = 6.0
BLOCK_CAMERA = dict(xh=0.012, yh=-0.008, c=8.52, A1=-6e-4, A2=2e-6, A3=-5e-9, B1=2e-5,
                    B2=-1.5e-5, C1=1e-4, C2=-5e-5)
NOISE_PX = 0.1
SMAC_FREE = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "A1", "A2")


def _cameras_toml(model: str) -> str:
    """cameras.toml of camera C1 with approximations c = 8.5, everything else 0, all free."""
    names = NAMES if model == "metrology" else SMAC_FREE
    lines = ["[C1]", f'model = "{model}"', "pixel_size = [0.00369, 0.00369]",
             "sensor = [6000, 4000]", "c = 8.5", f"free = {json.dumps(list(names))}"]
    if model == "metrology":
        lines.insert(2, f"r0 = {BLOCK_R0}")
    return "\n".join(lines) + "\n"


def _write_metrology_block(directory):
    """The synthetic lab (12 images, 60 targets, datum and distances) with its image points
    made by the metrology camera BLOCK_CAMERA, plus noise; cameras.toml for "metrology"."""
    truth = jaxba.write_synthetic_project(directory, seed=11, n_images=12, n_targets=60,
                                          noise_px=0.0, image_sigma_px=NOISE_PX)
    rng = np.random.default_rng(12)
    table = directory / "image_coordinates.txt"
    header, *rows = table.read_text().splitlines()
    lines = [header]
    for row in rows:
        image, point = row.split()[:2]
        x0, y0, z0, *opk = truth.images[image]
        m = rotation_matrix(*np.radians(opk))
        p_camera = m @ (np.array(truth.points[point]) - [x0, y0, z0])
        xy = _metrology_numpy(BLOCK_CAMERA, BLOCK_R0, p_camera[None])[0]
        xy = xy + rng.normal(0.0, NOISE_PX * PIXEL_SIZE[0], 2)
        lines.append(f"{image} {point} {xy[0]:.8f} {xy[1]:.8f}")
    table.write_text("\n".join(lines) + "\n")
    (directory / "cameras.toml").write_text(_cameras_toml("metrology"))
    return truth.project_file


@pytest.fixture(scope="module")
def metrology_block(tmp_path_factory):
    """(project file, project, result): the metrology block adjusted with its own model."""
    project_file = _write_metrology_block(tmp_path_factory.mktemp("metrology"))
    project = jaxba.build_project(jaxba.read_project(project_file))
    return project_file, project, jaxba.adjust_project(project)


def test_block_recovers_its_camera_and_sigma0(metrology_block):
    _, project, result = metrology_block
    assert result.converged, result.message
    model, row = project.camera_rows["C1"]
    assert model == "metrology"
    values = np.asarray(result.parameters.cameras[model][row])
    stds = np.asarray(result.precision.std.cameras[model][row])
    deviation = (values - [BLOCK_CAMERA[n] for n in NAMES]) / stds
    assert np.all(np.abs(deviation) < 3), dict(zip(NAMES, deviation.round(2)))
    assert 0.9 < result.sigma0 < 1.1


def test_block_adjusted_as_smac_is_biased(metrology_block, tmp_path):
    """The same data with a SMAC camera: corrections at the (noisy) measured point cannot
    reproduce the metrology lens, σ̂0 comes out clearly higher (the issue's 8 %)."""
    project_file, _, metrology = metrology_block
    folder = tmp_path / "smac"
    folder.mkdir()
    for path in project_file.parent.iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    (folder / "cameras.toml").write_text(_cameras_toml("smac"))
    result = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(folder /
                                                                          project_file.name)))
    assert result.converged, result.message
    redundancy = result.precision.redundancy
    upper = np.sqrt(scipy.stats.chi2.ppf(0.975, redundancy) / redundancy)  # σ0 = 1
    assert metrology.sigma0 < upper < 1.05 < result.sigma0


def test_block_on_the_schur_backend_agrees(metrology_block):
    """The constant r0 reaches the Schur backend's Jacobian blocks too."""
    _, project, dense = metrology_block
    schur = jaxba.solve(project.problem, "schur")
    assert schur.converged
    np.testing.assert_allclose(schur.parameters.cameras["metrology"],
                               dense.parameters.cameras["metrology"], rtol=1e-7, atol=1e-12)


def test_reports_list_r0_as_a_constant(metrology_block, tmp_path):
    _, project, result = metrology_block
    jaxba.write_reports(project, result, tmp_path)
    camera = json.loads((tmp_path / "results.json").read_text())["cameras"]["C1"]
    assert camera["r0"] == {"value": BLOCK_R0, "std": 0.0, "status": "constant"}
    assert camera["A1"]["status"] == "free"
    out = (tmp_path / f"{project.spec.name}.out").read_text()
    row = next(line for line in out.splitlines() if line.split()[:1] == ["r0"])
    assert row.split()[-1] == "constant" and float(row.split()[1]) == BLOCK_R0


# --- the datum: SMAC's K0 freed with c ------------------------------------------------------


def _k0_project(directory, sigma_k0=None):
    """A small SMAC block with K0 free beside c (or weighted with σ `sigma_k0`)."""
    free = ("xp", "yp", "c", "K1", "K2", "P1", "P2") + (("K0",) if sigma_k0 is None else ())
    truth = jaxba.write_synthetic_project(directory, seed=3, n_images=6, n_targets=20, free=free)
    if sigma_k0 is not None:
        cameras = directory / "cameras.toml"
        cameras.write_text(cameras.read_text() + f"\n[C1.sigma]\nK0 = {sigma_k0}\n")
    return jaxba.build_project(jaxba.read_project(truth.project_file))


@pytest.mark.parametrize("solver", ["dense", "schur"])
def test_k0_freed_with_c_is_refused_before_solving(tmp_path, solver):
    """Not separable: the solve would collapse to c = 0, K0 = 1 (every residual 0)."""
    project = _k0_project(tmp_path)
    with pytest.raises(jaxba.DatumError, match="K0 and c of camera C1 are not separable"):
        jaxba.adjust(project.problem, labels=project.labels, solver=solver)


def test_k0_with_a_prior_beside_c_is_separable(tmp_path):
    from jaxba._statistics._datum import check_separable

    project = _k0_project(tmp_path, sigma_k0=1e-4)
    check_separable(project.problem, project.labels)  # no DatumError
    names = jaxba.SmacCamera.parameter_names
    assert bool(project.problem.free.cameras["smac"][0, names.index("K0")])
