"""Statistics of a `BundleProblem` from the Schur split: the cofactors (JᵀJ)⁻¹ of the reduced
side and every object point's 3 x 3 block, without a dense n x n inverse."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._problem._bundle import BundleProblem, free_indices
from .._problem._parameters import Parameters
from .._solvers._schur._assembly import (
    BundleNormalEquations,
    compiled_normal_equations,
    schur_complement,
)
from .._solvers._schur._columns import reduced_positions, reduced_vector, to_parameters
from .._solvers._schur._normal import matmul, point_inverse, singular_points
from .._solvers._schur._structure import BundleStructure, bundle_structure
from ._covariance import Precision, SchurCovariance, with_ties


class BundleCofactors(eqx.Module):
    """Cofactors (JᵀJ)⁻¹ of the whitened bundle at a solution, from the Schur split.

    - `reduced`: (n_r, n_r) = S⁻¹, the full cofactor block of the reduced side (IOPs, EOPs,
      distance points; `BundleStructure` column order), rows/columns of fixed unknowns 0;
    - `points`: (n_points, 3, 3) the 3 x 3 cofactor block of every object point (reduced
      ones copied from `reduced`), V_p⁻¹ + V_p⁻¹ Y_p S⁻¹ Y_pᵀ V_p⁻¹ for eliminated ones
      (`_observation_cofactors`);
    - `sigma0_squared`: σ0² eᵀe / (n_observations - n_unknowns);
    - `std`: Parameters of σ = sqrt(σ̂0²/σ0² diag Q) (Cxx = σ̂0² N⁻¹, N = σ0² JᵀJ), 0 for
      fixed unknowns (as `Precision.std`).
    """

    reduced: Float[Array, "n_r n_r"]
    points: Float[Array, "n_points 3 3"]
    sigma0_squared: Float[Array, ""]
    std: Parameters


def schur_cofactors(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    structure: BundleStructure | None = None,
) -> BundleCofactors:
    """The precision of the unknowns at `params` without any dense n x n inverse.

    With N = JᵀJ split as [[U, W], [Wᵀ, V]] (points eliminated), N⁻¹'s reduced block is S⁻¹,
    S = U - W V⁻¹ Wᵀ (n_r x n_r, inverted by Cholesky), and the 3 x 3 diagonal block of
    eliminated point p is V_p⁻¹ + V_p⁻¹ Y_p S⁻¹ Y_pᵀ V_p⁻¹ (Y_p = W's rows of point p), summed
    over the pairs of observations of each point (Triggs et al. 2000, section 6.1;
    `_observation_cofactors`). Same numbers as the dense
    `jaxba.precision` (σ̂0² = σ0² eᵀe / r) for bundles with a datum; not for free networks.
    """
    if structure is None:
        structure = bundle_structure(problem)
    n_observations, n_unknowns = problem.n_observations(), problem.n_unknowns()
    normal, reduced, point_inverse, _ = compiled_normal_equations(problem, structure, params)
    return _schur_cofactors(problem, structure, params, normal, reduced, point_inverse,
                            *_traced_scalars(sigma0, n_observations - n_unknowns))


def schur_precision(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    structure: BundleStructure | None = None,
) -> Precision:
    """`jaxba.precision` from the Schur split (`schur_cofactors`): σ̂0², σ of every unknown,
    and as covariance a `SchurCovariance` (`covariance` None): Cxx of the reduced side and
    every object point's 3 x 3 block."""
    if structure is None:
        structure = bundle_structure(problem)
    cofactors = schur_cofactors(problem, params, sigma0=sigma0, structure=structure)
    return _precision_from_cofactors(problem, structure, cofactors, sigma0)


def _precision_from_cofactors(
    problem: BundleProblem,
    structure: BundleStructure,
    cofactors: BundleCofactors,
    sigma0: float,
    redundancy: tuple[np.ndarray, np.ndarray] | None = None,
) -> Precision:
    """`schur_precision` from `schur_cofactors`' result (and `SchurCovariance.redundancy`)."""
    sigma0_squared = float(cofactors.sigma0_squared)
    variance_factor = sigma0_squared / sigma0**2
    index = free_indices(problem)
    return with_ties(Precision(
        sigma0_squared=sigma0_squared,
        redundancy=problem.n_observations() - index.size,
        n_observations=problem.n_observations(),
        n_unknowns=index.size,
        free_index=index,
        covariance=None,
        std=jax.tree.map(np.asarray, cofactors.std),
        schur=SchurCovariance(
            reduced_positions=reduced_positions(problem, structure),
            reduced=variance_factor * np.asarray(cofactors.reduced),
            points=variance_factor * np.asarray(cofactors.points),
            redundancy=redundancy,
        ),
    ), problem)


def no_sigma(normal: BundleNormalEquations, eliminated: Float[Array, "n_e1 3 3"]) -> Array:
    """The eliminated points' 3 x 3 cofactor blocks (n_e + 1, 3, 3; last: padding), NaN for
    the points whose V_p is singular (`singular_points`): they have no σ."""
    singular = jnp.append(singular_points(normal.point_hessian), False)
    return jnp.where(singular[:, None, None], jnp.nan, eliminated)


def _reduced_cofactor(problem, structure, normal, reduced, inverse) -> tuple[Array, Array]:
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


def _observation_cofactors(
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


def _point_cofactors(problem, structure, cofactor, eliminated) -> Array:
    """The 3 x 3 cofactor block of every object point (n_points, 3, 3), 0 where fixed, from
    S⁻¹ and the eliminated points' blocks (n_e + 1, 3, 3: `_observation_cofactors`)."""
    n_e = structure.eliminated_points.shape[0]
    points = jnp.zeros((problem.initial.points.shape[0], 3, 3), cofactor.dtype)
    points = points.at[structure.eliminated_points].set(eliminated[:n_e])
    index = structure.point_column[structure.reduced_points][:, None] + jnp.arange(3)
    points = points.at[structure.reduced_points].set(cofactor[index[:, :, None], index[:, None, :]])
    free = problem.free.points.astype(cofactor.dtype)
    return points * free[:, :, None] * free[:, None, :]


def _traced_scalars(sigma0: float, redundancy: int) -> tuple[np.float64, np.float64]:
    """σ0 and the redundancy as float64 scalars, which `eqx.filter_jit` traces: as Python
    numbers they are static, and every new redundancy (data snooping switches observations
    off) compiled the statistics program again (~3 s)."""
    return np.float64(sigma0), np.float64(redundancy)


@eqx.filter_jit
def _schur_cofactors(problem, structure, params, normal, reduced, point_inverse, sigma0,
                     redundancy):
    cofactor, inverse = _reduced_cofactor(problem, structure, normal, reduced, point_inverse)
    _, eliminated = _observation_cofactors(structure, normal, cofactor, inverse)
    points = _point_cofactors(problem, structure, cofactor, no_sigma(normal, eliminated))
    residuals = problem.residuals(problem.with_free(params))
    return _bundle_cofactors(structure, problem, cofactor, points, residuals, sigma0, redundancy)


def _bundle_cofactors(structure, problem, cofactor, points, residuals, sigma0, redundancy):
    """`BundleCofactors` from S⁻¹, the points' 3 x 3 blocks and the whitened residuals."""
    sigma0_squared = sigma0**2 * sum(jnp.sum(r**2) for r in residuals) / redundancy
    variance_factor = sigma0_squared / sigma0**2
    reduced_std = jnp.sqrt(variance_factor * jnp.clip(jnp.diagonal(cofactor), 0.0))
    point_std = jnp.sqrt(variance_factor * jnp.clip(jnp.diagonal(points, axis1=1, axis2=2), 0.0))
    eliminated_std = point_std[structure.eliminated_points]
    std = to_parameters(structure, problem.initial, reduced_std, eliminated_std)
    return BundleCofactors(cofactor, points, sigma0_squared, std)
