"""Statistics against independent computations: SciPy adjustment, finite differences,
Monte Carlo, variance components, data snooping, redundancy numbers."""

import collections
import logging
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.stats
from helpers import SYNTHETIC_BLOCK

import jaxba

IOPS = ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2")
STD_RTOL_VS_SCIPY = 0.03  # issue: σ of the IOPs within 3 % of an independent adjustment
SIGMA0_RTOL_VS_SCIPY = 0.005
CORRELATION_ATOL_VS_SCIPY = 0.02


def _project(directory, **kwargs):
    truth = jaxba.write_synthetic_project(directory, **kwargs)
    return truth, jaxba.build_project(jaxba.read_project(truth.project_file))


def _with_settings(truth, **settings):
    text = truth.project_file.read_text()
    lines = "".join(
        f"\n{k} = {str(v).lower() if isinstance(v, bool) else v}" for k, v in settings.items()
    )
    truth.project_file.write_text(text.replace("[adjustment]", "[adjustment]" + lines))
    return jaxba.build_project(jaxba.read_project(truth.project_file))


@pytest.fixture(scope="module")
def block(synthetic_block):
    return synthetic_block


# --- an independent adjustment: NumPy model (CONVENTIONS.md), SciPy least squares ---------


def _rotations(angles):
    """M = R3(κ) R2(φ) R1(ω) (n, 3, 3) of omega, phi, kappa (n, 3) in radians."""
    (co, cp, ck), (so, sp, sk) = np.cos(angles.T), np.sin(angles.T)
    one, zero = np.ones_like(co), np.zeros_like(co)
    r1 = np.stack([one, zero, zero, zero, co, so, zero, -so, co], -1).reshape(-1, 3, 3)
    r2 = np.stack([cp, zero, -sp, zero, one, zero, sp, zero, cp], -1).reshape(-1, 3, 3)
    r3 = np.stack([ck, sk, zero, -sk, ck, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    return r3 @ r2 @ r1


class _ScipyBundle:
    """The lab bundle written again from the file contents, for scipy.optimize.least_squares."""

    def __init__(self, spec):
        self.images = list(spec.images)
        self.points = sorted({m.point for m in spec.image_points}, key=list(spec.points).index)
        self.sigma = spec.settings.image_sigma
        point_row = {p: k for k, p in enumerate(self.points)}
        image_row = {i: k for k, i in enumerate(self.images)}
        self.obs_image = np.array([image_row[m.image] for m in spec.image_points])
        self.obs_point = np.array([point_row[m.point] for m in spec.image_points])
        self.xy = np.array([m.xy for m in spec.image_points])
        xyz = np.array([spec.points[p].xyz for p in self.points])
        self.point_fixed = np.array([[s == 0 for s in spec.points[p].sigma] for p in self.points])
        self.xyz_fixed = xyz[self.point_fixed]
        eop = np.array([spec.images[i].eop for i in self.images], dtype=float)
        eop[:, 3:] = np.radians(eop[:, 3:])
        self.distances = [(point_row[d.a], point_row[d.b], d.distance, d.sigma)
                          for d in spec.distances]
        camera = next(iter(spec.cameras.values()))
        iop = np.array([camera.values[n] for n in IOPS])
        self.x0 = np.concatenate([iop, eop.ravel(), xyz[~self.point_fixed]])

    def unpack(self, x):
        iop = dict(zip(IOPS, x[:8]))
        eop = x[8:8 + 6 * len(self.images)].reshape(-1, 6)
        xyz = np.empty(self.point_fixed.shape)
        xyz[self.point_fixed] = self.xyz_fixed
        xyz[~self.point_fixed] = x[8 + 6 * len(self.images):]
        return iop, eop, xyz

    def residuals(self, x):
        """Whitened residuals, all image observations at once (scipy's 3-point Jacobian
        calls this ~3,500 times: an image at a time it took 3 s)."""
        iop, eop, xyz = self.unpack(x)
        m = _rotations(eop[:, 3:])[self.obs_image]
        uvw = np.einsum("nij,nj->ni", m, xyz[self.obs_point] - eop[self.obs_image, :3])
        xbar = self.xy[:, 0] - iop["xp"]
        ybar = self.xy[:, 1] - iop["yp"]
        r2 = xbar**2 + ybar**2
        radial = iop["K1"] * r2 + iop["K2"] * r2**2 + iop["K3"] * r2**3
        dx = xbar * radial + iop["P1"] * (r2 + 2 * xbar**2) + 2 * iop["P2"] * xbar * ybar
        dy = ybar * radial + 2 * iop["P1"] * xbar * ybar + iop["P2"] * (r2 + 2 * ybar**2)
        x_comp = iop["xp"] - iop["c"] * uvw[:, 0] / uvw[:, 2] + dx
        y_comp = iop["yp"] - iop["c"] * uvw[:, 1] / uvw[:, 2] + dy
        image = np.stack([self.xy[:, 0] - x_comp, self.xy[:, 1] - y_comp], 1).ravel() / self.sigma
        distance = [(d - np.linalg.norm(xyz[a] - xyz[b])) / s for a, b, d, s in self.distances]
        return np.concatenate([image, distance])


@pytest.fixture(scope="module")
def scipy_solution(block):
    _, project, _ = block
    bundle = _ScipyBundle(project.spec)
    fit = scipy.optimize.least_squares(
        bundle.residuals, bundle.x0, jac="3-point", method="trf", x_scale="jac",
        xtol=1e-12, ftol=1e-12, gtol=1e-12,
    )
    redundancy = fit.fun.size - fit.x.size
    sigma0_squared = float(fit.fun @ fit.fun) / redundancy
    covariance = sigma0_squared * np.linalg.inv(fit.jac.T @ fit.jac)
    return fit, redundancy, sigma0_squared, covariance[:8, :8]


def test_precision_matches_an_independent_scipy_adjustment(block, scipy_solution):
    _, project, result = block
    fit, redundancy, sigma0_squared, covariance = scipy_solution
    assert fit.success
    assert result.precision.redundancy == redundancy
    assert math.isclose(result.sigma0, math.sqrt(sigma0_squared), rel_tol=SIGMA0_RTOL_VS_SCIPY)
    names = jaxba.SmacCamera.parameter_names
    std = np.asarray(result.precision.std.cameras["smac"][0])
    for k, name in enumerate(IOPS):
        assert math.isclose(std[names.index(name)], math.sqrt(covariance[k, k]),
                            rel_tol=STD_RTOL_VS_SCIPY), name
    estimated, rho = jaxba.camera_correlation(result, "smac", 0)
    scipy_rho = jaxba.correlation(covariance)
    k1, k2 = estimated.index("K1"), estimated.index("K2")
    assert abs(rho[k1, k2] - scipy_rho[3, 4]) < CORRELATION_ATOL_VS_SCIPY


def test_covariance_matches_finite_difference_jacobian_and_numpy_inverse(block):
    _, project, result = block
    problem = result.problem
    index = jaxba.advanced.free_indices(problem)
    base = jaxba.advanced.flatten(result.parameters)
    rows = np.concatenate([np.ravel(np.asarray(g.mask())) for g in problem.groups])
    residuals = jax.jit(lambda values: problem.residuals(values))  # one compile, 700 calls

    def residual(x_free):
        flat = base.copy()
        flat[index] = x_free
        values = jaxba.advanced.unflatten(result.parameters, flat)
        return np.concatenate([np.ravel(np.asarray(r)) for r in residuals(values)])[rows]

    x = base[index]
    steps = 1e-6 * np.maximum(np.abs(x), 1.0) * np.where(np.abs(x) < 1e-3, 1e-3, 1.0)
    jacobian = np.stack([(residual(x + h * e) - residual(x - h * e)) / (2 * h)
                         for h, e in zip(steps, np.eye(x.size))], axis=1)
    cofactor = np.linalg.inv(jacobian.T @ jacobian)
    std = np.sqrt(np.diag(cofactor) * result.precision.sigma0_squared)
    np.testing.assert_allclose(np.sqrt(np.diag(result.precision.covariance)), std, rtol=1e-5)


def test_redundancy_numbers_sum_to_the_redundancy(block):
    _, _, result = block
    total = sum(np.nansum(r) for r in result.reliability.redundancy_numbers)
    assert math.isclose(total, result.precision.redundancy, rel_tol=1e-9)
    for r in result.reliability.redundancy_numbers:
        finite = r[np.isfinite(r)]
        assert np.all((finite > -1e-12) & (finite < 1 + 1e-12))


def test_propagation_of_a_distance(block):
    _, project, result = block
    a, b = 5, 60

    def distance(params):
        return jnp.linalg.norm(params.points[a] - params.points[b])

    value, covariance = jaxba.propagate(result, distance)
    points = np.asarray(result.parameters.points)
    assert math.isclose(float(value), np.linalg.norm(points[a] - points[b]), rel_tol=1e-14)
    # Closed form: σ_d² = uᵀ (C_aa + C_bb - C_ab - C_ba) u with u the unit direction.
    u = (points[a] - points[b]) / np.linalg.norm(points[a] - points[b])
    full = jaxba.full_covariance(result)
    positions = np.asarray(jaxba.advanced.unflatten(result.parameters,
                                           np.arange(full.shape[0])).points)
    pa, pb = positions[a], positions[b]
    block_ab = (full[np.ix_(pa, pa)] + full[np.ix_(pb, pb)]
                - full[np.ix_(pa, pb)] - full[np.ix_(pb, pa)])
    assert math.isclose(covariance[0, 0], u @ block_ab @ u, rel_tol=1e-10)
    ellipsoids = jaxba.point_covariances(result)
    np.testing.assert_allclose(ellipsoids[a], full[np.ix_(pa, pa)])
    axes, _ = jaxba.error_ellipsoids(ellipsoids[a:a + 1])
    assert math.isclose(np.sum(axes**2), np.trace(ellipsoids[a]), rel_tol=1e-10)


# --- variance components and data snooping ------------------------------------------------


@pytest.mark.slow  # ~45 s: a two-camera block, several variance-component rounds
def test_variance_components_recover_a_threefold_noisier_camera(tmp_path):
    truth = jaxba.write_synthetic_project(
        tmp_path, seed=5, n_cameras=2, noise_px=0.3, camera_noise_px=[0.3, 0.9]
    )
    project = _with_settings(truth, variance_components=True)
    result = jaxba.adjust_project(project)
    components = result.variance_components
    assert components["image_points:C1"].sigma0 == pytest.approx(1.0, rel=0.15)
    assert components["image_points:C2"].sigma0 == pytest.approx(3.0, rel=0.15)
    assert result.sigma0 == pytest.approx(1.0, abs=1e-3)
    assert result.variance_iterations >= 2
    r_image = sum(components[f"image_points:C{k}"].redundancy for k in (1, 2))
    assert r_image < result.precision.redundancy + 1e-6


def test_variance_components_after_a_rejection_are_named_by_camera(tmp_path):
    """Data snooping re-adjusts without IDs; the second variance-component pass, after its
    rejection, still names the components by the project's cameras, not by row number."""
    truth = jaxba.write_synthetic_project(
        tmp_path, seed=2, n_images=9, n_targets=50, n_cameras=2,
        camera_noise_px=[0.3, 0.9], blunders=[("img03", "12", 0, 0.02)])
    project = _with_settings(truth, variance_components=True, data_snooping=True)
    result = jaxba.adjust_project(project)
    assert result.rejections
    assert set(result.variance_components) == {"image_points:C1", "image_points:C2",
                                               "distances"}


def test_data_snooping_flags_a_planted_blunder(tmp_path, caplog):
    """Also: the re-adjustments after each rejection reuse the first adjustment's compiled
    solve and Jacobian (a switched-off observation keeps the shapes), none recompiled."""
    sigma_mm = 0.3 * 0.00369
    truth = jaxba.write_synthetic_project(
        tmp_path, **SYNTHETIC_BLOCK, blunders=[("img07", "33", 1, 30 * sigma_mm)]
    )
    project = _with_settings(truth, data_snooping=True)
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        result = jaxba.adjust_project(project)
    compiled = collections.Counter(
        record.getMessage().split()[4] for record in caplog.records
        if record.getMessage().startswith("Finished XLA compilation of "))
    assert all(compiled[name] <= 1 for name in ("jit(_step)", "jit(_dense_jacobian)")), compiled
    assert 1 <= len(result.rejections) <= 3
    first = result.rejections[0]
    group = project.problem.groups[0]
    assert project.image_ids[int(group.image[first.row])] == "img07"
    assert project.point_ids[int(group.point[first.row])] == "33"
    assert first.coordinate == 1 and first.w > 20
    final = result.reliability
    assert np.nanmax(np.abs(np.concatenate([np.ravel(w) for w in final.normalised_residuals]))) \
        <= final.critical_value
    assert result.precision.n_observations == project.problem.n_observations() - 2 * len(
        result.rejections)


@pytest.mark.slow  # ~1 min: a plain and a robust adjustment
def test_robust_loss_resists_blunders(tmp_path):
    sigma_mm = 0.3 * 0.00369
    clean = jaxba.write_synthetic_project(tmp_path / "clean", **SYNTHETIC_BLOCK)
    measured = clean.project_file.parent.joinpath("image_coordinates.txt").read_text().split("\n")
    rows = [line.split()[:2] for line in measured if line and not line.startswith("#")]
    blunders = [(*rows[k], k % 2, 40 * sigma_mm) for k in range(7, len(rows), len(rows) // 6)]
    truth = jaxba.write_synthetic_project(tmp_path, **SYNTHETIC_BLOCK, blunders=blunders)
    plain = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(truth.project_file)))
    robust = jaxba.adjust_project(_with_settings(truth, robust='"huber"', robust_scale=2.0))
    names = jaxba.SmacCamera.parameter_names
    true = np.array([truth.cameras["C1"][n] for n in names])

    def error_in_sigmas(result):
        values = np.asarray(result.parameters.cameras["smac"][0])
        std = np.asarray(result.precision.std.cameras["smac"][0])
        free = std > 0
        return np.abs(values - true)[free] / std[free]

    assert robust.converged and plain.converged
    assert np.max(error_in_sigmas(robust)) < np.max(error_in_sigmas(plain))
    assert np.max(error_in_sigmas(robust)) < 4.0


@pytest.mark.parametrize("kind", ["huber", "cauchy"])
def test_robust_transform_gives_the_loss(kind):
    loss = jaxba.RobustLoss(kind, 2.0)
    e = np.linspace(-10, 10, 201)
    rho = {"huber": np.where(np.abs(e) <= 2, 0.5 * e**2, 2 * np.abs(e) - 2.0),
           "cauchy": 2.0 * np.log1p((e / 2) ** 2)}[kind]
    # One program (op by op: ~40 small ones per loss).
    values, gradient, at_zero = jax.jit(
        lambda e: (loss(e), jax.vmap(jax.grad(loss))(e), jax.grad(loss)(0.0)))(e)
    np.testing.assert_allclose(0.5 * np.asarray(values) ** 2, rho, rtol=1e-12, atol=1e-14)
    assert np.all(np.isfinite(gradient)) and float(at_zero) == pytest.approx(1.0)


# --- Monte Carlo ---------------------------------------------------------------------------

REPLICATES = 200
MC_STD_RTOL = 0.10  # issue: empirical σ of the IOPs within ±10 % of the formal σ


@pytest.mark.slow
def test_monte_carlo_precision_and_variance_factor(tmp_path):
    """Replicates of one geometry with fresh noise, solved in one vmapped call."""
    camera = {"xp": 0.01, "yp": -0.01, "c": 8.52}  # distortion 0 in truth, still estimated
    truth, project = _project(tmp_path, seed=17, n_images=10, n_targets=24, noise_px=0.0,
                              image_sigma_px=0.3, camera=camera)
    base = project.problem
    group = base.groups[0]
    sigma = np.asarray(group.stddev)
    plan = jaxba.advanced.linearisation_plan(base)
    noise = np.random.default_rng(2024).normal(size=(REPLICATES, *sigma.shape)) * sigma

    def solve_one(measured):
        problem = eqx.tree_at(lambda p: p.groups[0].measured, base, measured)
        return jaxba.solve(problem, jaxba.advanced.Dense(plan), max_steps=60, rtol=1e-10,
                           atol=1e-10)

    solutions = jax.vmap(solve_one)(group.measured + noise)
    assert bool(jnp.all(solutions.converged))
    redundancy = base.n_observations() - base.n_unknowns()
    variance_factor = 2 * np.asarray(solutions.cost) / redundancy
    # r σ̂0² ~ χ²(r): mean 1, and the distribution as a whole.
    assert abs(variance_factor.mean() - 1) < 4 * math.sqrt(2 / redundancy / REPLICATES)
    assert scipy.stats.kstest(redundancy * variance_factor, "chi2", args=(redundancy,)).pvalue \
        > 0.001
    # The formal σ (σ0 = 1) at the first replicate's solution.
    first = jaxba.precision(eqx.tree_at(lambda p: p.groups[0].measured, base,
                                        group.measured + noise[0]),
                            jax.tree.map(lambda leaf: leaf[0], solutions.parameters))
    formal = np.asarray(first.std.cameras["smac"][0]) / math.sqrt(first.sigma0_squared)
    estimates = np.asarray(solutions.parameters.cameras["smac"][:, 0])
    empirical = estimates.std(axis=0, ddof=1)
    names = jaxba.SmacCamera.parameter_names
    for name in IOPS:
        k = names.index(name)
        assert empirical[k] == pytest.approx(formal[k], rel=MC_STD_RTOL), name
