"""Solve a bundle with optimistix Levenberg-Marquardt and report honestly."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ._datum import check_datum
from ._parameters import Parameters, flatten, unflatten
from ._problem import BundleProblem, dense_jacobian, free_indices
from ._progress import Iteration, StepRecorder, listening, report_step
from ._statistics import Precision, precision


class NotConvergedError(RuntimeError):
    """The adjustment stopped without meeting its convergence criteria."""


@dataclasses.dataclass(frozen=True)
class Adjustment:
    """The outcome of `adjust`.

    - `parameters`: adjusted unknowns (fixed ones at their given values);
    - `precision`: σ̂0², redundancy, covariance and σ of every unknown;
    - `residuals`: per observation group, v = observed - computed in the observation's
      units (masked entries 0), same shapes as the group's residuals;
    - `iterations`: every accepted iterate with its cost ½Σe² and σ̂0²;
    - `converged`, `message`, `steps` (solver steps, rejected ones included).
    """

    problem: BundleProblem
    parameters: Parameters
    precision: Precision
    residuals: tuple[np.ndarray, ...]
    iterations: list[Iteration]
    converged: bool
    message: str
    steps: int

    @property
    def sigma0(self) -> float:
        """A posteriori σ̂0."""
        return float(np.sqrt(self.precision.sigma0_squared))


def _column_scale(problem: BundleProblem) -> Parameters:
    """Jacobi scaling: 1/‖column‖ of the whitened Jacobian for free unknowns, 0 for fixed.

    The solver works on z with x = x₀ + scale ⊙ z, so every column has unit norm at the
    approximations and the Levenberg-Marquardt damping λI treats all unknowns alike.
    """
    jacobian, _ = dense_jacobian(problem, problem.initial)
    norms = np.linalg.norm(np.asarray(jacobian), axis=0)
    scale = np.zeros(flatten(problem.initial).shape)
    scale[free_indices(problem)] = 1.0 / np.where(norms > 0, norms, 1.0)
    return unflatten(problem.initial, scale)


def _residual_fn(z: Parameters, args: tuple[BundleProblem, Parameters]):
    problem, scale = args
    params = jax.tree.map(lambda x0, s, dz: x0 + s * dz, problem.initial, scale, z)
    return problem.residuals(params), None


@eqx.filter_jit
def _solve(problem: BundleProblem, scale: Parameters, max_steps: int, rtol: float, atol: float):
    solver = optx.LevenbergMarquardt(
        rtol=rtol, atol=atol, linear_solver=lx.QR(), verbose=report_step
    )
    z0 = jax.tree.map(jnp.zeros_like, problem.initial)
    solution = optx.least_squares(
        _residual_fn, solver, z0, args=(problem, scale), has_aux=True,
        max_steps=max_steps, throw=False,
    )
    params = jax.tree.map(lambda x0, s, dz: x0 + s * dz, problem.initial, scale, solution.value)
    return params, solution.result, solution.stats["num_steps"]


def adjust(
    problem: BundleProblem,
    *,
    sigma0: float = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    labels: list[str] | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
    throw: bool = False,
) -> Adjustment:
    """Adjust `problem` by Levenberg-Marquardt (optx.least_squares, dense QR).

    The datum is checked first (`DatumError` names the unobservable directions, using
    `labels`, one per scalar unknown in `flatten` order). `on_iteration` is called for
    every accepted iterate. With `throw=True` a non-converged solve raises
    `NotConvergedError`; otherwise `converged` and `message` say what happened.
    """
    check_datum(problem, labels=labels)
    redundancy = problem.n_observations() - problem.n_unknowns()
    recorder = StepRecorder(redundancy, sigma0, on_iteration)
    scale = _column_scale(problem)
    with listening(recorder):
        params, result, steps = _solve(problem, scale, max_steps, rtol, atol)
        params = jax.block_until_ready(params)
    whitened = problem.residuals(params)
    final_cost = 0.5 * sum(float(jnp.sum(e**2)) for e in whitened)
    if not np.isfinite(final_cost):
        raise NotConvergedError("the adjustment produced non-finite residuals (NaN or inf)")
    recorder.finish(final_cost)
    converged = result == optx.RESULTS.successful
    message = "converged" if converged else optx.RESULTS[result]
    if throw and not converged:
        raise NotConvergedError(f"no convergence after {int(steps)} steps: {message}")
    residuals = tuple(
        np.asarray(e) * np.where(np.asarray(g.mask()), np.asarray(g.sigma()), 0.0)
        for e, g in zip(whitened, problem.groups)
    )
    return Adjustment(
        problem=problem,
        parameters=params,
        precision=precision(problem, params, sigma0=sigma0),
        residuals=residuals,
        iterations=recorder.iterations,
        converged=bool(converged),
        message=str(message),
        steps=int(steps),
    )
