"""The Schur backend's Levenberg-Marquardt: the damped step of a `BundleProblem` by the Schur
complement of its normal equations (`_bundle.py`), the model's predicted reduction, and
the solve."""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Int, Scalar

from ..._problem._bundle import BundleProblem
from ..._problem._parameters import Parameters
from .._compiled import solver_jit
from .._solution import Solution
from .._steps import StepInfo, least_squares_stepwise
from .._trust_region import (
    STEP_TOLERANCE,
    AbstractNormalDescent,
    LevenbergMarquardt,
    normal_equations_result,
)
from ._assembly import BundleNormalEquations, bundle_normal_equations, zero_normal_equations
from ._columns import at_columns, reduced_vector, to_parameters
from ._reduced_solve import solve_bundle_damped
from ._structure import BundleStructure, bundle_structure


def bundle_predicted_reduction(
    structure: BundleStructure, normal: BundleNormalEquations, step: Parameters
) -> Scalar:
    """δᵀJᵀe + ½ δᵀJᵀJδ for the step δ (a Parameters tree): the Gauss-Newton model's change
    of ½|e|², with δᵀJᵀJδ = δ_rᵀUδ_r + Σ δ_eᵀVδ_e + 2 Σ_i δ_r,iᵀ W_i δ_e,i."""
    x_r = reduced_vector(structure, step)
    x_e = step.points[structure.eliminated_points]
    x_r_padded = jnp.append(x_r, jnp.zeros((), x_r.dtype))
    x_e_padded = jnp.concatenate([x_e, jnp.zeros((1, 3), x_e.dtype)])
    # One einsum (as in `_normal.predicted_reduction`: gathered products summed run slowly).
    coupled = jnp.einsum("ncm,nm,nc->", normal.coupling, at_columns(structure, x_r_padded),
                         x_e_padded[structure.image_point])
    quadratic = (
        x_r @ (normal.reduced_hessian @ x_r)
        + jnp.sum(x_e * jnp.sum(normal.point_hessian * x_e[:, None, :], axis=2))
        + 2.0 * coupled
    )
    linear = x_r @ normal.reduced_gradient + jnp.sum(x_e * normal.point_gradient)
    return linear + 0.5 * quadratic


class BundleSchurDescent(
    AbstractNormalDescent[Parameters, tuple[BundleNormalEquations, optx.RESULTS]]
):
    """Damped Newton step -(JᵀJ + λD)⁻¹ Jᵀe, λ = 1/radius, of a `BundleProblem` by the
    Schur complement (see the module docstring). y is the full Parameters tree; fixed
    unknowns get a zero step.

    `gauge`: booleans like `problem.free`, True on the unknowns of a minimal datum that the
    damped steps
    move with the rest (the damping fixes the gauge, as Ceres on BAL's problems) and the
    Gauss-Newton step (λ = 0), whose N is singular along the gauge, holds: its step and
    gᵀN⁻¹g are those of the problem with the datum fixed (gᵀN⁻¹g is the same in any datum:
    g is orthogonal to the gauge's directions). None: no gauge released."""

    problem: BundleProblem
    structure: BundleStructure
    min_diagonal: float = 1e-6
    max_diagonal: float = 1e32
    gauge: Parameters | None = None

    def init(self, y: Parameters, residual) -> tuple[BundleNormalEquations, optx.RESULTS]:
        # Zeros shaped from the structure: `jax.eval_shape(self._normal, y)` traced the
        # normal equations once more in every process (0.3-0.6 s on a 60-image block).
        return zero_normal_equations(self.structure, y.images.dtype), optx.RESULTS.successful

    def query(self, y: Parameters, residual, state):
        """The normal equations at `y` and whether they are finite (checked once here)."""
        del residual, state
        normal = self._normal(y)
        return normal, normal_equations_result(normal)

    def solve(self, damping: Scalar, state):
        """x = (N + λD)⁻¹g by the Schur complement: the step -x, gᵀx and whether the
        normal equations were finite (fixed unknowns have zero gradient and step)."""
        normal, result = state
        held = None if self.gauge is None else (
            reduced_vector(self.structure, self.gauge).astype(normal.reduced_gradient.dtype)
            * (damping == 0))
        x_r, x_e = solve_bundle_damped(self.structure, normal, damping, held)
        decrement = x_r @ normal.reduced_gradient + jnp.sum(x_e * normal.point_gradient)
        return self._parameters(-x_r, -x_e), decrement, result

    def _parameters(self, x_r, x_e) -> Parameters:
        step = to_parameters(self.structure, self.problem.initial, x_r, x_e)
        return jax.tree.map(lambda s, f: jnp.where(f, s, 0.0), step, self.problem.free)

    def predicted_reduction(self, y_diff: Parameters, state) -> Scalar:
        return bundle_predicted_reduction(self.structure, state[0], y_diff)

    def _normal(self, y: Parameters) -> BundleNormalEquations:
        return bundle_normal_equations(
            self.problem, self.structure, y, self.min_diagonal, self.max_diagonal
        )


def bundle_residuals(y: Parameters, problem: BundleProblem) -> tuple[Array, ...]:
    """`fn(y, args)` for `optx.least_squares`: the residuals the solver minimises."""
    return problem.residuals(problem.with_free(y))


def _make_schur_solver(problem, structure, *, rtol, atol, step_tolerance, function_tolerance,
                       gauge=None):
    return LevenbergMarquardt(
        rtol, atol, BundleSchurDescent(problem, structure, gauge=gauge),
        step_tolerance=step_tolerance, function_tolerance=function_tolerance)


def _make_schur_solution(problem, solution: optx.Solution) -> Solution:
    return Solution(
        parameters=problem.with_free(solution.value),
        converged=solution.result == optx.RESULTS.successful,
        steps=solution.stats["num_steps"],
        accepted_steps=solution.state.num_accepted_steps,
        cost=solution.state.cost,  # ½Σẽ² at the final (accepted) iterate
        result=solution.result,
    )


_schur_solution = eqx.filter_jit(_make_schur_solution)


@solver_jit
def _solve_schur(problem, structure, *, max_steps, **settings):
    solver = _make_schur_solver(problem, structure, **settings)
    solution = optx.least_squares(
        bundle_residuals, solver, problem.initial, args=problem, max_steps=max_steps, throw=False
    )
    return _make_schur_solution(problem, solution)


def solve_schur(
    problem: BundleProblem,
    free_index: Int[Array, " n_free"] | None = None,
    *,
    max_steps: int = 50,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    step_tolerance: float = STEP_TOLERANCE,
    function_tolerance: float = 0.0,
    structure: BundleStructure | None = None,
    on_step: Callable[[StepInfo], None] | None = None,
    gauge: Parameters | None = None,
) -> Solution:
    """Levenberg-Marquardt on `problem` with the points eliminated (Schur complement).
    Converged as `solve`: at an accepted iterate from which the Gauss-Newton step would move
    every unknown by less than `step_tolerance` of its σ (gᵀN⁻¹g ≤ τ²,
    `jaxba._solvers._trust_region`, with its Gauss-Newton steps; 0: both off), where an
    accepted step lowered the cost by at most `function_tolerance` of it (0: off; BAL's
    gauge-free problems, whose N is singular, stop this way as Ceres does), or where
    optimistix's Cauchy test (`rtol`, `atol`) passes.

    Same return type as `jaxba.solve` (`Solution`: parameters, converged, steps, cost ½Σẽ²,
    result). `free_index` is accepted for signature compatibility with `solve` and not
    used: the free unknowns are `problem.free`. Not vmappable (the split is computed in
    NumPy from the problem's indices; pass `structure=bundle_structure(problem)` to reuse
    it). As for `solve`: without `on_step` one compiled `optx.least_squares`; with it, one
    compiled step at a time, `on_step(StepInfo)` hearing every step.
    Memory O(n_obs m + n_r²), no dense Jacobian; n_r = IOPs + 6 n_images + 3 ×
    distance points. `gauge`: booleans like `problem.free`, True on free unknowns of a
    minimal datum that only the Gauss-Newton steps hold (`BundleSchurDescent.gauge`; the
    solution is then in no particular datum); None: none.
    """
    del free_index
    if structure is None:
        structure = bundle_structure(problem)
    # The tolerances as arrays, traced: solves that differ only in them share one compiled
    # program. step_tolerance stays static: whether it is 0 decides what is compiled.
    # device_put: jnp.asarray compiled a program to stage a Python float.
    settings = dict(rtol=jax.device_put(rtol), atol=jax.device_put(atol),
                    step_tolerance=step_tolerance,
                    function_tolerance=jax.device_put(function_tolerance))
    if gauge is not None:
        settings["gauge"] = gauge
    if on_step is None:
        return _solve_schur(problem, structure, max_steps=max_steps, **settings)
    solver = _make_schur_solver(problem, structure, **settings)
    solution = least_squares_stepwise(
        bundle_residuals, solver, problem.initial, problem, max_steps=max_steps,
        on_step=on_step)
    return _schur_solution(problem, solution)
