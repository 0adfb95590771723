"""Tests of `jaxba._models._rotation` against CONVENTIONS.md, hand values and scipy's Rotation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ANGLE_TOL, FD_ATOL, FD_RTOL, ROTATION_TOL, assert_jacobian_matches_fd
from scipy.spatial.transform import Rotation

import jaxba

# Jitted once: eager dispatch of many small ops would dominate the test time.
opk_to_matrix = jax.jit(jaxba.opk_to_matrix)
matrix_to_opk = jax.jit(jaxba.matrix_to_opk)
rodrigues_to_matrix = jax.jit(jaxba.rodrigues_to_matrix)
matrix_to_rodrigues = jax.jit(jaxba.matrix_to_rodrigues)
quaternion_to_matrix = jax.jit(jaxba.quaternion_to_matrix)
matrix_to_quaternion = jax.jit(jaxba.matrix_to_quaternion)
rodrigues_to_quaternion = jax.jit(jaxba.rodrigues_to_quaternion)
quaternion_to_rodrigues = jax.jit(jaxba.quaternion_to_rodrigues)

NEAR_PI = math.pi - 1e-7
ROUND_TRIP_RTOL = 1e-9  # relative to |r|: axis-angle recovered through the quaternion


def element_matrix(omega, phi, kappa):
    """M written out element by element from CONVENTIONS.md (NumPy, radians)."""
    so, co = np.sin(omega), np.cos(omega)
    sp, cp = np.sin(phi), np.cos(phi)
    sk, ck = np.sin(kappa), np.cos(kappa)
    return np.array(
        [
            [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
            [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
            [sp, -so * cp, co * cp],
        ]
    )


# Elementary rotations, passive ("rotate the axes"), the sign convention that reproduces
# CONVENTIONS.md: R1(a) = [[1,0,0],[0,c,s],[0,-s,c]], R2(a) = [[c,0,-s],[0,1,0],[s,0,c]],
# R3(a) = [[c,s,0],[-s,c,0],[0,0,1]].
def r1(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def r2(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def r3(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def random_opk(rng, n):
    """n angle triples with omega, kappa in (-π, π) and |phi| < 90°."""
    omega = rng.uniform(-3.1, 3.1, n)
    phi = rng.uniform(-1.55, 1.55, n)
    kappa = rng.uniform(-3.1, 3.1, n)
    return np.stack([omega, phi, kappa], axis=1)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def special_rotvecs(rng):
    """Axis-angle vectors at the hard places: 0, tiny, ordinary, near π, exactly π."""
    axes = [unit(rng.normal(size=3)) for _ in range(3)]
    vectors = [np.zeros(3)]
    for axis in axes:
        vectors += [1e-9 * axis, 1e-3 * axis, 1.0 * axis, 3.0 * axis, NEAR_PI * axis]
    vectors += [NEAR_PI * np.eye(3)[i] for i in range(3)]
    return vectors


def random_rotvecs(rng, n):
    """n axis-angle vectors with random axes and angles in (0, π)."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * rng.uniform(0.0, math.pi, (n, 1))


def same_quaternion(a, b, atol=ROTATION_TOL):
    """q and -q are the same rotation."""
    a, b = np.asarray(a), np.asarray(b)
    return np.allclose(a, b, rtol=0, atol=atol) or np.allclose(a, -b, rtol=0, atol=atol)


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


# --------------------------------------------------------------------------- omega, phi, kappa


def test_opk_matches_conventions_elements():
    rng = np.random.default_rng(0)
    for omega, phi, kappa in random_opk(rng, 20):
        np.testing.assert_allclose(
            opk_to_matrix(jnp.array([omega, phi, kappa])),
            element_matrix(omega, phi, kappa),
            rtol=0,
            atol=ROTATION_TOL,
        )


def test_opk_hand_value():
    """omega = 10°, phi = -20°, kappa = 30°, by hand.

    cos10 = 0.9848077530, sin10 = 0.1736481777, cos20 = 0.9396926208, sin20 = 0.3420201433,
    cos30 = 0.8660254038, sin30 = 0.5; e.g. m12 = cos10 sin30 + sin10 sin(-20) cos30
    = 0.4924038765 - 0.0514342660 = 0.4409696105.
    """
    hand = np.array(
        [
            [0.8137976813, 0.4409696105, 0.3785223064],
            [-0.4698463104, 0.8825641193, -0.0180283112],
            [-0.3420201433, -0.1631759112, 0.9254165784],
        ]
    )
    omega, phi, kappa = np.deg2rad([10.0, -20.0, 30.0])
    product = r3(kappa) @ r2(phi) @ r1(omega)
    np.testing.assert_allclose(product, hand, rtol=0, atol=1e-10)
    # The stated elementary-matrix convention reproduces CONVENTIONS.md ...
    np.testing.assert_allclose(product, element_matrix(omega, phi, kappa), rtol=0, atol=1e-15)
    # ... and the library reproduces both.
    m = np.asarray(opk_to_matrix(jnp.array([omega, phi, kappa])))
    np.testing.assert_allclose(m, product, rtol=0, atol=ROTATION_TOL)
    np.testing.assert_allclose(m, hand, rtol=0, atol=1e-10)


def test_opk_single_axis_matches_elementary():
    for angle in (-1.2, 0.3, 2.5):
        np.testing.assert_allclose(opk_to_matrix(jnp.array([angle, 0.0, 0.0])), r1(angle),
                                   rtol=0, atol=ROTATION_TOL)
        np.testing.assert_allclose(opk_to_matrix(jnp.array([0.0, angle, 0.0])), r2(angle),
                                   rtol=0, atol=ROTATION_TOL)
        np.testing.assert_allclose(opk_to_matrix(jnp.array([0.0, 0.0, angle])), r3(angle),
                                   rtol=0, atol=ROTATION_TOL)


def test_opk_orthonormal_det_one():
    rng = np.random.default_rng(1)
    for opk in random_opk(rng, 20):
        m = np.asarray(opk_to_matrix(jnp.asarray(opk)))
        np.testing.assert_allclose(m @ m.T, np.eye(3), rtol=0, atol=ROTATION_TOL)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=ROTATION_TOL)


def test_matrix_to_opk_round_trip():
    rng = np.random.default_rng(2)
    angles = np.concatenate([random_opk(rng, 50), [[0.0, 0.0, 0.0], [0.1, -1.5, 3.0]]])
    for opk in angles:
        recovered = matrix_to_opk(opk_to_matrix(jnp.asarray(opk)))
        np.testing.assert_allclose(recovered, opk, rtol=0, atol=ANGLE_TOL)


# --------------------------------------------------------------------------- axis-angle


def test_rodrigues_matches_scipy():
    rng = np.random.default_rng(3)
    for r in [*special_rotvecs(rng), *random_rotvecs(rng, 20), np.array([3.0, -4.0, 1.0])]:
        np.testing.assert_allclose(
            rodrigues_to_matrix(jnp.asarray(r)),
            Rotation.from_rotvec(r).as_matrix(),
            rtol=0,
            atol=ROTATION_TOL,
        )


def test_rodrigues_zero_is_identity():
    np.testing.assert_array_equal(rodrigues_to_matrix(jnp.zeros(3)), np.eye(3))


def test_rodrigues_taylor_branch_value():
    """For |r| = 1e-13 (< the 1e-12 switch), R - I = [r]_x to first order, so (R - I)/|r|
    is the skew matrix of the unit axis. The library gives 5/6 of it (1 - θ²/6 at θ = 1)."""
    axis = unit([1.0, -2.0, 0.5])
    m = np.asarray(rodrigues_to_matrix(jnp.asarray(1e-13 * axis)))
    np.testing.assert_allclose((m - np.eye(3)) / 1e-13, skew(axis), rtol=0, atol=1e-9)


def test_matrix_to_rodrigues_round_trip():
    rng = np.random.default_rng(4)
    for r in [*special_rotvecs(rng), *random_rotvecs(rng, 30)]:
        recovered = np.asarray(matrix_to_rodrigues(rodrigues_to_matrix(jnp.asarray(r))))
        assert np.linalg.norm(recovered - r) <= ROUND_TRIP_RTOL * np.linalg.norm(r) + 1e-300


def test_matrix_to_rodrigues_exactly_pi():
    """At θ = π the axis sign is arbitrary (r and -r are the same rotation): compare matrices."""
    rng = np.random.default_rng(5)
    axes = [*np.eye(3), unit([1.0, 1.0, 0.0]), *(unit(rng.normal(size=3)) for _ in range(5))]
    for axis in axes:
        m = rodrigues_to_matrix(jnp.asarray(math.pi * axis))
        recovered = np.asarray(matrix_to_rodrigues(m))
        assert np.linalg.norm(recovered) == pytest.approx(math.pi, abs=1e-12)
        assert same_quaternion(recovered, math.pi * axis, atol=1e-12)
        np.testing.assert_allclose(rodrigues_to_matrix(jnp.asarray(recovered)), m,
                                   rtol=0, atol=ROTATION_TOL)


def test_rodrigues_jacobian_at_zero_finite():
    jacobian = np.asarray(jax.jacfwd(rodrigues_to_matrix)(jnp.zeros(3)))
    assert jacobian.shape == (3, 3, 3)
    assert np.all(np.isfinite(jacobian))


def test_rodrigues_jacobian_at_zero_is_skew_generators():
    """dR/dr_i at r = 0 is [e_i]_x (the so(3) generators). The library gives 5/6 [e_i]_x."""
    jacobian = np.asarray(jax.jacfwd(rodrigues_to_matrix)(jnp.zeros(3)))
    for i in range(3):
        np.testing.assert_allclose(jacobian[:, :, i], skew(np.eye(3)[i]), rtol=0, atol=1e-15)


@pytest.mark.parametrize("r", [[0.3, -0.2, 0.5], [1e-6, 2e-6, -1e-6], [0.0, 0.0, 3.0]])
def test_rodrigues_jacobian_matches_fd(r):
    assert_jacobian_matches_fd(rodrigues_to_matrix, np.array(r), FD_RTOL, FD_ATOL)


def test_round_trip_gradient_at_zero_finite():
    def round_trip(r):
        return matrix_to_rodrigues(rodrigues_to_matrix(r))

    jacobian = np.asarray(jax.jacfwd(round_trip)(jnp.zeros(3)))
    assert np.all(np.isfinite(jacobian))
    gradient = np.asarray(jax.grad(lambda r: jnp.sum(round_trip(r) ** 2))(jnp.zeros(3)))
    assert np.all(np.isfinite(gradient))


def test_round_trip_jacobian_at_zero_is_identity():
    """matrix_to_rodrigues ∘ rodrigues_to_matrix is the identity, so its Jacobian is I."""
    jacobian = jax.jacfwd(lambda r: matrix_to_rodrigues(rodrigues_to_matrix(r)))(jnp.zeros(3))
    np.testing.assert_allclose(jacobian, np.eye(3), rtol=0, atol=1e-12)


@pytest.mark.parametrize("r", [[0.3, -0.2, 0.5], [1e-6, 2e-6, -1e-6], [2.0, 1.0, -1.5]])
def test_round_trip_jacobian_is_identity(r):
    jacobian = jax.jacfwd(lambda r: matrix_to_rodrigues(rodrigues_to_matrix(r)))(jnp.array(r))
    np.testing.assert_allclose(jacobian, np.eye(3), rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- quaternions


def test_quaternion_to_matrix_matches_scipy():
    rng = np.random.default_rng(6)
    quaternions = [*rng.normal(size=(30, 4)), np.array([1.0, 0.0, 0.0, 0.0])]
    for q in quaternions:  # (w, x, y, z), not normalised: the function normalises
        expected = Rotation.from_quat(np.roll(q, -1)).as_matrix()  # scipy: (x, y, z, w)
        np.testing.assert_allclose(quaternion_to_matrix(jnp.asarray(q)), expected,
                                   rtol=0, atol=ROTATION_TOL)


def shepperd_cases():
    """Matrices where each of Shepperd's four pivots wins (trace, m11, m22, m33), and near them."""
    cases = {"identity": np.eye(3)}
    for i, name in enumerate("xyz"):
        cases[f"180 about {name}"] = Rotation.from_rotvec(math.pi * np.eye(3)[i]).as_matrix()
        cases[f"170 about {name}"] = Rotation.from_rotvec(
            np.deg2rad(170) * unit(np.eye(3)[i] + 0.05)).as_matrix()
    return cases


@pytest.mark.parametrize("name", list(shepperd_cases()))
def test_matrix_to_quaternion_shepperd_branches(name):
    m = shepperd_cases()[name]
    q = np.asarray(matrix_to_quaternion(jnp.asarray(m)))
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=ROTATION_TOL)
    assert q[0] >= 0
    assert same_quaternion(q, np.roll(Rotation.from_matrix(m).as_quat(), 1))
    np.testing.assert_allclose(quaternion_to_matrix(jnp.asarray(q)), m, rtol=0, atol=ROTATION_TOL)


def test_matrix_to_quaternion_round_trip_random():
    rng = np.random.default_rng(7)
    for q in rng.normal(size=(200, 4)):
        q = q / np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        m = quaternion_to_matrix(jnp.asarray(q))
        recovered = np.asarray(matrix_to_quaternion(m))
        np.testing.assert_allclose(recovered, q, rtol=0, atol=ROTATION_TOL)
        np.testing.assert_allclose(quaternion_to_matrix(jnp.asarray(recovered)), m,
                                   rtol=0, atol=ROTATION_TOL)


def test_rodrigues_to_quaternion_matches_scipy():
    rng = np.random.default_rng(8)
    for r in [*special_rotvecs(rng)[1:], *random_rotvecs(rng, 20)]:
        expected = np.roll(Rotation.from_rotvec(r).as_quat(), 1)  # -> (w, x, y, z)
        assert same_quaternion(rodrigues_to_quaternion(jnp.asarray(r)), expected)


def test_rodrigues_to_quaternion_zero_is_unit():
    """r = 0 is the identity quaternion (1, 0, 0, 0); the library gives (cos 0.5, 0, 0, 0)."""
    np.testing.assert_allclose(rodrigues_to_quaternion(jnp.zeros(3)), [1.0, 0.0, 0.0, 0.0],
                               rtol=0, atol=ROTATION_TOL)


def test_rodrigues_quaternion_round_trips():
    rng = np.random.default_rng(9)
    for r in [*special_rotvecs(rng)[1:], *random_rotvecs(rng, 30)]:
        back = np.asarray(quaternion_to_rodrigues(rodrigues_to_quaternion(jnp.asarray(r))))
        assert np.linalg.norm(back - r) <= ROUND_TRIP_RTOL * np.linalg.norm(r)
    for q in rng.normal(size=(30, 4)):
        q = q / np.linalg.norm(q)
        back = np.asarray(rodrigues_to_quaternion(quaternion_to_rodrigues(jnp.asarray(q))))
        assert same_quaternion(back, q)
        # q and -q give the same axis-angle vector (angle in [0, π]).
        np.testing.assert_allclose(quaternion_to_rodrigues(jnp.asarray(-q)),
                                   quaternion_to_rodrigues(jnp.asarray(q)), rtol=0, atol=1e-14)


def test_quaternion_to_rodrigues_identity():
    np.testing.assert_array_equal(quaternion_to_rodrigues(jnp.array([1.0, 0.0, 0.0, 0.0])),
                                  np.zeros(3))
    jacobian = jax.jacfwd(quaternion_to_rodrigues)(jnp.array([1.0, 0.0, 0.0, 0.0]))
    assert np.all(np.isfinite(np.asarray(jacobian)))


# --------------------------------------------------------------------------- batching


def test_vmap_over_batch():
    rng = np.random.default_rng(10)
    opk = random_opk(rng, 8)
    rotvecs = np.concatenate([random_rotvecs(rng, 6), np.zeros((1, 3)), [[0.0, NEAR_PI, 0.0]]])
    branches = np.stack(list(shepperd_cases().values()))

    batched = {
        "opk": jax.vmap(opk_to_matrix)(jnp.asarray(opk)),
        "rodrigues": jax.vmap(rodrigues_to_matrix)(jnp.asarray(rotvecs)),
        "to_quaternion": jax.vmap(matrix_to_quaternion)(jnp.asarray(branches)),
        "to_rodrigues": jax.vmap(matrix_to_rodrigues)(jnp.asarray(branches)),
        "to_opk": jax.vmap(matrix_to_opk)(jax.vmap(opk_to_matrix)(jnp.asarray(opk))),
    }
    looped = {
        "opk": [opk_to_matrix(jnp.asarray(a)) for a in opk],
        "rodrigues": [rodrigues_to_matrix(jnp.asarray(r)) for r in rotvecs],
        "to_quaternion": [matrix_to_quaternion(jnp.asarray(m)) for m in branches],
        "to_rodrigues": [matrix_to_rodrigues(jnp.asarray(m)) for m in branches],
        "to_opk": [matrix_to_opk(opk_to_matrix(jnp.asarray(a))) for a in opk],
    }
    for name, result in batched.items():
        np.testing.assert_allclose(result, np.stack(looped[name]), rtol=0, atol=1e-15,
                                   err_msg=name)
