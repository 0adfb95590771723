"""The Dense backend: Levenberg-Marquardt on the normal equations of all free unknowns (its
statistics' linear algebra: `_dense_statistics.py`)."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._problem._bundle import BundleProblem, params_from_scaled
from .._problem._linearisation import (
    LinearisationPlan,
    dense_jacobian,
    linearisation_plan,
    normal_equations,
)
from ._backend import Backend, LeastSquares, Tolerances
from ._dense_statistics import (
    SINGULAR_VALUE_RTOL,
    dense_cofactors,
    dense_leverages,
    dense_normal_solve,
    jacobian_rank,
)
from ._levenberg_marquardt import UNBATCHED_BLOCK, NormalLevenbergMarquardt


def _residual_fn(z, args):
    problem, index, scale = args
    return problem.residuals(params_from_scaled(problem, z, index, scale)), None


def column_scale(problem: BundleProblem, plan: LinearisationPlan) -> Float[Array, " n_free"]:
    """Jacobi scaling: 1/‖column‖ of the residuals' Jacobian at the approximations.

    The solver works on z with x_free = x_free,0 + scale ⊙ z, so every column has unit
    norm at the start and the Levenberg-Marquardt damping λI treats all unknowns alike.
    Masked residual entries are exactly 0 and add nothing to the norms.
    """
    return scale_from_normal(normal_equations(problem, problem.initial, plan)[0])


def scale_from_normal(normal: Float[Array, "n n"]) -> Float[Array, " n"]:
    """`column_scale` from the normal matrix N = JᵀJ at the approximations: 1/√N_ii (1
    for an empty column)."""
    norms = jnp.sqrt(jnp.diag(normal))
    return 1.0 / jnp.where(norms > 0, norms, 1.0)


class Dense(Backend):
    """All free unknowns in one dense normal matrix (calibrations, batches, vmap): the loop
    runs on the Jacobi-scaled unknowns z (`column_scale`), x_free = x_free,0 + scale ⊙ z,
    each damped step a blocked Cholesky of N + λI (`NormalLevenbergMarquardt`).

    `plan`: `linearisation_plan(problem)`, filled in by `ready` where not given; it must be
    given under `jax.vmap` / `jax.jit`, where the problem's index arrays are traced.
    `block_size`: the Cholesky's block (None: tuned for vmapped batches). `scale`:
    `column_scale`, where the caller has the normal matrix at the approximations already
    (`scale_from_normal`; None: made here)."""

    plan: LinearisationPlan | None = None
    block_size: int | None = eqx.field(static=True, default=None)
    scale: Float[Array, " n_free"] | None = None

    name: ClassVar[str] = "dense"
    tolerance: ClassVar[float] = 1e-8
    top_level: ClassVar[bool] = False
    compiled_setup: ClassVar[bool] = True
    holds_inner_constraints: ClassVar[bool] = True

    def ready(self, problem):
        return self if self.plan is not None else Dense(linearisation_plan(problem),
                                                        self.block_size, self.scale)

    def for_steps(self):
        return Dense(self.plan, UNBATCHED_BLOCK, self.scale)

    def least_squares(self, problem: BundleProblem, tolerances: Tolerances) -> LeastSquares:
        """The column scale is held constant under differentiation (`stop_gradient`): the
        optimum does not depend on it, so its derivative would only cancel."""
        plan = self.plan
        scale = column_scale(problem, plan) if self.scale is None else self.scale
        scale = jax.lax.stop_gradient(scale)
        solver = NormalLevenbergMarquardt(
            problem, plan, scale, tolerances.rtol, tolerances.atol,
            step_tolerance=tolerances.step, function_tolerance=tolerances.function,
            gauss_newton=tolerances.gauss_newton, block_size=self.block_size)
        return LeastSquares(_residual_fn, solver, jnp.zeros_like(scale),
                            (problem, plan.free_index, scale))

    def parameters(self, problem, args, value):
        _, index, scale = args
        return params_from_scaled(problem, value, index, scale)

    def rank(self, problem, *, rtol: float = SINGULAR_VALUE_RTOL):
        """`jacobian_rank` of the dense Jacobian at the approximations (`rtol`: its
        threshold on the singular values)."""
        return jacobian_rank(np.asarray(dense_jacobian(problem, problem.initial)[0]),
                             rtol=rtol)

    def cofactors(self, problem, params):
        return dense_cofactors(problem, params)

    def leverages(self, problem, params):
        return dense_leverages(problem, params)

    def normal_solve(self, problem, params, rhs):
        return dense_normal_solve(problem, params, rhs)


def equilibrated(normal: Float[Array, "n n"], real: Bool[Array, " n"] | None = None
                 ) -> tuple[Float[Array, "n n"], Float[Array, " n"]]:
    """(D N D, D) with D = 1/‖column‖ (0 for an unknown that is not `real`, padding in a
    batch, or unobserved), those unknowns' (zero) block replaced by I so that they drop
    out. `real`: default all."""
    real = jnp.ones(normal.shape[0], bool) if real is None else real
    norms = jnp.sqrt(jnp.diag(normal))
    scale = jnp.where(real & (norms > 0), 1.0 / jnp.where(norms > 0, norms, 1.0), 0.0)
    return normal * scale[:, None] * scale[None, :] + jnp.diag(jnp.where(real, 0.0, 1.0)), scale


def cofactors(normal: Float[Array, "n n"], real: Bool[Array, " n"] | None = None
              ) -> Float[Array, "n n"]:
    """Q = N⁻¹ of the normal matrix N = JᵀJ (n x n) by Cholesky of the equilibrated
    D N D (`equilibrated`): Q = D (D N D)⁻¹ D, 0 on the unknowns that are not `real`. A jax
    function: inside a batch's program, vmapped, and differentiable."""
    scaled, scale = equilibrated(normal, real)
    inverse = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(scaled),
                                         jnp.eye(normal.shape[0], dtype=normal.dtype))
    return scale[:, None] * inverse * scale[None, :]
