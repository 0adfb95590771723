"""optimistix's Levenberg-Marquardt with the damped step solved on the normal equations.

`optx.LevenbergMarquardt` materialises the Jacobian (one JVP per unknown) and QR-factorises
the (m + n) x n augmented system at every trial step. `NormalLevenbergMarquardt` keeps
optimistix's loop (`optx.AbstractGaussNewton`, `optx.ClassicalTrustRegion`, Cauchy
termination) but its descent forms JᵀJ and Jᵀe once per accepted iterate from per-row
Jacobian blocks (`_linearisation`) and solves (JᵀJ + λI) δ = -Jᵀe by Cholesky per trial
step. It works on the Jacobi-scaled unknowns z of `solve` (x = x₀ + scale ⊙ z).
"""

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Scalar

from ._cholesky import cholesky_solve
from ._linearisation import LinearisationPlan, normal_equations
from ._problem import BundleProblem, params_from_scaled
from ._trust_region import CERES_INITIAL_RADIUS, CERES_TRUST_REGION, silent

# Stop when the Gauss-Newton step from an accepted iterate would lower the cost by less
# than this fraction of it. Then the unknowns are within √(1e-12 r) σ of the optimum
# (5e-5 σ for r = 2500: ½δᵀNδ = decrement, σ̂0² = 2 cost / r), and the steps that got
# there still changed the cost by far more than its rounding noise (~1e-15 relative), so
# every accept/reject decision, and with it the final iterate, is reproducible.
DECREMENT_TOLERANCE = 1e-12


def _block_size(n: int) -> int:
    """Cholesky block for an n x n system: small blocks run faster under vmap (Zhang's 37
    unknowns, batch 250: 6 ms with 16, 23 ms with 128; 279 unknowns, batch 20: 31 ms with
    32, 145 ms with 128) but unroll more code; at most 8 blocks keeps compiles short."""
    return 16 if n <= 64 else max(32, -(-n // 8))


class _NormalState(eqx.Module):
    normal: Float[Array, "n n"]
    gradient: Float[Array, " n"]
    converged: Bool[Array, ""]  # the Gauss-Newton decrement is below tolerance


class NormalDampedNewtonDescent(
    optx.AbstractDescent[Array, optx.FunctionInfo.ResidualJac, _NormalState]
):
    """The damped Newton step -(JᵀJ + λI)⁻¹ Jᵀe in the scaled unknowns z, λ = 1 /
    (initial_radius · step_size) (`optx.DampedNewtonDescent` for initial_radius 1).

    The descent holds `problem`, `plan` and `scale` because the per-row Jacobian blocks
    are not in `FunctionInfo.ResidualJac` (a matrix-free operator); the residual function
    given to `optx.least_squares` must be `solve`'s, with the same problem and scale.

    Decrement tolerance: once the Gauss-Newton step from an accepted iterate would lower
    the cost ½Σe² by less than `decrement_tolerance` times the cost (½ gᵀN⁻¹g, the
    Newton decrement), the descent proposes the zero step, which optimistix accepts and
    its Cauchy test reads as convergence. Without it (0), at the noise floor of the cost
    every further step is rejected and the solve only ends when the trust region has
    shrunk to nothing (~25 extra steps), at an iterate that depends on rounding.
    """

    problem: BundleProblem
    plan: LinearisationPlan
    scale: Float[Array, " n_free"]
    initial_radius: float = CERES_INITIAL_RADIUS
    decrement_tolerance: float = DECREMENT_TOLERANCE

    def init(self, y: Array, f_info_struct: optx.FunctionInfo.ResidualJac) -> _NormalState:
        n = y.shape[0]
        return _NormalState(jnp.zeros((n, n), y.dtype), jnp.zeros(n, y.dtype),
                            jnp.array(False))

    def query(
        self, y: Array, f_info: optx.FunctionInfo.ResidualJac, state: _NormalState
    ) -> _NormalState:
        del state
        params = params_from_scaled(self.problem, y, self.plan.free_index, self.scale)
        normal, gradient = normal_equations(self.problem, params, self.plan)
        normal = self.scale[:, None] * normal * self.scale[None, :]
        gradient = self.scale * gradient
        # Unknowns no row depends on (padding in a batch) have empty rows: regularise.
        regular = normal + 1e-12 * jnp.max(jnp.diag(normal)) * jnp.eye(normal.shape[0])
        newton = cholesky_solve(regular, gradient, _block_size(gradient.shape[0]))
        converged = 0.5 * gradient @ newton <= self.decrement_tolerance * f_info.as_min()
        return _NormalState(normal, gradient, converged)

    def step(self, step_size: Scalar, state: _NormalState) -> tuple[Array, optx.RESULTS]:
        usable = step_size > jnp.finfo(step_size.dtype).eps
        damping = jnp.where(usable, 1 / (self.initial_radius * jnp.where(usable, step_size, 1)),
                            jnp.finfo(step_size.dtype).max)
        n = state.gradient.shape[0]
        damped = state.normal + damping * jnp.eye(n, dtype=state.normal.dtype)
        step = cholesky_solve(damped, state.gradient, _block_size(n))
        finite = jnp.all(jnp.isfinite(step))
        result = optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.singular)
        return -jnp.where(finite & ~state.converged, step, 0.0), result


class NormalLevenbergMarquardt(optx.AbstractGaussNewton[Array, Array, None]):
    """Levenberg-Marquardt through optimistix with `NormalDampedNewtonDescent` and a
    Ceres-like trust region (`CERES_TRUST_REGION`). Use with `optx.least_squares` on `solve`'s
    residual function of the scaled unknowns (args: problem, free index, scale)."""

    rtol: float
    atol: float
    norm: Callable[[Array], Scalar]
    descent: NormalDampedNewtonDescent
    search: optx.ClassicalTrustRegion
    verbose: Callable[..., None]

    def __init__(
        self,
        problem: BundleProblem,
        plan: LinearisationPlan,
        scale: Float[Array, " n_free"],
        rtol: float,
        atol: float,
        *,
        decrement_tolerance: float = DECREMENT_TOLERANCE,
        verbose: Callable[..., None] | None = None,
    ):
        self.rtol = rtol
        self.atol = atol
        self.norm = optx.max_norm
        self.descent = NormalDampedNewtonDescent(
            problem, plan, scale, decrement_tolerance=decrement_tolerance)
        self.search = CERES_TRUST_REGION
        self.verbose = verbose or silent
