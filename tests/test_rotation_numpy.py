"""The NumPy omega-phi-kappa rotation (`jaxba._models._rotation_numpy`) equals jaxba's jax one
(`jaxba._models._rotation`) to rounding, its derivative equals jax's forward-mode Jacobian,
and it broadcasts over leading axes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
from jaxba._models import _rotation_numpy as rn

EXACT = 1e-15  # a few float64 ulps of values of order 1


@pytest.fixture(scope="module")
def opk():
    """Random angles, phi over the whole open range, and phi within 1e-7 of ±90°."""
    rng = np.random.default_rng(7)
    general = rng.uniform(-np.pi, np.pi, (200, 3))
    general[:, 1] /= 2.0
    near_gimbal = rng.uniform(-np.pi, np.pi, (40, 3))
    near_gimbal[:, 1] = np.where(np.arange(40) % 2, 1.0, -1.0) * (
        np.pi / 2 - 10.0 ** rng.uniform(-12, -7, 40))
    return np.r_[general, near_gimbal]


def test_matrix_equals_jax(opk):
    expected = np.asarray(jax.jit(jax.vmap(jaxba.opk_to_matrix))(jnp.asarray(opk)))
    np.testing.assert_allclose(rn.opk_to_matrix(opk), expected, rtol=0, atol=EXACT)


def test_angles_equal_jax(opk):
    matrices = rn.opk_to_matrix(opk)
    expected = np.asarray(jax.jit(jax.vmap(jaxba.matrix_to_opk))(jnp.asarray(matrices)))
    found = rn.matrix_to_opk(matrices)
    np.testing.assert_allclose(found, expected, rtol=0, atol=EXACT)
    # And they are the angles (omega and kappa lose accuracy only right at phi = ±90°).
    general = slice(0, 200)
    np.testing.assert_allclose(found[general], opk[general], rtol=0, atol=1e-13)


def test_matrix_is_the_product_of_the_elementary_rotations(opk):
    """M = R3(kappa) R2(phi) R1(omega), R1(a) = [[1, 0, 0], [0, c, s], [0, -s, c]], R2 and R3
    alike about y and z (docs/conventions.md)."""
    def elementary(axis, a):
        c, s = np.cos(a), np.sin(a)
        r = np.eye(3)
        i, j = [n for n in range(3) if n != axis]
        r[i, i] = r[j, j] = c
        r[i, j], r[j, i] = (s, -s) if axis != 1 else (-s, s)
        return r

    for omega, phi, kappa in opk[::10]:
        product = elementary(2, kappa) @ elementary(1, phi) @ elementary(0, omega)
        np.testing.assert_allclose(rn.opk_to_matrix([omega, phi, kappa]), product, rtol=0,
                                   atol=EXACT)


def test_derivatives_equal_jax_jacfwd(opk):
    expected = np.asarray(jax.jit(jax.vmap(jax.jacfwd(jaxba.opk_to_matrix)))(jnp.asarray(opk)))
    found = rn.opk_derivatives(opk)
    assert found.shape == (len(opk), 3, 3, 3)
    np.testing.assert_allclose(found, expected, rtol=0, atol=EXACT)


def test_derivatives_against_central_differences(opk):
    h = 1e-6
    steps = h * np.eye(3)
    numeric = np.stack([(rn.opk_to_matrix(opk + s) - rn.opk_to_matrix(opk - s)) / (2 * h)
                        for s in steps], axis=-1)
    np.testing.assert_allclose(rn.opk_derivatives(opk), numeric, rtol=0, atol=1e-9)


def test_leading_axes_broadcast(opk):
    grid = opk[:24].reshape(2, 3, 4, 3)
    matrices = rn.opk_to_matrix(grid)
    assert matrices.shape == (2, 3, 4, 3, 3)
    assert rn.matrix_to_opk(matrices).shape == (2, 3, 4, 3)
    assert rn.opk_derivatives(grid).shape == (2, 3, 4, 3, 3, 3)
    np.testing.assert_array_equal(matrices[1, 2, 3], rn.opk_to_matrix(grid[1, 2, 3]))
    np.testing.assert_array_equal(rn.opk_to_matrix(list(opk[0])), rn.opk_to_matrix(opk[0]))
    m = matrices[1, 2, 3]
    np.testing.assert_allclose(m @ m.T, np.eye(3), rtol=0, atol=1e-15)


@pytest.mark.parametrize(("function", "shape"), [
    (rn.opk_to_matrix, (2,)), (rn.opk_derivatives, (4, 2)), (rn.matrix_to_opk, (3, 2))])
def test_bad_shapes_are_refused(function, shape):
    with pytest.raises(ValueError, match="shape"):
        function(np.zeros(shape))


@pytest.mark.parametrize("scale", [0.0, 1e-13, 1e-3, 2.5])
def test_rodrigues_matrix_equals_jax(scale):
    """Rodrigues' formula in NumPy equals jax's, below its Taylor threshold and above."""
    r = scale * np.array([0.6, -0.48, 0.64])
    expected = np.asarray(jax.jit(jaxba.rodrigues_to_matrix)(jnp.asarray(r)))
    np.testing.assert_allclose(rn.rodrigues_to_matrix(r), expected, rtol=0, atol=EXACT)
