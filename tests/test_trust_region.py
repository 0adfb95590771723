"""jaxba's trust-region loop (`jaxba._solvers._trust_region.LevenbergMarquardt`) on toy problems,
with a dense Gauss-Newton descent: convergence, each stopping rule, non-finite starts, and a
descent whose steps never help (the radius must collapse in a few steps)."""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from jaxba._solvers._trust_region import (
    GAUSS_NEWTON_REGION,
    MIN_RADIUS,
    STEP_TOLERANCE,
    AbstractNormalDescent,
    LevenbergMarquardt,
    finite_step,
)


def rosenbrock(y, args=None):
    """Residuals of Rosenbrock's function: ½|r|² has its minimum 0 at (1, 1)."""
    return jnp.array([10.0 * (y[1] - y[0] ** 2), 1.0 - y[0]])


class DenseDescent(AbstractNormalDescent):
    """Gauss-Newton on a dense Jacobian (`jax.jacfwd`), damped with λ = 1/radius."""

    residual_fn: Callable = eqx.field(static=True)

    def init(self, y, residual):
        return jnp.zeros((y.size, y.size)), jnp.zeros(y.size)

    def query(self, y, residual, state):
        jacobian = jax.jacfwd(self.residual_fn)(y)
        return jacobian.T @ jacobian, jacobian.T @ residual

    def solve(self, damping, state):
        normal, gradient = state
        newton = jnp.linalg.solve(normal + damping * jnp.eye(gradient.size), gradient)
        step, result = finite_step(-newton)
        return step, gradient @ newton, result

    def predicted_reduction(self, y_diff, state):
        normal, gradient = state
        return y_diff @ gradient + 0.5 * y_diff @ (normal @ y_diff)


class UphillDescent(DenseDescent):
    """Damped steps that go the wrong way (the Gauss-Newton step is right), with a model
    that promises a decrease each time."""

    def solve(self, damping, state):
        step, decrement, result = super().solve(damping, state)
        return jnp.where(damping > 0, -step, step), decrement, result

    def predicted_reduction(self, y_diff, state):
        return -jnp.abs(super().predicted_reduction(y_diff, state)) - 1e-300


def _solve(descent, y0, *, max_steps=200, **options):
    solver = LevenbergMarquardt(options.pop("rtol", 1e-12), options.pop("atol", 1e-12),
                                descent, **options)
    return optx.least_squares(rosenbrock, solver, y0, max_steps=max_steps, throw=False)


Y0 = jnp.array([-1.2, 1.0])


def test_converges_on_rosenbrock():
    solution = _solve(DenseDescent(rosenbrock), Y0)
    assert solution.result == optx.RESULTS.successful
    np.testing.assert_allclose(solution.value, [1.0, 1.0], atol=1e-8)
    assert int(solution.stats["num_steps"]) < 60


def offset_rosenbrock(y, args=None):
    """Rosenbrock's residuals and a constant one: the minimum cost is ½, not 0, so relative
    cost changes tend to 0 near it."""
    return jnp.append(rosenbrock(y), 1.0)


def test_function_tolerance_stops_earlier_near_the_minimum():
    def solve(**options):
        solver = LevenbergMarquardt(descent=DenseDescent(offset_rosenbrock), **options)
        return optx.least_squares(offset_rosenbrock, solver, Y0, max_steps=200, throw=False)

    tight = solve(rtol=1e-12, atol=1e-12)
    loose = solve(rtol=0.0, atol=0.0, function_tolerance=1e-6)
    assert tight.result == optx.RESULTS.successful and loose.result == optx.RESULTS.successful
    assert int(loose.stats["num_steps"]) < int(tight.stats["num_steps"])
    np.testing.assert_allclose(loose.value, [1.0, 1.0], atol=1e-2)


def test_gauss_newton_step_within_tau_sigma_ends_the_solve():
    """Stops at the first accepted iterate whose Gauss-Newton step -N⁻¹g moves every unknown
    by at most τ of its σ = √(N⁻¹)_ii (whitened, σ0 = 1), checked on the Jacobian of the
    final iterate; one step less runs out of steps; fewer steps than the tight Cauchy test."""

    def solve(max_steps=200, **options):
        solver = LevenbergMarquardt(descent=DenseDescent(offset_rosenbrock), **options)
        return optx.least_squares(offset_rosenbrock, solver, Y0, max_steps=max_steps,
                                  throw=False)

    statistical = solve(rtol=0.0, atol=0.0, step_tolerance=STEP_TOLERANCE)
    assert statistical.result == optx.RESULTS.successful
    jacobian = jax.jacfwd(offset_rosenbrock)(statistical.value)
    cofactors = jnp.linalg.inv(jacobian.T @ jacobian)
    gauss_newton = -cofactors @ (jacobian.T @ offset_rosenbrock(statistical.value))
    assert np.all(np.abs(gauss_newton) <= STEP_TOLERANCE * np.sqrt(np.diag(cofactors)))
    steps = int(statistical.stats["num_steps"])
    earlier = solve(steps - 1, rtol=0.0, atol=0.0, step_tolerance=STEP_TOLERANCE)
    assert earlier.result == optx.RESULTS.nonlinear_max_steps_reached
    tight = solve(rtol=1e-12, atol=1e-12)
    assert tight.result == optx.RESULTS.successful
    assert steps < int(tight.stats["num_steps"])


def test_cost_rule_stops_where_the_cost_test_and_a_loose_step_test_hold():
    """`gauss_newton=False` with both tolerances (the "cost" stopping rule): damped steps
    until an accepted step changes the cost by at most the function tolerance; there it
    stops only where the Gauss-Newton step is within τ = 1e-3 of every σ (checked on the
    final Jacobian), else takes that step. Rosenbrock's valley passes the cost test far
    from the minimum with a huge function tolerance: the guard keeps the solve going."""

    def solve(**options):
        solver = LevenbergMarquardt(descent=DenseDescent(offset_rosenbrock), rtol=0.0,
                                    atol=0.0, **options)
        return optx.least_squares(offset_rosenbrock, solver, Y0, max_steps=200, throw=False)

    tau = 1e-3
    cost_only = solve(function_tolerance=0.5)
    guarded = solve(function_tolerance=0.5, step_tolerance=tau, gauss_newton=False)
    assert cost_only.result == optx.RESULTS.successful
    assert guarded.result == optx.RESULTS.successful
    assert np.max(np.abs(cost_only.value - 1.0)) > 1e-2  # stopped far from (1, 1)
    jacobian = jax.jacfwd(offset_rosenbrock)(guarded.value)
    cofactors = jnp.linalg.inv(jacobian.T @ jacobian)
    step = -cofactors @ (jacobian.T @ offset_rosenbrock(guarded.value))
    assert np.all(np.abs(step) <= tau * np.sqrt(np.diag(cofactors)))
    assert int(guarded.stats["num_steps"]) > int(cost_only.stats["num_steps"])


LINEAR_A = jnp.array([[2.0, 1.0], [1.0, 3.0], [0.5, -1.0], [1.0, 1.0], [-1.0, 2.0]])
LINEAR_B = jnp.array([1.0, 2.0, 0.5, -1.0, 3.0])


def linear(y, args=None):
    return LINEAR_A @ y - LINEAR_B


def test_gauss_newton_end_game_solves_a_linear_problem_in_one_step():
    """Within `GAUSS_NEWTON_REGION` of the optimum the undamped step is proposed: on a linear
    problem it lands on the least-squares solution, where the step test ends the solve
    (step 0 evaluates the start, step 1 the Gauss-Newton point). Without the test (τ = 0)
    the damped steps (λ = 1e-4 at the start) only approach it."""
    optimum = jnp.linalg.lstsq(LINEAR_A, LINEAR_B)[0]
    offset = jnp.array([0.3, -0.2])
    start = optimum + offset
    assert float(offset @ (LINEAR_A.T @ LINEAR_A) @ offset) <= GAUSS_NEWTON_REGION

    def solve(max_steps, step_tolerance):
        solver = LevenbergMarquardt(0.0, 0.0, DenseDescent(linear),
                                    step_tolerance=step_tolerance)
        return optx.least_squares(linear, solver, start, max_steps=max_steps, throw=False)

    solution = solve(200, STEP_TOLERANCE)
    assert solution.result == optx.RESULTS.successful
    assert int(solution.stats["num_steps"]) == 2
    np.testing.assert_allclose(solution.value, optimum, rtol=0, atol=1e-14)
    damped = solve(2, 0.0)
    assert float(jnp.max(jnp.abs(damped.value - optimum))) > 1e-6


class WrongNewtonDescent(DenseDescent):
    """Damped steps as `DenseDescent`, a Gauss-Newton step that goes the wrong way (its
    decrement is right)."""

    def solve(self, damping, state):
        step, decrement, result = super().solve(damping, state)
        return jnp.where(damping == 0, -step, step), decrement, result


def test_rejected_gauss_newton_step_leaves_the_radius():
    """Far from the optimum the Gauss-Newton step is proposed first; when the trust region
    rejects it, the next trial is the damped step for the same radius (λ = 1e-4 from the
    first radius 1e4), not for a shrunk one: step 0 evaluates the start, step 1 rejects the
    Gauss-Newton point, step 2 accepts the damped one."""
    optimum = jnp.linalg.lstsq(LINEAR_A, LINEAR_B)[0]
    start = optimum + jnp.array([30.0, -20.0])
    assert float((start - optimum) @ (LINEAR_A.T @ LINEAR_A) @ (start - optimum)) > 1e3
    solver = LevenbergMarquardt(0.0, 0.0, WrongNewtonDescent(linear),
                                step_tolerance=STEP_TOLERANCE)
    first = optx.least_squares(linear, solver, start, max_steps=2, throw=False)
    assert int(first.state.num_accepted_steps) == 1  # the start: Gauss-Newton rejected
    np.testing.assert_array_equal(first.value, start)
    solution = optx.least_squares(linear, solver, start, max_steps=3, throw=False)
    normal, gradient = LINEAR_A.T @ LINEAR_A, LINEAR_A.T @ linear(start)
    damped = start - jnp.linalg.solve(normal + jnp.eye(2) / 1e4, gradient)
    assert int(solution.state.num_accepted_steps) == 2  # the start and the damped point
    np.testing.assert_allclose(solution.value, damped, rtol=1e-12)
    converged = optx.least_squares(linear, solver, start, max_steps=200, throw=False)
    assert converged.result == optx.RESULTS.successful
    np.testing.assert_allclose(converged.value, optimum, rtol=0, atol=1e-6)


def test_statistical_test_ends_a_solve_started_at_the_optimum():
    """g = 0 at the start: the step test passes there (the decrement gᵀN⁻¹g is 0), the
    start is the answer."""
    optimum = jnp.array([1.0, 1.0])
    solution = _solve(DenseDescent(rosenbrock), optimum, rtol=0.0, atol=0.0,
                      step_tolerance=STEP_TOLERANCE)
    assert solution.result == optx.RESULTS.successful
    assert int(solution.stats["num_steps"]) == 1
    np.testing.assert_array_equal(solution.value, optimum)


def test_non_finite_start_is_reported():
    solution = _solve(DenseDescent(rosenbrock), jnp.array([jnp.nan, 1.0]))
    assert solution.result == optx.RESULTS.nonfinite
    assert int(solution.stats["num_steps"]) <= 1


def test_steps_that_never_help_collapse_the_radius_quickly():
    """Every trial is rejected: the radius shrinks by 2, 4, 8... (Ceres' doubling decrease
    factor) from 1e4 to below MIN_RADIUS in ~16 steps, and the start is the answer."""
    solution = _solve(UphillDescent(rosenbrock), Y0)
    steps = int(solution.stats["num_steps"])
    assert solution.result == optx.RESULTS.successful
    np.testing.assert_array_equal(solution.value, Y0)
    # k rejections shrink the radius by 2^(k(k+1)/2): 1e4 -> 1e-32 needs k = 16.
    expected = next(k for k in range(1, 100) if 1e4 / 2.0 ** (k * (k + 1) / 2) < MIN_RADIUS)
    assert steps == expected + 1  # + step 0, which evaluates the start
    assert solution.state.num_accepted_steps == 1


@pytest.mark.parametrize("max_steps", [3])
def test_max_steps_is_reported(max_steps):
    solution = _solve(DenseDescent(rosenbrock), Y0, max_steps=max_steps)
    assert solution.result == optx.RESULTS.nonlinear_max_steps_reached
