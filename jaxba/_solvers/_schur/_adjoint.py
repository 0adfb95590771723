"""The adjusted bundle as a differentiable function of its data, on the Schur backend.

The implicit function theorem at the optimum x̂(θ) of ½‖e(x, θ)‖², g(x̂, θ) = ∇ₓ ½‖e‖² = 0,
gives dx̂/dθ = -H⁻¹ ∂g/∂θ with H = ∂g/∂x the full Hessian (JᵀJ plus the residuals'
curvature Σ e_k ∇²e_k). `schur_adjusted` solves forward with the Schur backend's
Levenberg-Marquardt (`solve` with the `Schur` backend) and hands x̂ to
optimistix's `implicit_jvp` (what `optx.ImplicitAdjoint` runs; called directly so that the
linear solver can carry a preconditioner built at x̂, which an adjoint's solver, made before
the solve and given no options, cannot). Its linear systems H v = w (one per tangent, or per
cotangent in reverse mode) are solved by `SchurPreconditionedCG`: conjugate gradients on the
matrix-free H (a Hessian-vector product is one forward-over-reverse pass through the
residuals), preconditioned by the Gauss-Newton normal matrix N = JᵀJ at x̂, applied through
the Schur split (`GaussNewtonFactor`: V⁻¹ per point, the reduced camera matrix
S = U - W V⁻¹ Wᵀ factored once). No n x n matrix and no Jacobian is formed: the largest
arrays are S (n_r x n_r) and the per-observation blocks of the normal equations.

Why CG preconditioned by N rather than a direct solve with H: H has the block sparsity of N
(the curvature of observation i couples only the IOPs, EOPs and point it touches), so a
Schur solve of H itself would be exact in one pass, but it needs every observation's
second derivatives assembled into the backend's blocks: a second assembly next to the
normal equations. N⁻¹H = I + N⁻¹ Σ e_k ∇²e_k differs from I by terms of the size of the
residuals relative to the curvature of the model, small at a well-fitting optimum, so
preconditioned CG converges in a handful of iterations (each one Hessian-vector product and
one Schur back-substitution), and it is exact to its tolerance whatever the fit: the
preconditioner only sets the speed. The tolerance is measured in N's metric,
‖r‖_N⁻¹ ≤ rtol ‖b‖_N⁻¹ (the same metric as the trust region's statistical test), so it does
not depend on the units of the unknowns, unlike lineax `CG`'s elementwise test, which needs
every entry of the residual below an absolute tolerance where the right-hand side is 0 (a
cotangent on a few IOPs is 0 almost everywhere).

Fixed unknowns: the residuals ignore them (`BundleProblem.with_free`), so ∇ₓ½‖e‖² is 0 and
H singular there; the optimality condition given to `implicit_jvp` is x on those entries
instead (H gets a unit diagonal, their derivative is 0, as N's unit diagonal in the
backend). The dependence of x̂ on the fixed values (control, datum) flows through g.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Float, Int, PyTree, Scalar
from optimistix.internal import implicit_jvp

from ..._problem._bundle import BundleProblem
from ..._problem._parameters import Parameters
from .._solve import solve, stop_gradient
from .._trust_region import STEP_TOLERANCE
from ._assembly import bundle_normal_equations, schur_complement
from ._columns import add_at_columns, at_columns, free_masks, reduced_vector, to_parameters
from ._descent import Schur, bundle_residuals
from ._normal import matvec, small_inverse
from ._structure import BundleStructure

# ‖r‖_N⁻¹ ≤ CG_RTOL ‖b‖_N⁻¹: the adjoint's solution to ~1e-10 of its size in N's metric,
# far below the 1e-8 to which derivatives are compared (tests/test_differentiable.py).
CG_RTOL = 1e-10
CG_MAX_STEPS = 100
HESSIAN_TAGS = frozenset({lx.symmetric_tag, lx.positive_semidefinite_tag})


def _tree_dot(a: PyTree[Array], b: PyTree[Array]) -> Scalar:
    return sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


class GaussNewtonFactor(eqx.Module):
    """N = JᵀJ of a bundle at a point, factored through the Schur split for repeated
    solves N x = r (`solve`): the points' V⁻¹ (n_e, 3, 3), the Cholesky factor of the
    Jacobi-equilibrated reduced camera matrix D S D (n_r, n_r, lower; `scale` D), the
    coupling blocks W and the free masks. Fixed unknowns get x = r (N's unit diagonal)."""

    structure: BundleStructure
    point_inverse: Float[Array, "n_e 3 3"]
    factor: Float[Array, "n_r n_r"]
    scale: Float[Array, " n_r"]
    coupling: Float[Array, "n_obs1 3 m"]
    free_r: Float[Array, " n_r1"]
    free_e: Float[Array, "n_e1 3"]
    free: Parameters

    def solve(self, r: Parameters) -> Parameters:
        """N⁻¹ r (r and the result: Parameters trees), as `solve_bundle_damped` at λ = 0:
        x_r = S⁻¹ (r_r - Σ_p Y_pᵀ V_p⁻¹ r_e,p), x_e,p = V_p⁻¹ (r_e,p - Y_p x_r)."""
        s = self.structure
        dtype = self.factor.dtype
        n_e = self.point_inverse.shape[0]
        k = s.m - s.point_width
        r_r = reduced_vector(s, r) * self.free_r[:-1]
        r_e = r.points[s.eliminated_points] * self.free_e[:-1]
        eliminated = jnp.concatenate([matvec(self.point_inverse, r_e), jnp.zeros((1, 3), dtype)])
        per_observation = jnp.sum(
            self.coupling[:, :, :k] * eliminated[s.image_point][:, :, None], axis=1)
        rhs = r_r - add_at_columns(s, per_observation)[: s.n_reduced]
        x_r = self.scale * jax.scipy.linalg.cho_solve((self.factor, True), self.scale * rhs)
        x_r_padded = jnp.append(x_r, jnp.zeros((), dtype))
        coupled = jnp.sum(self.coupling * at_columns(s, x_r_padded)[:, None, :], axis=2)
        coupled = jax.ops.segment_sum(coupled, s.image_point, n_e + 1)[:n_e]
        x_e = matvec(self.point_inverse, r_e - coupled)
        x = to_parameters(s, r, x_r, x_e)
        return jax.tree.map(jnp.where, self.free, x, r)


def gauss_newton_factor(
    problem: BundleProblem, structure: BundleStructure, params: Parameters
) -> GaussNewtonFactor:
    """`GaussNewtonFactor` of `problem` at `params` (the backend's normal equations: U, V,
    W, with unit diagonals on fixed unknowns; S assembled pair-wise, Cholesky once)."""
    normal = bundle_normal_equations(problem, structure, params)
    point_inverse = small_inverse(normal.point_hessian)
    product, _ = schur_complement(structure, normal, point_inverse)
    reduced = normal.reduced_hessian + product
    scale = 1.0 / jnp.sqrt(jnp.diagonal(reduced))
    factor, _ = jax.scipy.linalg.cho_factor(scale[:, None] * reduced * scale[None, :], lower=True)
    free_r, free_e = free_masks(problem, structure, normal.reduced_gradient.dtype)
    return GaussNewtonFactor(structure, point_inverse, factor, scale, normal.coupling, free_r,
                             free_e, problem.free)


class SchurPreconditionedCG(lx.AbstractLinearSolver):
    """Conjugate gradients on a symmetric positive definite operator over Parameters trees
    (the Hessian of the implicit adjoint), preconditioned by `preconditioner`'s N⁻¹.

    Stops where ‖r‖_N⁻¹ ≤ `rtol` ‖b‖_N⁻¹ (r = b - H x, ‖r‖²_N⁻¹ = rᵀN⁻¹r: the preconditioned
    CG's own γ), or fails (`max_steps_reached`, and `lx.linear_solve` raises) after
    `max_steps` iterations, as it may where the operator is not positive definite (x̂ not a
    minimum); a zero right-hand side gives 0 at once. Symmetric: its transpose (reverse
    mode) is itself.
    """

    preconditioner: GaussNewtonFactor
    rtol: float = CG_RTOL
    max_steps: int = CG_MAX_STEPS

    def init(self, operator: lx.AbstractLinearOperator, options):
        del options
        if not (lx.is_symmetric(operator) and lx.is_positive_semidefinite(operator)):
            raise ValueError("SchurPreconditionedCG needs a symmetric positive definite operator")
        return lx.linearise(operator)  # one linearisation, then a pass per product

    def compute(self, state, vector, options):
        del options
        operator, precondition = state, self.preconditioner.solve
        zero = jax.tree.map(jnp.zeros_like, vector)
        z = precondition(vector)
        gamma = _tree_dot(vector, z)
        tolerance = self.rtol**2 * gamma

        def unfinished(carry):
            *_, gamma, step = carry
            return (gamma > tolerance) & (step < self.max_steps)

        def iterate(carry):
            x, r, p, gamma, step = carry
            hp = operator.mv(p)
            alpha = gamma / _tree_dot(p, hp)
            x = jax.tree.map(lambda a, b: a + alpha * b, x, p)
            r = jax.tree.map(lambda a, b: a - alpha * b, r, hp)
            z = precondition(r)
            gamma_next = _tree_dot(r, z)
            p = jax.tree.map(lambda a, b: a + (gamma_next / gamma) * b, z, p)
            return x, r, p, gamma_next, step + 1

        x, _, _, gamma, steps = jax.lax.while_loop(
            unfinished, iterate, (zero, vector, z, gamma, jnp.array(0)))
        result = lx.RESULTS.where(
            gamma <= tolerance, lx.RESULTS.successful, lx.RESULTS.max_steps_reached)
        return x, result, {"num_steps": steps, "max_steps": self.max_steps}

    def transpose(self, state, options):
        return state, options

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


def _primal(inputs):
    """`implicit_jvp`'s primal: the optimum, already computed (no tangent of its own)."""
    optimum, _ = inputs
    return optimum, None


def _optimality(y: Parameters, _, inputs) -> Parameters:
    """g(y, θ) = ∇_y ½‖e(y, θ)‖² on the free unknowns, y on the fixed ones."""
    _, problem = inputs

    def cost(y):
        return 0.5 * sum(jnp.sum(e**2) for e in bundle_residuals(y, problem))

    return jax.tree.map(jnp.where, problem.free, jax.grad(cost)(y), y)


@eqx.filter_jit
def schur_adjusted(
    problem: BundleProblem,
    structure: BundleStructure,
    *,
    max_steps: int,
    rtol: float,
    atol: float,
    step_tolerance: float = STEP_TOLERANCE,
    cg_rtol: float = CG_RTOL,
    cg_max_steps: int = CG_MAX_STEPS,
) -> tuple[Parameters, optx.RESULTS, Int[Array, ""]]:
    """x̂(θ) of `problem` (`structure = bundle_structure(problem)`), differentiable w.r.t.
    every array of `problem` (module docstring); also the solve's result and step count.

    The solve is `solve`'s Levenberg-Marquardt on the `Schur` backend (`rtol`, `atol`: its
    Cauchy test, `step_tolerance`: its statistical test); the adjoint's CG stops at `cg_rtol` in N's
    metric and fails after `cg_max_steps` iterations (an error under differentiation).
    """
    fixed = stop_gradient(problem)
    solution = solve(fixed, Schur(structure), max_steps=max_steps, rtol=rtol, atol=atol,
                     step_tolerance=step_tolerance)
    optimum = solution.parameters
    linear_solver = SchurPreconditionedCG(
        gauss_newton_factor(fixed, structure, optimum), cg_rtol, cg_max_steps)
    optimum, _ = implicit_jvp(_primal, _optimality, (optimum, problem), HESSIAN_TAGS,
                                   linear_solver)
    return problem.with_free(optimum), solution.result, solution.steps
