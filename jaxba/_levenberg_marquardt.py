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
from jaxtyping import Array, Bool, Float, Scalar

from ._cholesky import cholesky_solve
from ._linearisation import LinearisationPlan, normal_equations
from ._problem import BundleProblem, params_from_scaled
from ._trust_region import AbstractNormalDescent, LevenbergMarquardt, finite_step

# Stop when the Gauss-Newton step from an accepted iterate would lower the cost by less
# than this fraction of it. Then the unknowns are within √(1e-12 r) σ of the optimum
# (5e-5 σ for r = 2500: ½δᵀNδ = decrement, σ̂0² = 2 cost / r), and the steps that got
# there still changed the cost by far more than its rounding noise (~1e-15 relative), so
# every accept/reject decision, and with it the final iterate, is reproducible.
DECREMENT_TOLERANCE = 1e-12


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
    converged: Bool[Array, ""]  # the Gauss-Newton decrement is below tolerance


class NormalDampedNewtonDescent(AbstractNormalDescent[Array, _NormalState]):
    """The damped Newton step -(JᵀJ + λI)⁻¹ Jᵀe in the scaled unknowns z, λ = 1/radius.

    The descent holds `problem`, `plan` and `scale`: the residual function given to
    `optx.least_squares` must be `solve`'s, with the same problem and scale.

    Decrement tolerance: an accepted iterate from which the Gauss-Newton step would lower
    the cost ½Σe² by less than `decrement_tolerance` times the cost (½ gᵀN⁻¹g, the Newton
    decrement) is converged. Without it (0), the solve ends on the Cauchy test, or at the
    noise floor of the cost once every further step is rejected and the trust region has
    shrunk below its minimum, at an iterate that depends on rounding.

    `block_size`: of the blocked Cholesky (None: `_block_size`, tuned for vmapped batches).
    """

    problem: BundleProblem
    plan: LinearisationPlan
    scale: Float[Array, " n_free"]
    decrement_tolerance: float = DECREMENT_TOLERANCE
    block_size: int | None = eqx.field(static=True, default=None)

    def _block(self, n: int) -> int:
        return _block_size(n) if self.block_size is None else min(self.block_size, n)

    def init(self, y: Array, residual) -> _NormalState:
        n = y.shape[0]
        return _NormalState(jnp.zeros((n, n), y.dtype), jnp.zeros(n, y.dtype),
                            jnp.array(False))

    def query(self, y: Array, residual, cost: Scalar, state: _NormalState) -> _NormalState:
        del residual, state
        params = params_from_scaled(self.problem, y, self.plan.free_index, self.scale)
        normal, gradient = normal_equations(self.problem, params, self.plan)
        normal = self.scale[:, None] * normal * self.scale[None, :]
        gradient = self.scale * gradient
        # Unknowns no row depends on (padding in a batch) have empty rows: regularise.
        regular = normal + 1e-12 * jnp.max(jnp.diag(normal)) * jnp.eye(normal.shape[0])
        newton = cholesky_solve(regular, gradient, self._block(gradient.shape[0]))
        converged = 0.5 * gradient @ newton <= self.decrement_tolerance * cost
        return _NormalState(normal, gradient, converged)

    def step(self, radius: Scalar, state: _NormalState) -> tuple[Array, optx.RESULTS]:
        n = state.gradient.shape[0]
        damped = state.normal + jnp.eye(n, dtype=state.normal.dtype) / radius
        return finite_step(-cholesky_solve(damped, state.gradient, self._block(n)))

    def predicted_reduction(self, y_diff: Array, state: _NormalState) -> Scalar:
        return y_diff @ state.gradient + 0.5 * y_diff @ (state.normal @ y_diff)

    def converged(self, state: _NormalState) -> Bool[Array, ""]:
        return state.converged


class NormalLevenbergMarquardt(LevenbergMarquardt):
    """Levenberg-Marquardt with `NormalDampedNewtonDescent` and Ceres' trust region. Use with
    `optx.least_squares` on `solve`'s residual function of the scaled unknowns (args:
    problem, free index, scale)."""

    def __init__(
        self,
        problem: BundleProblem,
        plan: LinearisationPlan,
        scale: Float[Array, " n_free"],
        rtol: float,
        atol: float,
        *,
        decrement_tolerance: float = DECREMENT_TOLERANCE,
        block_size: int | None = None,
    ):
        super().__init__(rtol, atol, NormalDampedNewtonDescent(
            problem, plan, scale, decrement_tolerance, block_size))
