"""Distortion curves (`jaxba._statistics._distortion`): each model's curve against its formula
written out in NumPy along the radius, the decentering maximum against its closed form, and
the 1σ band against central differences of the formula propagated with the camera's Cxx."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FORMULA_RTOL

import jaxba
from jaxba._statistics._derived import camera_covariance
from jaxba._statistics._distortion import correction_profile, distortion_profiles

RADII = np.linspace(0.0, 12.0, 101)  # mm (101: the compiled program of the report's curves)
PIXEL_RADII = np.linspace(0.0, 2400.0, 7)  # px
DIRECTIONS = 72  # correction_profile's default
SAMPLED_MAX_RTOL = 1e-3  # the largest decentering over 72 directions against the true maximum
SIGMA_RTOL = 1e-6  # σ from jax.jacfwd against central differences of the NumPy formula
# The curve is a difference of two image points ~10 mm (or ~2000 px) apart from the principal
# point: float64 rounding of each leaves a few 1e-15 mm (1e-13 px).
DIFFERENCE_ATOL = 1e-14


def _smac(**values):
    names = jaxba.CAMERA_MODELS["smac"].parameter_names
    return jaxba.SmacCamera.from_parameters(jnp.array([values.get(n, 0.0) for n in names]))


SMAC = dict(xp=0.03, yp=-0.02, c=8.5, K0=1e-4, K1=-8e-4, K2=3e-6, K3=-1e-8, P1=2e-5, P2=-1.5e-5,
            P3=1e-4, A1=2e-4, A2=-1e-4)


def _radial_smac(values, r):
    return r * (values["K0"] + values["K1"] * r**2 + values["K2"] * r**4 + values["K3"] * r**6)


def _brown(values, points):
    """SMAC decentering (n, 2) at reduced points (n, 2), written out."""
    x, y = points[..., 0], points[..., 1]
    r2 = x * x + y * y
    p1, p2, p3 = values["P1"], values["P2"], values["P3"]
    return (1 + p3 * r2)[..., None] * np.stack(
        [p1 * (r2 + 2 * x * x) + 2 * p2 * x * y, 2 * p1 * x * y + p2 * (r2 + 2 * y * y)], -1)


def test_smac_radial_is_the_models_own_correction():
    camera = _smac(**SMAC)
    value, jacobian = correction_profile(camera, "smac", "radial", RADII)
    np.testing.assert_allclose(value, _radial_smac(SMAC, RADII), rtol=FORMULA_RTOL,
                               atol=DIFFERENCE_ATOL)
    own = [float(camera.radial.correction(jnp.array([r, 0.0]))[0]) for r in RADII]
    np.testing.assert_allclose(value, own, rtol=FORMULA_RTOL, atol=DIFFERENCE_ATOL)
    names = list(jaxba.CAMERA_MODELS["smac"].parameter_names)
    np.testing.assert_allclose(jacobian[:, names.index("K1")], RADII**3, rtol=1e-12, atol=1e-15)
    assert not jacobian[:, names.index("P1")].any()  # the other kinds are 0 in the drawn camera


def test_smac_decentering_is_the_largest_over_directions():
    value, _ = correction_profile(_smac(**SMAC), "smac", "decentering", RADII)
    angles = np.arange(DIRECTIONS) * 2 * np.pi / DIRECTIONS
    points = RADII[:, None, None] * np.stack([np.cos(angles), np.sin(angles)], -1)[None]
    sampled = np.linalg.norm(_brown(SMAC, points), axis=-1).max(axis=1)
    np.testing.assert_allclose(value, sampled, rtol=FORMULA_RTOL, atol=DIFFERENCE_ATOL)
    # Brown's |Δ| over the directions: |P| r² (1 + P3 r²) times 1 to 3.
    closed = 3 * np.hypot(SMAC["P1"], SMAC["P2"]) * RADII**2 * (1 + SMAC["P3"] * RADII**2)
    np.testing.assert_allclose(value, closed, rtol=SAMPLED_MAX_RTOL)


def test_forward_pixel_models_along_x():
    """OpenCV and fisheye: Δ = fx (x'' - x') along +x, x' = r / fx (pinhole) or θ = r / fx
    (the fisheye's ideal camera is equidistant)."""
    opencv = jaxba.OpenCVCamera(1500.0, 1400.0, 1000.0, 700.0, 3.0, -0.2, 0.05, 1e-3, -2e-3, 0.01)
    value, _ = correction_profile(opencv, "opencv", "radial", PIXEL_RADII)
    rho = PIXEL_RADII / 1500.0
    expected = PIXEL_RADII * (-0.2 * rho**2 + 0.05 * rho**4 + 0.01 * rho**6)
    np.testing.assert_allclose(value, expected, rtol=FORMULA_RTOL, atol=100 * DIFFERENCE_ATOL)
    fisheye = jaxba.FisheyeCamera(800.0, 810.0, 960.0, 540.0, 0.05, -0.01, 0.002, -1e-4)
    value, _ = correction_profile(fisheye, "fisheye", "radial", PIXEL_RADII / 2)
    theta = PIXEL_RADII / 2 / 800.0
    expected = PIXEL_RADII / 2 * (0.05 * theta**2 - 0.01 * theta**4 + 0.002 * theta**6
                                  - 1e-4 * theta**8)
    np.testing.assert_allclose(value, expected, rtol=FORMULA_RTOL, atol=100 * DIFFERENCE_ATOL)
    with pytest.raises(ValueError, match="no decentering terms"):
        correction_profile(fisheye, "fisheye", "decentering", PIXEL_RADII)


def test_metrology_crosses_zero_at_r0_and_photomodeler_has_the_opposite_sign():
    names = jaxba.CAMERA_MODELS["metrology"].parameter_names
    values = dict(xh=0.01, yh=0.02, c=8.5, A1=-8e-4, A2=3e-6, A3=-1e-8, B1=1e-5, B2=2e-5,
                  C1=1e-4, C2=-1e-4)
    camera = jaxba.MetrologyCamera.from_parameters(
        jnp.array([values[n] for n in names]), r0=6.0)
    value, _ = correction_profile(camera, "metrology", "radial", RADII)
    r2, r02 = RADII**2, 36.0
    expected = RADII * (values["A1"] * (r2 - r02) + values["A2"] * (r2**2 - r02**2)
                        + values["A3"] * (r2**3 - r02**3))
    np.testing.assert_allclose(value, expected, rtol=1e-12, atol=DIFFERENCE_ATOL)
    assert value[50] == pytest.approx(0.0, abs=DIFFERENCE_ATOL)  # RADII[50] = r0
    pm = jaxba.PhotoModelerCamera(0.02, -0.01, 8.5, -8e-4, 3e-6, -1e-8, 2e-5, -1e-5, 1e-3, 2e-4)
    value, _ = correction_profile(pm, "photomodeler", "radial", RADII)
    expected = -RADII * (-8e-4 * RADII**2 + 3e-6 * RADII**4 - 1e-8 * RADII**6)
    np.testing.assert_allclose(value, expected, rtol=1e-12, atol=DIFFERENCE_ATOL)


def test_profiles_reach_the_farthest_corner_with_sigma_from_cxx(synthetic_block):
    """The radial band: σ² = J C Jᵀ with J by central differences of the NumPy formula
    with respect to K0..K3 and C the adjusted block's covariance of those parameters."""
    _, project, result = synthetic_block
    model, row = project.camera_rows["C1"]
    names = list(jaxba.CAMERA_MODELS[model].parameter_names)
    values = dict(zip(names, np.asarray(result.parameters.cameras[model])[row].tolist()))
    corners = np.array([[-11.07, -7.38], [11.07, -7.38], [-11.07, 7.38], [11.07, 7.38]])
    profiles = distortion_profiles(result, model, row, corners)
    assert set(profiles) == {"radial", "decentering"}
    radial = profiles["radial"]
    farthest = np.max(np.linalg.norm(corners - [values["xp"], values["yp"]], axis=1))
    assert radial.radius[-1] == pytest.approx(farthest, rel=1e-14)
    np.testing.assert_allclose(radial.value, _radial_smac(values, radial.radius),
                               rtol=FORMULA_RTOL, atol=DIFFERENCE_ATOL)
    kind = ["K0", "K1", "K2", "K3"]
    jacobian = np.empty((radial.radius.size, len(kind)))
    for k, name in enumerate(kind):
        step = 1e-6 * max(abs(values[name]), 1e-9)
        up, down = dict(values), dict(values)
        up[name] += step
        down[name] -= step
        jacobian[:, k] = (_radial_smac(up, radial.radius) - _radial_smac(down, radial.radius)) / (
            2 * step)
    chosen = [names.index(name) for name in kind]
    covariance = camera_covariance(result, model, row)[np.ix_(chosen, chosen)]
    expected = np.sqrt(np.einsum("nk,kl,nl->n", jacobian, covariance, jacobian))
    assert expected[-1] > 0 and covariance[0, 0] == 0  # K0 fixed: no variance
    np.testing.assert_allclose(radial.std, expected, rtol=SIGMA_RTOL, atol=1e-15)
    assert profiles["decentering"].std[-1] > 0
