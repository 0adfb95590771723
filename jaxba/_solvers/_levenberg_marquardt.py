"""Levenberg-Marquardt with the damped step solved on the normal equations.

`optx.LevenbergMarquardt` materialises the Jacobian (one JVP per unknown) and QR-factorises
the (m + n) x n augmented system at every trial step. `NormalDampedNewtonDescent` forms JᵀJ
and Jᵀe once per accepted iterate from per-row Jacobian blocks (`_linearisation`) and
solves (JᵀJ + λI) δ = -Jᵀe by Cholesky per trial step, inside jaxba's trust-region loop
(`_trust_region.LevenbergMarquardt`, an optimistix solver). It works on the Jacobi-scaled
unknowns z of `solve` (x = x₀ + scale ⊙ z).
"""

import equinox as eqx
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float, Scalar

from .._problem._bundle import BundleProblem, params_from_scaled
from .._problem._linearisation import LinearisationPlan, normal_equations
from ._cholesky import cholesky_solve
from ._trust_region import (
    STEP_TOLERANCE,
    AbstractNormalDescent,
    LevenbergMarquardt,
    finite_step,
)

# Cholesky block of a solve that is not vmapped (one problem stepped from Python): fewer,
# bigger blocks halve the compilation of the step (lab, 350 unknowns: 6.4 s against 13.8 s
# with `_block_size`'s 44, on a loaded machine) for ~40 ms more per solve.
UNBATCHED_BLOCK = 128


def _block_size(n: int) -> int:
    """Cholesky block for an n x n system: small blocks run faster under vmap (Zhang's 37
    unknowns, batch 250: 6 ms with 16, 23 ms with 128; 279 unknowns, batch 20: 31 ms with
    32, 145 ms with 128) but unroll more code; at most 8 blocks keeps compiles short."""
    return 16 if n <= 64 else max(32, -(-n // 8))


class _NormalState(eqx.Module):
    normal: Float[Array, "n n"]
    gradient: Float[Array, " n"]


class NormalDampedNewtonDescent(AbstractNormalDescent[Array, _NormalState]):
    """The damped Newton step -(JᵀJ + λI)⁻¹ Jᵀe in the scaled unknowns z, λ = 1/radius.

    The descent holds `problem`, `plan` and `scale`: the residual function given to
    `optx.least_squares` must be `solve`'s, with the same problem and scale.

    `block_size`: of the blocked Cholesky (None: `_block_size`, tuned for vmapped batches).
    """

    problem: BundleProblem
    plan: LinearisationPlan
    scale: Float[Array, " n_free"]
    block_size: int | None = eqx.field(static=True, default=None)

    def _block(self, n: int) -> int:
        return _block_size(n) if self.block_size is None else min(self.block_size, n)

    def init(self, y: Array, residual) -> _NormalState:
        n = y.shape[0]
        return _NormalState(jnp.zeros((n, n), y.dtype), jnp.zeros(n, y.dtype))

    def query(self, y: Array, residual, state: _NormalState) -> _NormalState:
        del residual, state
        params = params_from_scaled(self.problem, y, self.plan.free_index, self.scale)
        normal, gradient = normal_equations(self.problem, params, self.plan)
        normal = self.scale[:, None] * normal * self.scale[None, :]
        return _NormalState(normal, self.scale * gradient)

    def solve(self, damping: Scalar, state: _NormalState) -> tuple[Array, Scalar, optx.RESULTS]:
        """-(N + λI)⁻¹g by Cholesky, gᵀ(N + λI)⁻¹g and whether the step is finite. For
        λ = 0 (Gauss-Newton) unknowns no row depends on (padding in a batch) have empty
        rows, regularised by 1e-12 of N's largest diagonal entry instead."""
        normal, gradient = state.normal, state.gradient
        n = gradient.shape[0]
        shift = jnp.where(damping > 0, damping, 1e-12 * jnp.max(jnp.diag(normal)))
        newton = cholesky_solve(normal + shift * jnp.eye(n, dtype=normal.dtype), gradient,
                                self._block(n))
        step, result = finite_step(-newton)
        return step, gradient @ newton, result

    def predicted_reduction(self, y_diff: Array, state: _NormalState) -> Scalar:
        return y_diff @ state.gradient + 0.5 * y_diff @ (state.normal @ y_diff)


class NormalLevenbergMarquardt(LevenbergMarquardt):
    """Levenberg-Marquardt with `NormalDampedNewtonDescent` and Ceres' trust region. Use with
    `optx.least_squares` on `solve`'s residual function of the scaled unknowns (args:
    problem, free index, scale). `step_tolerance`, `function_tolerance`, `gauss_newton`: the
    trust-region loop's statistical and cost-change tests (`jaxba._solvers._trust_region`)."""

    def __init__(
        self,
        problem: BundleProblem,
        plan: LinearisationPlan,
        scale: Float[Array, " n_free"],
        rtol: float,
        atol: float,
        *,
        step_tolerance: float = STEP_TOLERANCE,
        function_tolerance: float = 0.0,
        gauss_newton: bool = True,
        block_size: int | None = None,
    ):
        super().__init__(rtol, atol, NormalDampedNewtonDescent(problem, plan, scale, block_size),
                         step_tolerance=step_tolerance, function_tolerance=function_tolerance,
                         gauss_newton=gauss_newton)
