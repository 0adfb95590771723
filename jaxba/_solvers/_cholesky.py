"""Dense Cholesky solve written in XLA operations (no LAPACK call).

The solvers' damped normal systems are small (the reduced camera system of the Schur
solver, the normal equations of a calibration: a few hundred unknowns) and are solved once
per trial step. LAPACK is avoided for two reasons. Under `jax.vmap` XLA calls a batched
`potrf` from its own worker threads, and with OPENBLAS_NUM_THREADS=1 (OpenBLAS then keeps
one unlocked buffer) that deadlocked a batched solve inside pytest. And on CPU,
`jnp.linalg.cholesky` calls OpenBLAS's threaded `potrf` from inside an XLA computation;
when OpenBLAS's threads and XLA's compete for the cores this takes ~500 ms instead of
~2 ms for a 441 x 441 matrix (measured on 2 cores; the known OpenBLAS oversubscription
problem, OpenMathLib/OpenBLAS#5517) unless OPENBLAS_NUM_THREADS=1 is set before numpy
loads. Blocked right-looking Cholesky with matrix products (XLA's own kernels) costs
~3 ms with or without that setting (block size 128: compiles in ~1 s; 64 runs 0.8 ms
faster but compiles ~2 s longer, 32 slower on both counts).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def cholesky_solve(
    matrix: Float[Array, "n n"], vector: Float[Array, " n"], block_size: int = 128
) -> Float[Array, " n"]:
    """x = A⁻¹ b for a symmetric positive definite A, by the Cholesky factor A = L Lᵀ.

    Right-looking blocked factorisation (Golub & Van Loan, "Matrix Computations", 4th
    ed., algorithm 4.2.10): for each diagonal block, factor it unblocked, solve the panel
    below with the block's triangular inverse, and update the trailing matrix by one
    matrix product; then forward (L z = b) and back (Lᵀ x = z) substitution by blocks.
    Only the lower triangle of `matrix` is read. A matrix that is not positive definite
    gives NaNs. `block_size` is static; the blocks are unrolled (n / block_size of them).
    """
    n = matrix.shape[0]
    bounds = [(start, min(start + block_size, n)) for start in range(0, n, block_size)]
    factor, inverses = matrix, []
    for start, stop in bounds:
        diagonal = _unblocked_cholesky(factor[start:stop, start:stop])
        inverse = _lower_triangular_inverse(diagonal)
        inverses.append(inverse)
        factor = factor.at[start:stop, start:stop].set(diagonal)
        if stop < n:
            panel = factor[stop:, start:stop] @ inverse.T
            factor = factor.at[stop:, start:stop].set(panel)
            factor = factor.at[stop:, stop:].add(-panel @ panel.T)
    forward = []
    for k, (start, stop) in enumerate(bounds):
        rhs = vector[start:stop]
        for m in range(k):
            rhs = rhs - factor[start:stop, bounds[m][0] : bounds[m][1]] @ forward[m]
        forward.append(inverses[k] @ rhs)
    backward = [None] * len(bounds)
    for k in reversed(range(len(bounds))):
        start, stop = bounds[k]
        rhs = forward[k]
        for m in range(k + 1, len(bounds)):
            rhs = rhs - factor[bounds[m][0] : bounds[m][1], start:stop].T @ backward[m]
        backward[k] = inverses[k].T @ rhs
    return jnp.concatenate(backward)


def _unblocked_cholesky(block: Float[Array, "b b"]) -> Float[Array, "b b"]:
    """Lower Cholesky factor of a small SPD block, one column per loop step (outer products)."""
    size = block.shape[0]
    index = jnp.arange(size)

    def column(k, work):
        pivot = jnp.sqrt(work[k, k])
        below = jnp.where(index > k, work[:, k] / pivot, 0.0)
        work = work - jnp.outer(below, below)
        return work.at[:, k].set(jnp.where(index == k, pivot, below))

    return jnp.tril(jax.lax.fori_loop(0, size, column, block))


def _lower_triangular_inverse(lower: Float[Array, "b b"]) -> Float[Array, "b b"]:
    """L⁻¹ of a small lower-triangular L, by forward substitution one row at a time."""
    size = lower.shape[0]
    index = jnp.arange(size)
    identity = jnp.eye(size, dtype=lower.dtype)

    def row(i, inverse):
        known = jnp.where(index < i, lower[i], 0.0) @ inverse
        return inverse.at[i].set((identity[i] - known) / lower[i, i])

    return jax.lax.fori_loop(0, size, row, jnp.zeros_like(lower))
