"""Kernels of the Schur backend's normal equations: the Marquardt damping, pair-wise block
sums and products of many tiny matrices.

Performance notes (XLA on CPU): per-observation products are accumulated a chunk at a
time (`jax.lax.scan` + scatter-add) so that they never exist for all observations at
once, and products of tiny matrices are written as short sums of broadcast products
(`matmul`), which fuse, instead of batched `dot_general`s, which do not.
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


def marquardt_diagonal(
    diagonal: Float[Array, "... n"], min_diagonal: float, max_diagonal: float
) -> Float[Array, "... n"]:
    """Ceres' Levenberg-Marquardt damping diagonal D, in the unscaled unknowns.

    Ceres scales the Jacobian's columns by s_j = 1 / (1 + ‖J_j‖) (Jacobi scaling) and
    damps with D̃ = clamp(diag(J̃ᵀJ̃), min_diagonal, max_diagonal). Undoing the scaling,
    D_j = clamp(d_j, min_diagonal / s_j², max_diagonal / s_j²) with d_j = ‖J_j‖² =
    diag(JᵀJ)_j: Marquardt's scale-invariant diag(JᵀJ), kept away from 0 for unknowns
    the residuals barely see (Ceres `LevenbergMarquardtStrategy`, defaults 1e-6, 1e32).
    """
    inverse_scale_squared = (1.0 + jnp.sqrt(diagonal)) ** 2
    return jnp.clip(
        diagonal, min_diagonal * inverse_scale_squared, max_diagonal * inverse_scale_squared
    )


def pair_block_sums(
    left: Float[Array, "n_obs k a"],
    right: Float[Array, "n_obs k b"],
    first: Int[Array, "n_chunks rows row_size"],
    second: Int[Array, "n_chunks rows row_size"],
    block: Int[Array, "n_chunks rows"],
    n_blocks: int,
) -> Float[Array, "n_blocks a b"]:
    """Σ left_iᵀ right_j over the pairs (i, j) of every block, (n_blocks, a, b).

    The pairs come in rows of one block each (`_pairs.block_rows`; padding pairs hold
    an out-of-range observation, gathered as zeros, padding rows block `n_blocks`,
    dropped): a row's products sum as one (a x row_size k) @ (row_size k x b) product,
    and one block per row is scattered, a chunk of rows at a time (`jax.lax.scan`).
    """

    def accumulate(total, chunk):
        first, second, block = chunk  # (rows, row_size), (rows, row_size), (rows,)
        rows = first.shape[0]
        lhs = left.at[first].get(mode="fill", fill_value=0.0).reshape(rows, -1, left.shape[-1])
        rhs = right.at[second].get(mode="fill", fill_value=0.0)
        rhs = rhs.reshape(rows, -1, right.shape[-1])
        # A sum of broadcast products, not an einsum: 20 ms against 29 ms per S on
        # Dubrovnik-16 (XLA's batched dot of tiny matrices is slow on the CPU).
        products = matmul(lhs.transpose(0, 2, 1), rhs)
        return total.at[block].add(products, mode="drop", indices_are_sorted=True), None

    zero = jnp.zeros((n_blocks, left.shape[-1], right.shape[-1]), left.dtype)
    total, _ = jax.lax.scan(accumulate, zero, (first, second, block))
    return total


def matmul(a: Float[Array, "n i k"], b: Float[Array, "n k j"]) -> Float[Array, "n i j"]:
    """a[n] @ b[n] for many small matrices, the short sum over k written out.

    XLA on CPU runs batched `dot_general`s of tiny matrices slowly; a sum of k
    broadcast products fuses into one loop.
    """
    return sum(a[:, :, k, None] * b[:, None, k, :] for k in range(a.shape[-1]))


def matvec(a: Float[Array, "n i k"], v: Float[Array, "n k"]) -> Float[Array, "n i"]:
    """a[n] @ v[n] for many small matrices (see `matmul`)."""
    return sum(a[:, :, k] * v[:, k, None] for k in range(a.shape[-1]))


def small_inverse(a: Float[Array, "n m m"]) -> Float[Array, "n m m"]:
    """Inverses of many small symmetric positive definite matrices.

    Gauss-Jordan elimination without pivoting (safe for SPD), unrolled over the static
    size m; elementwise over n, so it fuses (jnp.linalg.inv calls LAPACK per matrix).
    """
    m = a.shape[-1]
    augmented = jnp.concatenate([a, jnp.broadcast_to(jnp.eye(m, dtype=a.dtype), a.shape)], -1)
    for k in range(m):
        pivot_row = augmented[:, k, :] / augmented[:, k, k, None]
        augmented = augmented - augmented[:, :, k, None] * pivot_row[:, None, :]
        augmented = augmented.at[:, k, :].set(pivot_row)
    return augmented[:, :, m:]


# A point's 3 x 3 block of N whose smallest eigenvalue is below this fraction of its largest
# is singular: its inverse would hold no correct digit beyond ε/POINT_RCOND ~ 1e-4 (rays
# within ~1e-6 rad of each other: the point's depth along them is not determined).
POINT_RCOND = 1e-12


def singular_points(point_hessian: Float[Array, "n 3 3"]) -> Array:
    """(n,) True where a point's block V_p is singular (`POINT_RCOND`)."""
    values = jnp.linalg.eigvalsh(point_hessian)
    return values[:, 0] <= POINT_RCOND * values[:, -1]


def point_inverse(point_hessian: Float[Array, "n 3 3"]) -> Float[Array, "n 3 3"]:
    """V_p⁻¹ of every point (`small_inverse`); the pseudo-inverse where V_p is singular
    (`singular_points`). The direction N does not determine is then the point's own (moving
    it along its rays moves no residual, so W_p is 0 along it too), and S = U - W V⁺ Wᵀ is
    the S of the other unknowns, which stay determined. The eigen-decompositions run only
    where a block's reciprocal condition, estimated as 1 / (‖V‖_F ‖V⁻¹‖_F), is small."""
    inverse = small_inverse(point_hessian)
    estimate = 1.0 / (jnp.linalg.norm(point_hessian, axis=(1, 2))
                      * jnp.linalg.norm(inverse, axis=(1, 2)))
    suspect = ~(estimate > 10 * POINT_RCOND)  # NaN (a singular elimination) included

    def pseudo(_):
        values, vectors = jnp.linalg.eigh(point_hessian)
        kept = values > POINT_RCOND * values[:, -1:]
        inverse_values = jnp.where(kept, 1.0 / jnp.where(kept, values, 1.0), 0.0)
        pseudo = jnp.einsum("nij,nj,nkj->nik", vectors, inverse_values, vectors)
        return jnp.where(kept.all(axis=1)[:, None, None], inverse, pseudo)

    return jax.lax.cond(suspect.any(), pseudo, lambda _: inverse, None)


def add_diagonal(
    matrices: Float[Array, "m n n"], diagonals: Float[Array, "m n"]
) -> Float[Array, "m n n"]:
    """matrices[i] + diag(diagonals[i]) for every i."""
    return matrices + diagonals[:, :, None] * jnp.eye(matrices.shape[-1], dtype=matrices.dtype)
