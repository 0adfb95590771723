"""The normal equations of a bundle in the Schur split (`_structure`), and their reduction.

With the Jacobian of image observation i split into J_r,i (2 x m, its reduced columns) and
J_e,i (2 x 3, its eliminated point), U = Σ J_rᵀJ_r + priors (dense, n_r x n_r), V_p =
Σ_{i∈p} J_e,iᵀJ_e,i + control (3 x 3 per point), W_i = J_r,iᵀ J_e,i and g = Jᵀe, the damped
normal equations reduce to

    S x_r = g_r - Σ_p Y_pᵀ V_λ,p⁻¹ g_e,p,   S = U + λD_r - Σ_p Y_pᵀ V_λ,p⁻¹ Y_p,

Y_p = Σ_{i∈p} W_iᵀ (3 x n_r, the coupling of point p with the reduced side), then
x_e,p = V_λ,p⁻¹ (g_e,p - Y_p x_r) (Triggs et al., "Bundle adjustment - a modern synthesis",
2000, section 6.1). S is assembled pair-wise, as BAL's reduced camera matrix
(`_normal.py`): Y_pᵀ V⁻¹ Y_p = Σ_{i,j∈p} W_i V⁻¹ W_jᵀ over the pairs of observations of
each point, the pairs of one key pair (same reduced columns: for one camera, one pair of
images) summed first and scattered once into the dense S. Work O(n_pairs m²) per trial step
(n_pairs = Σ_p n_obs,p²/2), memory O(n_obs m + n_r²); U is summed per key the same way.

Fixed unknowns (False in `problem.free`) get zero Jacobian columns and a unit diagonal:
their step is exactly 0. The rows of the other groups (`AbstractObservationGroup.row_blocks`)
add their Jacobian blocks' Gram matrices at their own unknowns: to V where a row depends on
one eliminated point alone (control: 1/σ² on its diagonal), else to U (GNSS/INS and IOP
priors on its diagonal, a distance on its two reduced points).
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..._problem._bundle import BundleProblem
from ..._problem._parameters import Parameters
from ..._programs import stored
from .._compiled import solver_jit
from ._columns import add_at_columns, free_masks, row_columns, row_points
from ._jacobians import gram, image_blocks, row_jacobians, transposed_product
from ._normal import add_diagonal, marquardt_diagonal, matmul, pair_block_sums, small_inverse
from ._structure import BundleStructure


class BundleNormalEquations(eqx.Module):
    """Jacobian-dependent blocks (once per accepted iterate); see the module docstring.

    `reduced_hessian` U (n_r, n_r) with unit diagonal on fixed unknowns; `point_hessian` V
    (n_e, 3, 3) likewise; `coupling` W_iᵀ (n_image_obs + 1, 3, m) (last row zero; stored
    transposed, the layout the products of S read without copies);
    gradients g_r (n_r,), g_e (n_e, 3); Marquardt damping D_r (n_r,), D_e (n_e, 3).
    """

    reduced_hessian: Float[Array, "n_r n_r"]
    point_hessian: Float[Array, "n_e 3 3"]
    coupling: Float[Array, "n_obs1 3 m"]
    reduced_gradient: Float[Array, " n_r"]
    point_gradient: Float[Array, "n_e 3"]
    reduced_damping: Float[Array, " n_r"]
    point_damping: Float[Array, "n_e 3"]


def zero_normal_equations(structure: BundleStructure, dtype) -> BundleNormalEquations:
    """`BundleNormalEquations` of zeros, shaped as `bundle_normal_equations` returns them."""
    n_r, n_e = structure.n_reduced, structure.eliminated_points.shape[0]
    n_rows = structure.image_columns.shape[0]  # the image observations and the padding row
    return BundleNormalEquations(
        reduced_hessian=jnp.zeros((n_r, n_r), dtype),
        point_hessian=jnp.zeros((n_e, 3, 3), dtype),
        coupling=jnp.zeros((n_rows, 3, structure.m), dtype),
        reduced_gradient=jnp.zeros(n_r, dtype),
        point_gradient=jnp.zeros((n_e, 3), dtype),
        reduced_damping=jnp.zeros(n_r, dtype),
        point_damping=jnp.zeros((n_e, 3), dtype),
    )


def bundle_normal_equations(
    problem: BundleProblem,
    structure: BundleStructure,
    params: Parameters,
    min_diagonal: float = 1e-6,
    max_diagonal: float = 1e32,
) -> BundleNormalEquations:
    """U, V, W, g and the Marquardt damping of `problem` at `params` (all unknowns' values)."""
    blocks = _image_blocks(problem, structure, params)
    return normal_from_blocks(problem, structure, params, *blocks, min_diagonal, max_diagonal)


def _image_blocks(problem, structure, params):
    free_r, free_e = free_masks(problem, structure, params.images.dtype)
    return image_blocks(problem, structure, params, free_r, free_e)


def normal_from_blocks(
    problem: BundleProblem,
    structure: BundleStructure,
    params: Parameters,
    jr: Float[Array, "n_obs1 2 m"],
    je: Float[Array, "n_obs1 2 3"],
    e: Float[Array, "n_obs1 2"],
    min_diagonal: float = 1e-6,
    max_diagonal: float = 1e32,
) -> BundleNormalEquations:
    """`bundle_normal_equations` from the image observations' Jacobian blocks and whitened
    residuals at `params` (`image_blocks`, free columns only)."""
    n_r = structure.n_reduced
    n_e = structure.eliminated_points.shape[0]
    dtype = params.images.dtype
    free_r, free_e = free_masks(problem, structure, dtype)
    per_key = pair_block_sums(
        jr, jr, structure.key_rows, structure.key_rows, structure.key_row_block,
        structure.key_columns.shape[0],
    )
    key_columns = structure.key_columns
    hessian = dense_from_blocks(n_r, key_columns, key_columns, per_key)
    gradient = add_at_columns(structure, transposed_product(jr, e))
    point_hessian = jnp.zeros((n_e + 1, 3, 3), dtype).at[structure.image_point].add(gram(je, je))
    point_gradient = jnp.zeros((n_e + 1, 3), dtype).at[structure.image_point].add(
        transposed_product(je, e)
    )
    coupling = gram(je, jr)

    # The other groups' rows one at a time over their own unknowns (control, GNSS/INS and
    # IOP priors: one block row; distances: two reduced points), their residuals only:
    # the image points' are the blocks' own (the whole `problem.residuals` traced and
    # lowered them again, 0.1-0.2 s a program).
    for group in problem.groups:
        if group.kind() == "image_points":
            continue
        jacobian, residual = row_jacobians(problem, group, params)
        columns = row_columns(structure, group)
        reduced = jacobian * free_r[columns][:, None, :]
        # One product over the row's k entries (`gram` writes the sum out, for the image
        # blocks' k = 2): fewer operations in the program for these few rows.
        hessian = hessian.at[columns[:, :, None], columns[:, None, :]].add(
            jnp.einsum("nka,nkb->nab", reduced, reduced))
        gradient = gradient.at[columns].add(transposed_product(reduced, residual))
        point = row_points(structure, group)
        if point is not None:  # a row on one eliminated point (control): V and g_e
            eliminated = jacobian * free_e[point][:, None, :]
            point_hessian = point_hessian.at[point].add(
                jnp.einsum("nka,nkb->nab", eliminated, eliminated))
            point_gradient = point_gradient.at[point].add(
                transposed_product(eliminated, residual))

    hessian, gradient = hessian[:n_r, :n_r], gradient[:n_r]
    point_hessian, point_gradient = point_hessian[:n_e], point_gradient[:n_e]
    fixed_r = 1.0 - free_r[:n_r]
    fixed_e = 1.0 - free_e[:n_e]
    hessian = hessian + jnp.diag(fixed_r)
    point_hessian = add_diagonal(point_hessian, fixed_e)
    return BundleNormalEquations(
        reduced_hessian=hessian,
        point_hessian=point_hessian,
        coupling=coupling,
        reduced_gradient=gradient,
        point_gradient=point_gradient,
        reduced_damping=marquardt_diagonal(jnp.diagonal(hessian), min_diagonal, max_diagonal),
        point_damping=marquardt_diagonal(
            jnp.diagonal(point_hessian, axis1=1, axis2=2), min_diagonal, max_diagonal
        ),
    )


def _normal_and_reduced(problem, structure, params):
    jr, je, e = _image_blocks(problem, structure, params)
    normal = normal_from_blocks(problem, structure, params, jr, je, e)
    point_inverse = small_inverse(normal.point_hessian)
    product, _ = schur_complement(structure, normal, point_inverse)
    return normal, normal.reduced_hessian + product, point_inverse, (jr, je)


# One program of its own for the datum check (at the approximations) and the statistics (at
# the solution), which would otherwise each compile the normal equations inside theirs:
# `bundle_normal_equations` at `params`, S = U - Σ_p Y_pᵀ V_p⁻¹ Y_p (n_r, n_r), V⁻¹
# (n_e, 3, 3), and the image observations' Jacobian blocks (J_r, J_e) (`image_blocks`),
# which the leverages read instead of differentiating the camera model again in their own
# program. (The datum check's S was a second program, 0.2 s to load in every process.)
compiled_normal_equations = stored("normal_equations")(solver_jit(_normal_and_reduced))


def dense_from_blocks(
    n_r: int, rows: Int[Array, "n a"], columns: Int[Array, "n b"], blocks: Float[Array, "n a b"]
) -> Float[Array, "n_r1 n_r1"]:
    """Σ_k blocks[k] added at (rows[k], columns[k]) of a dense (n_r + 1, n_r + 1) matrix
    (row and column n_r: padding)."""
    flat = rows[:, :, None] * (n_r + 1) + columns[:, None, :]
    dense = jnp.zeros(((n_r + 1) ** 2,), blocks.dtype).at[flat].add(blocks)
    return dense.reshape(n_r + 1, n_r + 1)


def schur_complement(
    structure: BundleStructure, normal: BundleNormalEquations, point_inverse: Array
) -> tuple[Float[Array, "n_r n_r"], Float[Array, " n_r"]]:
    """-Σ_p Y_pᵀ V_λ,p⁻¹ Y_p and Σ_p Y_pᵀ V_λ,p⁻¹ g_e,p (`point_inverse`: V_λ⁻¹, (n_e, 3, 3)).

    Pair-wise: Y_pᵀ V⁻¹ Y_p = Σ_{i,j ∈ p} W_i V⁻¹ W_jᵀ, and the blocks of the pairs of one
    key pair (equal reduced columns; for one camera, one image pair) are summed first
    (`pair_block_sums`, lower key triangle), then mirrored and scattered once. Only the
    first m - point_width columns of W_i are nonzero for an eliminated point. The
    right-hand side comes from the same L_i = V_p⁻¹ W_iᵀ as the pairs, W_i V_p⁻¹ g_p =
    L_iᵀ g_p, in one pass with L (Dubrovnik-16: 5.2 -> 3.5 ms per trial step).
    """
    n_r, k = structure.n_reduced, structure.m - structure.point_width
    dtype = normal.reduced_gradient.dtype
    inverse = jnp.concatenate([point_inverse, jnp.zeros((1, 3, 3), dtype)])[structure.image_point]
    coupling_t = normal.coupling[:, :, :k]  # W_iᵀ (n_obs1, 3, k)
    left = matmul(inverse, coupling_t)  # L_i (n_obs1, 3, k)
    blocks = pair_block_sums(
        left, coupling_t, structure.pair_first, structure.pair_second,
        structure.pair_block, structure.key_pairs.shape[0],
    )
    first = structure.key_columns[structure.key_pairs[:, 0], :k]
    second = structure.key_columns[structure.key_pairs[:, 1], :k]
    mirrored = jnp.where(
        (structure.key_pairs[:, 0] != structure.key_pairs[:, 1])[:, None, None],
        blocks.transpose(0, 2, 1), 0.0,
    )
    product = dense_from_blocks(
        n_r, jnp.concatenate([first, second]), jnp.concatenate([second, first]),
        jnp.concatenate([blocks, mirrored]),
    )
    gradient = jnp.concatenate([normal.point_gradient, jnp.zeros((1, 3), dtype)])
    gradient = gradient[structure.image_point]
    rhs = add_at_columns(structure, transposed_product(left, gradient))
    return -product[:n_r, :n_r], rhs[:n_r]
