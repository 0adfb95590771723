"""The step-by-step driver: the same iterates as optx.least_squares, and no host callback in
the compiled step (so jax's persistent compilation cache can store it)."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from test_trust_region import DenseDescent, rosenbrock

import jaxba
from jaxba._solvers._steps import StepInfo, _step, least_squares_stepwise
from jaxba._solvers._trust_region import LevenbergMarquardt


def _rosenbrock(y, args):
    return rosenbrock(y), None


def _solver():
    return LevenbergMarquardt(rtol=1e-12, atol=1e-12, descent=DenseDescent(rosenbrock))


def _lab_problem(tmp_path):
    truth = jaxba.write_synthetic_project(tmp_path, n_images=6, n_targets=30, seed=3)
    del truth
    return jaxba.build_project(jaxba.read_project(tmp_path / "lab.toml")).problem


def test_dense_solve_stepwise_equals_the_compiled_loop(tmp_path):
    problem = _lab_problem(tmp_path)
    steps: list[StepInfo] = []
    stepwise = jaxba.solve(problem, on_step=steps.append)
    whole = jaxba.solve(problem)
    assert bool(stepwise.converged) and bool(whole.converged)
    assert int(stepwise.steps) == int(whole.steps) == len(steps)
    assert [s.step for s in steps] == list(range(len(steps)))
    assert steps[0].accepted and steps[-1].accepted
    assert steps[-1].cost == pytest.approx(float(whole.cost), rel=1e-12)
    for a, b in zip(jax.tree.leaves(stepwise.parameters), jax.tree.leaves(whole.parameters)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_max_steps_and_nonfinite_results_follow_optimistix():
    solver = _solver()
    y0 = jnp.array([-1.2, 1.0])
    for max_steps in (1, 3):
        mine = least_squares_stepwise(_rosenbrock, solver, y0, None, has_aux=True,
                                      max_steps=max_steps)
        theirs = optx.least_squares(_rosenbrock, solver, y0, has_aux=True,
                                    max_steps=max_steps, throw=False)
        assert mine.result == theirs.result == optx.RESULTS.nonlinear_max_steps_reached
        assert int(mine.stats["num_steps"]) == int(theirs.stats["num_steps"]) == max_steps
        np.testing.assert_array_equal(mine.value, theirs.value)
    bad = jnp.array([jnp.nan, 1.0])
    mine = least_squares_stepwise(_rosenbrock, solver, bad, None, has_aux=True, max_steps=20)
    theirs = optx.least_squares(_rosenbrock, solver, bad, has_aux=True, max_steps=20,
                                throw=False)
    assert mine.result == theirs.result
    assert mine.result != optx.RESULTS.successful
    assert int(mine.stats["num_steps"]) == int(theirs.stats["num_steps"])


def test_compiled_step_has_no_host_callback():
    solver = _solver()
    y0 = jnp.array([-1.2, 1.0])
    state = jax.eval_shape(lambda: solver.init(
        _rosenbrock, y0, None, {}, jax.ShapeDtypeStruct((2,), y0.dtype), None, frozenset()))
    state = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), state)
    text = _step.__wrapped__.lower(_rosenbrock, solver, y0, None, state).as_text()
    assert "stablehlo" in text and "callback" not in text
