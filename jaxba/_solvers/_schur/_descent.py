"""The Schur backend: the damped step of a `BundleProblem` by the Schur complement of its
normal equations (`_assembly.py`) and the model's predicted reduction, inside jaxba's
Levenberg-Marquardt (`jaxba._solvers._solve.solve` runs it); its rank, cofactors and
leverages from the same split (`_null_space.py`, `_cofactors.py`, `_leverages.py`)."""

from typing import ClassVar

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Scalar

from ..._problem._bundle import BundleProblem
from ..._problem._parameters import Parameters
from .._backend import Backend, LeastSquares, Tolerances
from .._trust_region import (
    AbstractNormalDescent,
    LevenbergMarquardt,
    normal_equations_result,
)
from ._assembly import BundleNormalEquations, bundle_normal_equations, zero_normal_equations
from ._columns import at_columns, reduced_vector, to_parameters
from ._leverages import schur_cofactors, schur_cofactors_ahead, schur_leverages
from ._null_space import schur_rank
from ._reduced_solve import schur_solve, solve_bundle_damped
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
    """The residuals the solver minimises at the full Parameters tree `y`."""
    return problem.residuals(problem.with_free(y))


def _residual_fn(y: Parameters, problem: BundleProblem):
    return bundle_residuals(y, problem), None


class Schur(Backend):
    """The object points eliminated (`BundleSchurDescent`): blocks of any size, no dense
    Jacobian; the loop runs on the full Parameters tree (fixed unknowns step 0).

    `structure`: `bundle_structure(problem)`, filled in by `ready` where not given (NumPy
    from the problem's indices: not vmappable). `gauge`: booleans like `problem.free`, True
    on free unknowns of a minimal datum that only the Gauss-Newton steps hold
    (`BundleSchurDescent.gauge`; the solution is then in no particular datum); None: none."""

    structure: BundleStructure | None = None
    gauge: Parameters | None = None

    name: ClassVar[str] = "schur"
    tolerance: ClassVar[float] = 1e-10
    top_level: ClassVar[bool] = True
    compiled_setup: ClassVar[bool] = False
    holds_inner_constraints: ClassVar[bool] = False  # a row over every point: no blocks
    releases_gauge: ClassVar[bool] = True

    def ready(self, problem):
        if self.structure is not None:
            return self
        return Schur(bundle_structure(problem), self.gauge)

    def least_squares(self, problem: BundleProblem, tolerances: Tolerances) -> LeastSquares:
        solver = LevenbergMarquardt(
            tolerances.rtol, tolerances.atol,
            BundleSchurDescent(problem, self.structure, gauge=self.gauge),
            step_tolerance=tolerances.step, function_tolerance=tolerances.function,
            gauss_newton=tolerances.gauss_newton)
        return LeastSquares(_residual_fn, solver, problem.initial, problem)

    def parameters(self, problem, args, value):
        return problem.with_free(value)

    def released_gauge(self, gauge):
        return Schur(gauge=gauge)

    def rank(self, problem):
        return schur_rank(problem, self.structure)

    def cofactors(self, problem, params):
        """With the leverages and the whitened residuals: one program for all."""
        return schur_cofactors(problem, self.structure, params)

    def cofactors_ahead(self, problem):
        schur_cofactors_ahead(problem, self.structure)

    def leverages(self, problem, params):
        return schur_leverages(problem, self.structure, params)

    def normal_solve(self, problem, params, rhs):
        return schur_solve(problem, params, rhs, structure=self.structure)
