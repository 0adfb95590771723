"""The damped solve of a bundle's normal equations by the Schur complement on the
eliminated points, and back-substitution."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Scalar

from ..._problem._bundle import BundleProblem
from ..._problem._parameters import Parameters, unflatten
from .._cholesky import cholesky_solve
from ._assembly import BundleNormalEquations, compiled_normal_equations, schur_complement
from ._columns import at_columns, free_masks, reduced_positions
from ._normal import add_diagonal, point_inverse, small_inverse
from ._structure import BundleStructure, bundle_structure


def solve_bundle_damped(
    structure: BundleStructure, normal: BundleNormalEquations, damping: Scalar,
    held: Float[Array, " n_r"] | None = None,
) -> tuple[Float[Array, " n_r"], Float[Array, "n_e 3"]]:
    """x = (JᵀJ + λD)⁻¹ Jᵀe as (x_r, x_e) by the Schur complement on the eliminated points;
    `held` (n_r,) 1.0 on reduced columns held (x_r = 0 there: their rows and columns of S
    and of the right-hand side dropped, which is S of the problem with them fixed). The
    undamped solve (λ = 0) takes pseudo-inverses of singular point blocks (`point_inverse`:
    a point on nearly coincident rays leaves the Gauss-Newton step and gᵀN⁻¹g finite)."""
    dtype = normal.reduced_gradient.dtype
    damped = add_diagonal(normal.point_hessian, damping * normal.point_damping)
    inverse = jax.lax.cond(damping == 0, point_inverse, small_inverse, damped)
    reduced, rhs = schur_complement(structure, normal, inverse)
    reduced = reduced + normal.reduced_hessian + jnp.diag(damping * normal.reduced_damping)
    rhs = normal.reduced_gradient - rhs
    if held is not None:
        kept = 1.0 - held
        reduced = reduced * kept[:, None] * kept[None, :] + jnp.diag(held)
        rhs = rhs * kept
    x_r = cholesky_solve(reduced, rhs)
    x_r_padded = jnp.append(x_r, jnp.zeros((), dtype))
    n_e = normal.point_gradient.shape[0]
    coupled = jnp.sum(normal.coupling * at_columns(structure, x_r_padded)[:, None, :], axis=2)
    coupled = jax.ops.segment_sum(coupled, structure.image_point, n_e + 1)[:n_e]
    x_e = jnp.sum(inverse * (normal.point_gradient - coupled)[:, None, :], axis=2)
    return x_r, x_e


def schur_solve(
    problem: BundleProblem,
    params: Parameters,
    rhs: Float[np.ndarray, "m n_all"],
    *,
    structure: BundleStructure | None = None,
) -> Float[np.ndarray, "m n_all"]:
    """(JᵀJ)⁻¹ r for each right-hand side r (a row of `rhs`, `flatten` positions) of the
    whitened bundle at `params`, by the Schur split: no dense n x n matrix. Entries of fixed
    unknowns are ignored in `rhs` and 0 in the result."""
    structure = structure or bundle_structure(problem)
    rhs = np.asarray(rhs)
    positions = unflatten(problem.initial, np.arange(rhs.shape[1]))
    reduced = reduced_positions(problem, structure)
    points = np.asarray(positions.points)[np.asarray(structure.eliminated_points)]
    normal = compiled_normal_equations(problem, structure, params)[0]
    x_r, x_e = _schur_solve(problem, structure, normal, jnp.asarray(rhs[:, reduced]),
                            jnp.asarray(rhs[:, points]))
    out = np.zeros_like(rhs)
    out[:, reduced] = np.asarray(x_r)
    out[:, points] = np.asarray(x_e)
    return out


@eqx.filter_jit
def _schur_solve(problem, structure, normal, rhs_r, rhs_e):
    """`schur_solve` with the normal equations `normal` formed (by their own program)."""
    free_r, free_e = free_masks(problem, structure, rhs_r.dtype)

    def one(r, e):  # vmapped over the right-hand sides; S is assembled once
        system = eqx.tree_at(lambda n: (n.reduced_gradient, n.point_gradient), normal,
                             (r * free_r[:-1], e * free_e[:-1]))
        return solve_bundle_damped(structure, system, 0.0)

    return jax.vmap(one)(rhs_r, rhs_e)


