"""Tests of `jaxba._models._cameras` and `collinearity_residual` (conventions, finite
differences)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_ATOL, FD_RTOL, FORMULA_RTOL, assert_jacobian_matches_fd

from jaxba import (
    Affine,
    AtmosphericRefraction,
    DecenteringSmac,
    NoRefraction,
    PixelGrid,
    RadialSmac,
    SmacCamera,
    opk_to_matrix,
)
from jaxba.advanced import collinearity_residual

FORMULA_ATOL = 1e-15  # mm, for corrections that vanish (at the principal point)
REFRACTION_RTOL = 1e-12  # the refraction coefficient against the hand computation

PARAMETER_NAMES = ("xp", "yp", "c", "K0", "K1", "K2", "K3", "P1", "P2", "P3", "A1", "A2")
# Small-format camera (mm), every distortion term nonzero at a realistic size.
IOP = np.array(
    [0.05, -0.03, 8.5, 1e-4, -2e-4, 3e-7, -1e-9, 2e-5, -3e-5, 1e-3, 5e-5, -4e-5]
)
# Near-vertical image 1500 m above sea level (object unit metres), kappa ~ 40°.
EOP = np.array([500.0, 400.0, 1500.0, 0.02, -0.03, 0.7])
MEASURED = np.array([5.06, -3.04])  # mm, near the projection of POINT
SIGMA = np.array([0.002, 0.003])  # mm
REDUCED_POINTS = np.array([[0.0, 0.0], [3.2, -1.7], [-10.5, 6.1], [0.0, 7.3], [-0.4, -0.9]])


def scene_point(eop, image_xy, depth):
    """Object point that projects (without distortion) to `image_xy` at `depth` below the camera."""
    c = IOP[2]
    m = np.asarray(opk_to_matrix(jnp.asarray(eop[3:])))
    ray_image = np.array([image_xy[0], image_xy[1], -c]) * depth / c
    return eop[:3] + m.T @ ray_image


POINT = scene_point(EOP, [5.0, -3.0], 1200.0)  # Z ≈ 300 m


# --------------------------------------------------------------------------- NumPy formulas


def radial_np(k, xy):
    k0, k1, k2, k3 = k
    x, y = xy
    r2 = x * x + y * y
    factor = k0 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    return np.array([x * factor, y * factor])


def decentering_np(p, xy):
    p1, p2, p3 = p
    x, y = xy
    r2 = x * x + y * y
    return (1 + p3 * r2) * np.array(
        [p1 * (r2 + 2 * x * x) + 2 * p2 * x * y, 2 * p1 * x * y + p2 * (r2 + 2 * y * y)]
    )


def affine_np(a, xy):
    a1, a2 = a
    x, y = xy
    return np.array([-a1 * x + a2 * y, a1 * y])


def refraction_np(k, c, xy):
    x, y = xy
    r2 = x * x + y * y
    return np.array([k * x * (1 + r2 / c**2), k * y * (1 + r2 / c**2)])


def refraction_coefficient_np(z0_km, z_km):
    return 0.00241 * (z0_km / (z0_km**2 - 6 * z0_km + 250)
                      - z_km**2 / (z0_km * (z_km**2 - 6 * z_km + 250)))


def distortion_np(iop, reduced, k):
    """Sum of all correction terms of CONVENTIONS.md at the reduced point."""
    return (radial_np(iop[3:7], reduced) + decentering_np(iop[7:10], reduced)
            + affine_np(iop[10:12], reduced) + refraction_np(k, iop[2], reduced))


def camera_point_np(eop, point):
    """(U, V, W) = M (X - X0), M from the element formulas of CONVENTIONS.md."""
    omega, phi, kappa = eop[3:]
    so, co, sp, cp = np.sin(omega), np.cos(omega), np.sin(phi), np.cos(phi)
    sk, ck = np.sin(kappa), np.cos(kappa)
    m = np.array(
        [
            [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
            [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
            [sp, -so * cp, co * cp],
        ]
    )
    return m @ (point - eop[:3])


@functools.partial(jax.jit, static_argnums=0)
def residual(model, iop, eop, point, measured, sigma, refraction):
    return collinearity_residual(model, iop, eop, point, measured, sigma, refraction)


# --------------------------------------------------------------------------- distortion terms


@pytest.mark.parametrize("xy", REDUCED_POINTS.tolist())
def test_radial_formula(xy):
    k = IOP[3:7]
    got = RadialSmac.from_parameters(jnp.asarray(k)).correction(jnp.asarray(xy))
    np.testing.assert_allclose(got, radial_np(k, xy), rtol=FORMULA_RTOL, atol=FORMULA_ATOL)


@pytest.mark.parametrize("xy", REDUCED_POINTS.tolist())
def test_decentering_formula(xy):
    p = IOP[7:10]
    got = DecenteringSmac.from_parameters(jnp.asarray(p)).correction(jnp.asarray(xy))
    np.testing.assert_allclose(got, decentering_np(p, xy), rtol=FORMULA_RTOL, atol=FORMULA_ATOL)


@pytest.mark.parametrize("xy", REDUCED_POINTS.tolist())
def test_affine_formula(xy):
    a = IOP[10:12]
    got = Affine.from_parameters(jnp.asarray(a)).correction(jnp.asarray(xy))
    np.testing.assert_allclose(got, affine_np(a, xy), rtol=FORMULA_RTOL, atol=FORMULA_ATOL)


@pytest.mark.parametrize("xy", REDUCED_POINTS.tolist())
def test_refraction_term_in_image_point(xy):
    """Only refraction on: image_point - (xp - c U/W) = k x̄ (1 + r²/c²)."""
    iop = np.zeros(12)
    iop[:3] = IOP[:3]
    camera = SmacCamera.from_parameters(jnp.asarray(iop))
    k = 2.5e-4
    p_camera = np.array([0.3, -0.2, -1.0])
    measured = np.asarray(xy) + IOP[:2]
    got = np.asarray(camera.image_point(jnp.asarray(p_camera), jnp.asarray(measured),
                                        jnp.asarray(k)))
    ideal = IOP[:2] - IOP[2] * p_camera[:2] / p_camera[2]
    np.testing.assert_allclose(got - ideal, refraction_np(k, IOP[2], xy),
                               rtol=1e-10, atol=FORMULA_ATOL)


# --------------------------------------------------------------------------- SmacCamera


def test_smac_parameter_names_name_the_vector_entries():
    """`parameter_names[i]` names entry i of the parameter vector (the names project files
    and reports use): entry i alone set to 1 sets the camera's (or its distortion part's)
    field of that name to 1 and no other."""
    assert SmacCamera.parameter_names == PARAMETER_NAMES

    def fields(camera):
        parts = (camera, camera.radial, camera.decentering, camera.affine)
        return {name: float(getattr(part, name)) for part in parts
                for name in PARAMETER_NAMES if hasattr(part, name)}

    for i, name in enumerate(PARAMETER_NAMES):
        values = np.zeros(len(PARAMETER_NAMES))
        values[i] = 1.0
        named = fields(SmacCamera.from_parameters(jnp.asarray(values)))
        assert sorted(named) == sorted(PARAMETER_NAMES)
        assert named == {n: float(n == name) for n in PARAMETER_NAMES}, name
    parts = RadialSmac, DecenteringSmac, Affine
    assert sum((part.parameter_names for part in parts), ()) == PARAMETER_NAMES[3:]


def test_smac_parameters_round_trip():
    camera = SmacCamera.from_parameters(jnp.asarray(IOP))
    np.testing.assert_array_equal(camera.parameters(), IOP)
    fields = {"xp": camera.xp, "yp": camera.yp, "c": camera.c}
    for part in (camera.radial, camera.decentering, camera.affine):
        fields.update({name: getattr(part, name) for name in part.parameter_names})
    assert [float(fields[name]) for name in PARAMETER_NAMES] == IOP.tolist()


def test_image_point_without_distortion_is_collinearity():
    iop = np.zeros(12)
    iop[:3] = IOP[:3]
    camera = SmacCamera.from_parameters(jnp.asarray(iop))
    p_camera = np.array([12.0, -7.0, -950.0])
    expected = IOP[:2] - IOP[2] * p_camera[:2] / p_camera[2]
    for measured in ([0.0, 0.0], [5.0, -3.0], [-11.0, 7.0]):
        got = camera.image_point(jnp.asarray(p_camera), jnp.asarray(measured), jnp.asarray(0.0))
        np.testing.assert_allclose(got, expected, rtol=FORMULA_RTOL, atol=0)


def test_image_point_full_formula():
    camera = SmacCamera.from_parameters(jnp.asarray(IOP))
    p_camera = camera_point_np(EOP, POINT)
    k = 1.4e-5
    got = camera.image_point(jnp.asarray(p_camera), jnp.asarray(MEASURED), jnp.asarray(k))
    expected = (IOP[:2] - IOP[2] * p_camera[:2] / p_camera[2]
                + distortion_np(IOP, MEASURED - IOP[:2], k))
    np.testing.assert_allclose(got, expected, rtol=FORMULA_RTOL, atol=0)


@pytest.mark.parametrize("k", [0.0, 1.4e-5])
def test_correction_evaluated_at_measured_point(k):
    """Changing only `measured` moves the computed point by exactly the distortion difference."""
    camera = SmacCamera.from_parameters(jnp.asarray(IOP))
    p_camera = jnp.asarray(camera_point_np(EOP, POINT))
    first, second = MEASURED, np.array([-8.2, 4.9])
    difference = (np.asarray(camera.image_point(p_camera, jnp.asarray(second), jnp.asarray(k)))
                  - np.asarray(camera.image_point(p_camera, jnp.asarray(first), jnp.asarray(k))))
    expected = (distortion_np(IOP, second - IOP[:2], k)
                - distortion_np(IOP, first - IOP[:2], k))
    assert np.all(np.abs(expected) > 1e-4)  # the check has teeth
    np.testing.assert_allclose(difference, expected, rtol=1e-9, atol=1e-15)


# --------------------------------------------------------------------------- refraction


def test_refraction_coefficient_by_hand():
    """Z0 = 1.5 km, Z = 0.3 km (object unit m, unit_km = 0.001).

    Z0² - 6 Z0 + 250 = 243.25, Z² - 6 Z + 250 = 248.29, Z0 · 248.29 = 372.435;
    k = 0.00241 (1.5/243.25 - 0.09/372.435) = 0.00241 (0.0061664954 - 0.0002416529)
      = 1.42788704e-5.
    """
    refraction = AtmosphericRefraction(unit_km=0.001)
    station = jnp.array([10.0, 20.0, 1500.0])
    point = jnp.array([-40.0, 75.0, 300.0])
    k = float(refraction.coefficient(station, point))
    assert k == pytest.approx(0.00241 * (1.5 / 243.25 - 0.09 / 372.435), rel=REFRACTION_RTOL)
    assert k == pytest.approx(1.42788704e-5, rel=1e-8)
    assert k == pytest.approx(refraction_coefficient_np(1.5, 0.3), rel=REFRACTION_RTOL)


def test_refraction_height_offset_and_none():
    shifted = AtmosphericRefraction(unit_km=0.001, height_offset=100.0)
    k = shifted.coefficient(jnp.array([0.0, 0.0, 1400.0]), jnp.array([0.0, 0.0, 200.0]))
    assert float(k) == pytest.approx(refraction_coefficient_np(1.5, 0.3), rel=REFRACTION_RTOL)
    assert float(NoRefraction().coefficient(jnp.zeros(3), jnp.ones(3))) == 0.0


def test_refraction_pushes_points_outward():
    refraction = AtmosphericRefraction(unit_km=0.001)
    for z0, z in [(1500.0, 300.0), (3000.0, 0.0), (800.0, 790.0)]:
        assert float(refraction.coefficient(jnp.array([0.0, 0.0, z0]),
                                            jnp.array([0.0, 0.0, z]))) > 0
    # Computed image point with refraction minus without: radial, pointing away from (xp, yp).
    args = (jnp.asarray(IOP), jnp.asarray(EOP), jnp.asarray(POINT), jnp.asarray(MEASURED),
            jnp.asarray(SIGMA))
    computed_on = MEASURED - SIGMA * np.asarray(residual("smac", *args, refraction))
    computed_off = MEASURED - SIGMA * np.asarray(residual("smac", *args, NoRefraction()))
    shift = computed_on - computed_off
    reduced = MEASURED - IOP[:2]
    assert shift @ reduced > 0
    cross = shift[0] * reduced[1] - shift[1] * reduced[0]
    assert abs(cross) < 1e-9 * np.linalg.norm(shift) * np.linalg.norm(reduced)  # rounding only
    k = refraction_coefficient_np(EOP[2] / 1000, POINT[2] / 1000)
    np.testing.assert_allclose(shift, refraction_np(k, IOP[2], reduced), rtol=1e-8)


# --------------------------------------------------------------------------- pixel grid


def test_pixel_grid_formula():
    ps_x, ps_y, ncols, nrows = 0.004, 0.005, 6000, 4000
    grid = PixelGrid(pixel_size=(ps_x, ps_y), sensor=(ncols, nrows))
    pixels = np.array([[0.0, 0.0], [5999.0, 3999.0], [2999.5, 1999.5], [12.25, 3100.75]])
    expected = np.stack(
        [(pixels[:, 0] - (ncols - 1) / 2) * ps_x, ((nrows - 1) / 2 - pixels[:, 1]) * ps_y], axis=1
    )
    np.testing.assert_allclose(grid.pixel_to_image(jnp.asarray(pixels)), expected,
                               rtol=FORMULA_RTOL, atol=1e-15)


def test_pixel_grid_top_left_and_centre():
    ps, ncols, nrows = 0.00369, 6000, 4000  # the BASC lab camera
    grid = PixelGrid(pixel_size=(ps, ps), sensor=(ncols, nrows))
    np.testing.assert_allclose(grid.pixel_to_image(jnp.array([0.0, 0.0])),
                               [-(ncols - 1) / 2 * ps, (nrows - 1) / 2 * ps], rtol=1e-15)
    np.testing.assert_allclose(grid.pixel_to_image(jnp.array([(ncols - 1) / 2, (nrows - 1) / 2])),
                               [0.0, 0.0], atol=1e-15)


def test_pixel_grid_round_trip():
    grid = PixelGrid(pixel_size=(0.00369, 0.0041), sensor=(5472, 3648))
    rng = np.random.default_rng(0)
    pixels = rng.uniform([-0.5, -0.5], [5471.5, 3647.5], size=(50, 2))
    image = grid.pixel_to_image(jnp.asarray(pixels))
    np.testing.assert_allclose(grid.image_to_pixel(image), pixels, rtol=0, atol=1e-9)
    images = rng.uniform(-10.0, 10.0, size=(50, 2))
    np.testing.assert_allclose(grid.pixel_to_image(grid.image_to_pixel(jnp.asarray(images))),
                               images, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- derivatives


REFRACTIONS = {"refraction": AtmosphericRefraction(unit_km=0.001), "no refraction": NoRefraction()}


@pytest.mark.parametrize("refraction", list(REFRACTIONS))
@pytest.mark.parametrize("wrt", ["iop", "eop", "point"])
def test_collinearity_jacobian_matches_fd(wrt, refraction):
    values = {"iop": IOP, "eop": EOP, "point": POINT}
    model = REFRACTIONS[refraction]

    @jax.jit
    def f(x):
        args = {name: jnp.asarray(v) for name, v in values.items()} | {wrt: x}
        return collinearity_residual("smac", args["iop"], args["eop"], args["point"],
                                     jnp.asarray(MEASURED), jnp.asarray(SIGMA), model)

    assert_jacobian_matches_fd(f, values[wrt], FD_RTOL, FD_ATOL)


def test_refraction_enters_height_derivatives():
    """With refraction on, the residual depends on Z0 and Z also through k."""
    args = (jnp.asarray(IOP), jnp.asarray(EOP), jnp.asarray(POINT), jnp.asarray(MEASURED),
            jnp.asarray(SIGMA))
    on = jax.jacfwd(residual, argnums=2)("smac", *args, REFRACTIONS["refraction"])
    off = jax.jacfwd(residual, argnums=2)("smac", *args, NoRefraction())
    assert np.all(np.abs(np.asarray(on - off)[:, 2]) > 0)


# --------------------------------------------------------------------------- batching


def test_vmap_matches_loop():
    rng = np.random.default_rng(1)
    n = 6
    iop = IOP * (1 + 0.1 * rng.normal(size=(n, 12)))
    eop = EOP + rng.normal(scale=[5.0, 5.0, 10.0, 0.01, 0.01, 0.1], size=(n, 6))
    point = POINT + rng.normal(scale=20.0, size=(n, 3))
    measured = MEASURED + rng.normal(scale=0.5, size=(n, 2))
    sigma = SIGMA * rng.uniform(0.5, 2.0, size=(n, 2))
    refraction = REFRACTIONS["refraction"]

    batched = jax.jit(jax.vmap(
        lambda *a: collinearity_residual("smac", *a, refraction)
    ))(*(jnp.asarray(a) for a in (iop, eop, point, measured, sigma)))
    looped = np.stack([
        residual("smac", *(jnp.asarray(a[i]) for a in (iop, eop, point, measured, sigma)),
                 refraction)
        for i in range(n)
    ])
    assert batched.shape == (n, 2)
    np.testing.assert_allclose(batched, looped, rtol=1e-12, atol=1e-12)
