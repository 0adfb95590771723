"""The damped normal equations of a two-block problem, solved by the Schur complement.

With J = [J_c J_p] the Jacobian of the residuals r with respect to y = (c, p), the
Levenberg-Marquardt step solves (JᵀJ + λD) x = Jᵀr, which in blocks reads

    [U + λD_c     W     ] [x_c]   [g_c]
    [   Wᵀ     V + λD_p ] [x_p] = [g_p],

U = Σ_i J_c,iᵀ J_c,i per camera (block diagonal), V = Σ_i J_p,iᵀ J_p,i per point (block
diagonal), W = J_cᵀ J_p with one block W_i = J_c,iᵀ J_p,i per observation, g = Jᵀr.
Eliminating the points (V_λ = V + λD_p is block diagonal, so V_λ⁻¹ is one small inverse
per point) leaves the reduced camera system

    S x_c = g_c - W V_λ⁻¹ g_p,   S = U + λD_c - W V_λ⁻¹ Wᵀ,

dense (n_cameras n_c square) and solved by Cholesky (`cholesky_solve`), then
x_p = V_λ⁻¹ (g_p - Wᵀ x_c).
(Triggs et al., "Bundle adjustment - a modern synthesis", 2000, section 6.1; Agarwal et
al., "Bundle adjustment in the large", ECCV 2010.)

Performance notes (XLA on CPU): per-observation products are accumulated a chunk at a
time (`jax.lax.scan` + scatter-add) so that they never exist for all observations at
once, and products of tiny matrices are written as short sums of broadcast products
(`_matmul`), which fuse, instead of batched `dot_general`s, which do not.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, Scalar

from .._cholesky import cholesky_solve
from ._problem import TwoBlockProblem, TwoBlockY


class NormalEquations(eqx.Module):
    """The Jacobian-dependent pieces of the normal equations (built once per accepted step).

    - `camera_hessian` U: (n_cameras, n_c, n_c); `point_hessian` V: (n_points, n_p, n_p);
    - `coupling` W_iᵀ = J_p,iᵀ J_c,i: (n_obs, n_p, n_c), stored transposed: the layout in
      which the reduced camera matrix's products read it without copies;
    - `camera_gradient` g_c: (n_cameras, n_c); `point_gradient` g_p: (n_points, n_p);
    - `camera_damping` D_c: (n_cameras, n_c); `point_damping` D_p: (n_points, n_p): the
      Marquardt diagonal, see `marquardt_diagonal`.
    """

    camera_hessian: Float[Array, "n_cameras n_c n_c"]
    point_hessian: Float[Array, "n_points n_p n_p"]
    coupling: Float[Array, "n_obs n_p n_c"]
    camera_gradient: Float[Array, "n_cameras n_c"]
    point_gradient: Float[Array, "n_points n_p"]
    camera_damping: Float[Array, "n_cameras n_c"]
    point_damping: Float[Array, "n_points n_p"]


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


def normal_equations(
    problem: TwoBlockProblem,
    y: TwoBlockY,
    residual: Float[Array, "n_obs k"],
    min_diagonal: float,
    max_diagonal: float,
) -> NormalEquations:
    """U, V, W, g and D at `y`, one chunk of observations at a time.

    `residual` is the residual vector at `y` (as the solver already has it).
    """
    cameras, points = y
    n_obs = problem.camera_index.shape[0]
    jacobian = problem.block_jacobian()
    n_c, n_p = cameras.shape[1], points.shape[1]

    def accumulate(totals, chunk):
        camera_hessian, point_hessian, camera_gradient, point_gradient = totals
        camera_row, point_row, data, r = chunk
        jc, jp = jax.vmap(jacobian)(
            cameras.at[camera_row].get(mode="clip"), points.at[point_row].get(mode="clip"), data
        )
        jc_t, jp_t = jc.transpose(0, 2, 1), jp.transpose(0, 2, 1)
        totals = (
            camera_hessian.at[camera_row].add(_matmul(jc_t, jc), mode="drop"),
            point_hessian.at[point_row].add(_matmul(jp_t, jp), mode="drop"),
            camera_gradient.at[camera_row].add(_matvec(jc_t, r), mode="drop"),
            point_gradient.at[point_row].add(_matvec(jp_t, r), mode="drop"),
        )
        return totals, _matmul(jp_t, jc)

    dtype = cameras.dtype
    zeros = (
        jnp.zeros((problem.n_cameras, n_c, n_c), dtype),
        jnp.zeros((problem.n_points, n_p, n_p), dtype),
        jnp.zeros((problem.n_cameras, n_c), dtype),
        jnp.zeros((problem.n_points, n_p), dtype),
    )
    chunks = (
        _chunked(problem.camera_index, problem.chunk_size, problem.n_cameras),
        _chunked(problem.point_index, problem.chunk_size, problem.n_points),
        jax.tree.map(lambda x: _chunked(x, problem.chunk_size), problem.data),
        _chunked(residual, problem.chunk_size),
    )
    totals, coupling = jax.lax.scan(accumulate, zeros, chunks)
    camera_hessian, point_hessian, camera_gradient, point_gradient = totals
    return NormalEquations(
        camera_hessian=camera_hessian,
        point_hessian=point_hessian,
        coupling=coupling.reshape(-1, n_p, n_c)[:n_obs],
        camera_gradient=camera_gradient,
        point_gradient=point_gradient,
        camera_damping=marquardt_diagonal(
            jnp.diagonal(camera_hessian, axis1=1, axis2=2), min_diagonal, max_diagonal
        ),
        point_damping=marquardt_diagonal(
            jnp.diagonal(point_hessian, axis1=1, axis2=2), min_diagonal, max_diagonal
        ),
    )


def solve_damped(
    problem: TwoBlockProblem, normal: NormalEquations, damping: Scalar
) -> tuple[Float[Array, "n_cameras n_c"], Float[Array, "n_points n_p"]]:
    """x = (JᵀJ + λD)⁻¹ Jᵀr in blocks (x_c, x_p), by the Schur complement on the points.

    `damping` is λ ≥ 0. A singular V_λ or an S that is not positive definite gives NaNs,
    which the trust region rejects like any step that does not reduce the cost.
    """
    cameras, points = problem.camera_index, problem.point_index
    point_inverse = _small_inverse(
        _add_diagonal(normal.point_hessian, damping * normal.point_damping)
    )
    # (W_i V_λ⁻¹)ᵀ = V_λ⁻¹ W_iᵀ for every observation, (n_obs, n_p, n_c).
    eliminated = _matmul(point_inverse[points], normal.coupling)
    reduced = _reduced_camera_matrix(problem, normal, eliminated, damping)
    reduced_gradient = normal.camera_gradient - jax.ops.segment_sum(
        _matvec(eliminated.transpose(0, 2, 1), normal.point_gradient[points]),
        cameras,
        problem.n_cameras,
    )
    camera_step = cholesky_solve(reduced, jnp.ravel(reduced_gradient))
    camera_step = camera_step.reshape(reduced_gradient.shape)
    coupled = _matvec(normal.coupling, camera_step[cameras])
    point_rhs = normal.point_gradient - jax.ops.segment_sum(coupled, points, problem.n_points)
    return camera_step, _matvec(point_inverse, point_rhs)


def predicted_reduction(
    problem: TwoBlockProblem, normal: NormalEquations, y_diff: TwoBlockY
) -> Scalar:
    """δᵀJᵀr + ½ δᵀJᵀJδ for the step δ = `y_diff` = (δ_c, δ_p): the Gauss-Newton model's
    change of ½|r|², with δᵀJᵀJδ = δ_cᵀUδ_c + δ_pᵀVδ_p + 2 Σ_i δ_p,iᵀ W_iᵀ δ_c,i."""
    camera_step, point_step = y_diff
    # One einsum: the sum of gathered products written out ran ~5x slower on the CPU.
    coupled = jnp.einsum("npc,nc,np->", normal.coupling, camera_step[problem.camera_index],
                         point_step[problem.point_index])
    quadratic = (
        jnp.sum(camera_step * _matvec(normal.camera_hessian, camera_step))
        + jnp.sum(point_step * _matvec(normal.point_hessian, point_step))
        + 2.0 * coupled
    )
    linear = jnp.sum(camera_step * normal.camera_gradient) + jnp.sum(
        point_step * normal.point_gradient)
    return linear + 0.5 * quadratic


def _reduced_camera_matrix(
    problem: TwoBlockProblem,
    normal: NormalEquations,
    eliminated: Float[Array, "n_obs n_p n_c"],
    damping: Scalar,
) -> Float[Array, "n_cameras*n_c n_cameras*n_c"]:
    """S = U + λD_c - W V_λ⁻¹ Wᵀ, dense, in camera-major order (row a n_c + k).

    Block (a_i, a_j) of W V_λ⁻¹ Wᵀ collects (W_i V_λ⁻¹) W_jᵀ over all pairs (i, j) of
    observations of the same point; only the lower block triangle (a_i >= a_j) is
    accumulated (`pair_block_sums` over `problem.pair_*`) and the rest mirrored.
    """
    n_cameras, n_c = normal.camera_gradient.shape
    lower = pair_block_sums(
        eliminated, normal.coupling, problem.pair_first, problem.pair_second,
        problem.pair_block, n_cameras * n_cameras,
    )
    lower = lower.reshape(n_cameras, n_cameras, n_c, n_c)
    off_diagonal = ~jnp.eye(n_cameras, dtype=bool)[:, :, None, None]
    product = lower + jnp.where(off_diagonal, lower.transpose(1, 0, 3, 2), 0.0)
    index = jnp.arange(n_cameras)
    diagonal = _add_diagonal(normal.camera_hessian, damping * normal.camera_damping)
    blocks = (-product).at[index, index].add(diagonal)
    return blocks.transpose(0, 2, 1, 3).reshape(n_cameras * n_c, n_cameras * n_c)


def pair_block_sums(
    left: Float[Array, "n_obs k a"],
    right: Float[Array, "n_obs k b"],
    first: Int[Array, "n_chunks rows row_size"],
    second: Int[Array, "n_chunks rows row_size"],
    block: Int[Array, "n_chunks rows"],
    n_blocks: int,
) -> Float[Array, "n_blocks a b"]:
    """Σ left_iᵀ right_j over the pairs (i, j) of every block, (n_blocks, a, b).

    The pairs come in rows of one block each (`_problem._block_rows`; padding pairs hold
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
        products = _matmul(lhs.transpose(0, 2, 1), rhs)
        return total.at[block].add(products, mode="drop", indices_are_sorted=True), None

    zero = jnp.zeros((n_blocks, left.shape[-1], right.shape[-1]), left.dtype)
    total, _ = jax.lax.scan(accumulate, zero, (first, second, block))
    return total


def _chunked(x: Array, chunk_size: int, fill: int | None = None) -> Array:
    """`x` (n, ...) padded to a multiple of `chunk_size` and reshaped (n_chunks, chunk_size, ...).

    Index arrays are padded with `fill` (out of range: dropped by scatters, clipped by
    gathers); data arrays repeat their last row, so that padding evaluates harmlessly.
    """
    padding = -x.shape[0] % chunk_size
    widths = [(0, padding)] + [(0, 0)] * (x.ndim - 1)
    if fill is None:
        padded = jnp.pad(x, widths, mode="edge")
    else:
        padded = jnp.pad(x, widths, constant_values=fill)
    return padded.reshape(-1, chunk_size, *x.shape[1:])


def _matmul(a: Float[Array, "n i k"], b: Float[Array, "n k j"]) -> Float[Array, "n i j"]:
    """a[n] @ b[n] for many small matrices, the short sum over k written out.

    XLA on CPU runs batched `dot_general`s of tiny matrices slowly; a sum of k
    broadcast products fuses into one loop.
    """
    return sum(a[:, :, k, None] * b[:, None, k, :] for k in range(a.shape[-1]))


def _matvec(a: Float[Array, "n i k"], v: Float[Array, "n k"]) -> Float[Array, "n i"]:
    """a[n] @ v[n] for many small matrices (see `_matmul`)."""
    return sum(a[:, :, k] * v[:, k, None] for k in range(a.shape[-1]))


def _small_inverse(a: Float[Array, "n m m"]) -> Float[Array, "n m m"]:
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


def _add_diagonal(
    matrices: Float[Array, "m n n"], diagonals: Float[Array, "m n"]
) -> Float[Array, "m n n"]:
    """matrices[i] + diag(diagonals[i]) for every i."""
    return matrices + diagonals[:, :, None] * jnp.eye(matrices.shape[-1], dtype=matrices.dtype)
