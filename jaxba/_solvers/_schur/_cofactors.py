"""The cofactors (JᵀJ)⁻¹ of a bundle from the Schur split: S⁻¹ on the reduced side and every
object point's 3 x 3 block, without a dense n x n inverse (jax functions, traced into the
programs of `_leverages.py`).

With N = JᵀJ split as [[U, W], [Wᵀ, V]] (points eliminated), N⁻¹'s reduced block is S⁻¹,
S = U - W V⁻¹ Wᵀ (n_r x n_r, inverted by Cholesky), and the 3 x 3 diagonal block of
eliminated point p is V_p⁻¹ + V_p⁻¹ Y_p S⁻¹ Y_pᵀ V_p⁻¹ (Y_p = W's rows of point p), summed
over the pairs of observations of each point (Triggs et al. 2000, section 6.1;
`observation_cofactors`).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._assembly import BundleNormalEquations, schur_complement
from ._columns import reduced_vector
from ._normal import matmul, point_inverse, singular_points
from ._structure import BundleStructure


def nan_where_singular(normal: BundleNormalEquations, eliminated: Float[Array, "n_e1 3 3"]
                       ) -> Array:
    """The eliminated points' 3 x 3 cofactor blocks (n_e + 1, 3, 3; last: padding), NaN for
    the points whose V_p is singular (`singular_points`): they have no σ."""
    singular = jnp.append(singular_points(normal.point_hessian), False)
    return jnp.where(singular[:, None, None], jnp.nan, eliminated)


def reduced_cofactor(problem, structure, normal, reduced, inverse) -> tuple[Array, Array]:
    """S⁻¹ (n_r, n_r; rows and columns of fixed unknowns 0) and the points' V⁻¹ padded
    with a zero block (n_e + 1, 3, 3), from S (`reduced`) and V⁻¹ (`inverse`) as
    `compiled_normal_equations` returns them; where a point's V_p is singular
    (`singular_points`) its pseudo-inverse (`point_inverse`) instead, and S formed again
    with it."""
    dtype = reduced.dtype
    free_r = reduced_vector(structure, problem.free).astype(dtype)
    singular = singular_points(normal.point_hessian)
    inverse = jnp.where(singular[:, None, None], point_inverse(normal.point_hessian), inverse)
    reduced = jax.lax.cond(
        singular.any(),
        lambda: normal.reduced_hessian + schur_complement(structure, normal, inverse)[0],
        lambda: reduced)
    factor = jax.scipy.linalg.cho_factor(reduced, lower=True)
    cofactor = jax.scipy.linalg.cho_solve(factor, jnp.diag(free_r)) * free_r[:, None]
    return cofactor, jnp.concatenate([inverse, jnp.zeros((1, 3, 3), dtype)])


def observation_cofactors(
    structure: BundleStructure, normal: BundleNormalEquations, cofactor: Array, inverse: Array
) -> tuple[Float[Array, "n_obs1 3 k"], Float[Array, "n_e1 3 3"]]:
    """`_pairwise_cofactors` or `_dense_cofactors`, as `structure.pairwise` says: the same
    blocks, less work pair-wise where points are seen by few images."""
    if structure.pairwise:
        return _pairwise_cofactors(structure, normal, cofactor, inverse)
    return _dense_cofactors(structure, normal, cofactor, inverse)


def _dense_cofactors(
    structure: BundleStructure, normal: BundleNormalEquations, cofactor: Array, inverse: Array
) -> tuple[Float[Array, "n_obs1 3 k"], Float[Array, "n_e1 3 3"]]:
    """`_pairwise_cofactors`' blocks from G_p = S⁻¹ Y_p V_p⁻¹ (n_r x 3) formed for a chunk of
    points at a time as one matrix product, (n_r + 1) x (n_r + 1) by (n_r + 1) x 3P: for
    points seen by many images (a target field), where the pairs are many."""
    n_r, n_points, k = structure.n_reduced, structure.points_per_chunk, _g_width(structure)
    padded = jnp.pad(cofactor, ((0, 1), (0, 1)))

    def chunk(g_all, chunk):
        obs, local, points = chunk
        t = _chunk_coupling(structure, normal, inverse, obs, local, points)
        t_flat = t.transpose(1, 0, 2).reshape(n_r + 1, 3 * n_points)
        g = (padded @ t_flat).reshape(n_r + 1, n_points, 3)
        blocks = inverse[points] + jnp.einsum("pci,cpk->pik", t, g)
        g_obs = g[structure.image_columns[obs][:, :k], local[:, None], :]  # (max_obs, k, 3)
        return g_all.at[obs].set(g_obs.transpose(0, 2, 1)), blocks

    g_all = jnp.zeros((structure.image_point.shape[0], 3, k), cofactor.dtype)
    g_all, blocks = jax.lax.scan(
        chunk, g_all, (structure.chunk_obs, structure.chunk_local, structure.chunk_points))
    n_e = inverse.shape[0] - 1
    points = jnp.concatenate([blocks.reshape(-1, 3, 3)[:n_e], jnp.zeros_like(inverse[:1])])
    return g_all.at[-1].set(0.0), points


def _chunk_coupling(structure, normal, inverse, obs, local, points) -> Array:
    """T = Y V⁻¹ (points of the chunk, n_r + 1, 3): the coupling blocks W of the chunk's
    observations summed per point (Y; last row: padding), times the point's V⁻¹."""
    n_r, n_points = structure.n_reduced, structure.points_per_chunk
    flat = local[:, None] * (n_r + 1) + structure.image_columns[obs]
    y = jnp.zeros((n_points * (n_r + 1), 3), normal.coupling.dtype).at[flat].add(
        normal.coupling[obs].transpose(0, 2, 1), mode="drop"
    )
    y = y.reshape(n_points, n_r + 1, 3)
    return jnp.sum(y[:, :, None, :] * inverse[points][:, None, :, :], axis=3)


def _g_width(structure: BundleStructure) -> int:
    """k: the reduced columns an eliminated point's observation can be nonzero in."""
    return structure.m - structure.point_width


def _pairwise_cofactors(
    structure: BundleStructure, normal: BundleNormalEquations, cofactor: Array, inverse: Array
) -> tuple[Float[Array, "n_obs1 3 k"], Float[Array, "n_e1 3 3"]]:
    """The cofactor blocks between the reduced side and the eliminated points that the
    statistics need, pair-wise over the observations of each point, without the dense
    n_r x 3 blocks G_p = S⁻¹ Y_p V_p⁻¹ (O(n_points n_r²) work).

    With t_i = W_i V_p⁻¹ (k x 3; k = m - point_width, the columns W_i can be nonzero in),
    Y_p V_p⁻¹ = Σ_{j∈p} t_j at the columns c_j of observation j, so G_p's rows at the
    columns c_i of observation i are g_i = Σ_{j∈p} S⁻¹[c_i, c_j] t_j, and the point's
    3 x 3 block is V_p⁻¹ + V_p⁻¹ Y_pᵀ S⁻¹ Y_p V_p⁻¹ = V_p⁻¹ + Σ_{i∈p} t_iᵀ g_i. The pairs
    (i, j) are S's (`structure.pair_first`, ...: key_i >= key_j, in rows of one key pair,
    whose S⁻¹ block is gathered once per key pair). `cofactor`: S⁻¹ (n_r, n_r); `inverse`:
    V⁻¹ padded (n_e + 1, 3, 3). Returns g_iᵀ (n_obs1, 3, k) and the eliminated points' 3 x 3
    cofactor blocks (n_e + 1, 3, 3; last: padding)."""
    k = _g_width(structure)
    padded = jnp.pad(cofactor, ((0, 1), (0, 1)))
    first = structure.key_columns[structure.key_pairs[:, 0], :k]
    second = structure.key_columns[structure.key_pairs[:, 1], :k]
    blocks = padded[first[:, :, None], second[:, None, :]]  # S⁻¹[c_i, c_j] per key pair
    t = matmul(inverse[structure.image_point], normal.coupling[:, :, :k])  # t_iᵀ (n, 3, k)

    def accumulate(total, chunk):
        first, second, block = chunk  # (rows, row_size), (rows, row_size), (rows,)
        q = blocks.at[block].get(mode="fill", fill_value=0.0)[:, None]  # (rows, 1, k, k)
        t_first, t_second = t[first], t[second]  # (rows, row_size, 3, k)
        # g_iᵀ += t_jᵀ S⁻¹[c_j, c_i], and for i != j also g_jᵀ += t_iᵀ S⁻¹[c_i, c_j].
        to_first = sum(t_second[..., a, None] * q[:, :, None, :, a] for a in range(k))
        to_second = sum(t_first[..., a, None] * q[:, :, None, a, :] for a in range(k))
        to_second = jnp.where((first != second)[:, :, None, None], to_second, 0.0)
        total = total.at[first].add(to_first).at[second].add(to_second)
        return total, None

    g, _ = jax.lax.scan(accumulate, jnp.zeros_like(t),
                        (structure.pair_first, structure.pair_second, structure.pair_block))
    n_e1 = inverse.shape[0]
    points = inverse + jax.ops.segment_sum(
        matmul(t, g.transpose(0, 2, 1)), structure.image_point, n_e1)
    return g, points


def point_cofactors(problem, structure, cofactor, eliminated) -> Array:
    """The 3 x 3 cofactor block of every object point (n_points, 3, 3), 0 where fixed, from
    S⁻¹ and the eliminated points' blocks (n_e + 1, 3, 3: `observation_cofactors`)."""
    n_e = structure.eliminated_points.shape[0]
    points = jnp.zeros((problem.initial.points.shape[0], 3, 3), cofactor.dtype)
    points = points.at[structure.eliminated_points].set(eliminated[:n_e])
    index = structure.point_column[structure.reduced_points][:, None] + jnp.arange(3)
    points = points.at[structure.reduced_points].set(cofactor[index[:, :, None], index[:, None, :]])
    free = problem.free.points.astype(cofactor.dtype)
    return points * free[:, :, None] * free[:, None, :]
