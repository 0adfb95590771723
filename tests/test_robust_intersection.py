"""The block initialisation's robust forward intersection (`jaxba._adjust._initialise._robust.
intersect`): the point of the pair of rays that most rays fit, found by scoring all pairs at once,
is the one a plain loop over the pairs finds; with more rays than `RAY_PAIRS` pairs, a sample of
pairs still finds the point among many blunders."""

import numpy as np
import pytest

from jaxba._adjust._initialise import _robust
from jaxba._approximations import forward_intersection
from jaxba._approximations._intersection import closest_point
from jaxba._models._rotation_numpy import matrix_to_opk, opk_to_matrix

NOISE = 1e-5  # normalised units (radians near the axis)
THRESHOLD = 5 * NOISE  # a clean ray misses by more with odds exp(-12.5)
POINT_ATOL = 1e-3  # m: 100 noise σ at the 10 m distance of the images


def rays_of(rng, k, blunders):
    """k images on a sphere around a point near the origin looking at it, their normalised
    coordinates q (k, 2) of the point with noise, `blunders` of them moved by 0.05."""
    point = rng.normal(0.0, 0.1, 3)
    stations = rng.normal(0.0, 1.0, (k, 3))
    stations = 10.0 * stations / np.linalg.norm(stations, axis=1, keepdims=True)
    opk = np.c_[rng.uniform(-0.2, 0.2, (k, 2)), rng.uniform(-np.pi, np.pi, k)]
    matrices = np.empty((k, 3, 3))
    for n, (station, angles) in enumerate(zip(stations, opk)):
        z = (station - point) / np.linalg.norm(station - point)  # the camera looks along -z
        x = np.cross(rng.normal(size=3), z)
        x /= np.linalg.norm(x)
        matrices[n] = opk_to_matrix(angles) @ np.stack([x, np.cross(z, x), z])
    uvw = np.einsum("kij,kj->ki", matrices, point - stations)
    q = -uvw[:, :2] / uvw[:, 2:] + rng.normal(0.0, NOISE, (k, 2))
    bad = rng.choice(k, blunders, replace=False)
    q[bad] += 0.05 * rng.choice([-1.0, 1.0], (blunders, 2))
    eops = np.c_[stations, matrix_to_opk(matrices)]
    return point, q, eops, matrices, bad


def best_pair_by_loop(q, eops, matrices, threshold):
    """The pair point a loop over all pairs i < j keeps (the first of the most inliers, then of
    the least truncated squares)."""
    directions = np.einsum("kji,kj->ki", matrices, np.c_[q, -np.ones(len(q))])
    best = (-1, -np.inf, None)
    for i in range(len(q)):
        for j in range(i + 1, len(q)):
            candidate = closest_point(eops[[i, j], :3], directions[[i, j]], "")
            uvw = np.einsum("kij,kj->ki", matrices, candidate - eops[:, :3])
            e = np.linalg.norm(q + uvw[:, :2] / uvw[:, 2:], axis=1)
            e = np.where(uvw[:, 2] < 0, e, np.inf)
            key = (np.sum(e <= threshold), -np.sum(np.minimum(e, threshold) ** 2))
            if key > best[:2]:
                best = (*key, candidate)
    return best


@pytest.mark.parametrize("k", [5, 12, 40])
def test_the_vectorised_pair_search_equals_a_loop(k, monkeypatch):
    rng = np.random.default_rng(k)
    point, q, eops, matrices, bad = rays_of(rng, k, blunders=k // 3)
    threshold = THRESHOLD
    fitted = []  # the rays of each forward intersection: all, then the winning pair's inliers

    def recording(image_points, *args, **kwargs):
        fitted.append(np.asarray(image_points))
        return forward_intersection(image_points, *args, **kwargs)

    monkeypatch.setattr(_robust, "forward_intersection", recording)
    found = _robust.intersect(q, eops, matrices, threshold, np.radians(1.0))
    count, _, expected = best_pair_by_loop(q, eops, matrices, threshold)
    assert count == k - len(bad)
    uvw = np.einsum("kij,kj->ki", matrices, expected - eops[:, :3])
    chosen = np.linalg.norm(q + uvw[:, :2] / uvw[:, 2:], axis=1) <= threshold
    assert len(fitted) == 2
    np.testing.assert_array_equal(fitted[1], q[chosen])
    assert found.point is not None
    np.testing.assert_array_equal(np.flatnonzero(~found.inliers), np.sort(bad))
    np.testing.assert_allclose(found.point, point, atol=POINT_ATOL)


def test_pairs_are_all_or_a_deterministic_sample():
    i, j = _robust._ray_pairs(12)
    assert len(i) == 66 and np.all(i < j)
    k = 200
    i, j = _robust._ray_pairs(k)
    assert len(i) == _robust.RAY_PAIRS and np.all(i != j)
    assert np.all((0 <= i) & (i < k) & (0 <= j) & (j < k))
    np.testing.assert_array_equal(np.c_[i, j], np.c_[_robust._ray_pairs(k)])


def test_many_rays_with_many_blunders_are_sampled():
    rng = np.random.default_rng(3)
    k = 150  # 11175 pairs: a sample of RAY_PAIRS
    point, q, eops, matrices, bad = rays_of(rng, k, blunders=60)
    found = _robust.intersect(q, eops, matrices, THRESHOLD, np.radians(1.0))
    assert found.point is not None
    np.testing.assert_array_equal(np.flatnonzero(~found.inliers), np.sort(bad))
    np.testing.assert_allclose(found.point, point, atol=POINT_ATOL)
