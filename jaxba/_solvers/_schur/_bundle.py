"""Schur-complement Levenberg-Marquardt for photogrammetric bundles (`BundleProblem`).

The unknowns split into a reduced ("camera") side and an eliminated point side:

- reduced side, r: all IOPs of all camera models (shared by the images that use them), all
  EOPs, the rig cameras' relative poses (`Parameters.mounts`, where there are rigs) and the
  object points touched by `Distances` (a distance couples two points, so they cannot be
  eliminated one by one), in that order;
- point side, e: every other object point, 3 unknowns each.

Image observation i touches one IOP row, one EOP row (and in a rig one mount row) and one
point, so its Jacobian splits into J_r,i (2 x m: the model's free IOPs + 6 EOPs (+ 6 of the
mount), plus 3 for a reduced-side point) and
J_e,i (2 x 3). With U = Σ J_rᵀJ_r + priors (dense, n_r x n_r), V_p = Σ_{i∈p} J_e,iᵀJ_e,i +
control (3 x 3 per point), W_i = J_r,iᵀ J_e,i and g = Jᵀe, the damped normal equations
reduce to

    S x_r = g_r - Σ_p Y_pᵀ V_λ,p⁻¹ g_e,p,   S = U + λD_r - Σ_p Y_pᵀ V_λ,p⁻¹ Y_p,

Y_p = Σ_{i∈p} W_iᵀ (3 x n_r, the coupling of point p with the reduced side), then
x_e,p = V_λ,p⁻¹ (g_e,p - Y_p x_r) (Triggs et al., "Bundle adjustment - a modern synthesis",
2000, section 6.1). S is assembled pair-wise, as BAL's reduced camera matrix
(`_normal.py`): Y_pᵀ V⁻¹ Y_p = Σ_{i,j∈p} W_i V⁻¹ W_jᵀ over the pairs of observations of
each point, the pairs of one key pair (same reduced columns: for one camera, one pair of
images) summed first and scattered once into the dense S. Work O(n_pairs m²) per trial step
(n_pairs = Σ_p n_obs,p²/2), memory O(n_obs m + n_r²); U is summed per key the same way.

Fixed unknowns (False in `problem.free`) get zero Jacobian columns and a unit diagonal:
their step is exactly 0. Control points / GNSS-INS / IOP priors (`ParameterObservations`)
add 1/σ² to the diagonal of V (eliminated points) or U (everything else).
"""


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, Scalar

from ..._models._poses import POSE_MODELS
from ..._problem._bundle import BundleProblem, tie_source
from ..._problem._observations import (
    Distances,
    ImagePoints,
    ParameterObservations,
    _frame_collinearity_residual,
    row_pose,
)
from ..._problem._parameters import Parameters, flatten, unflatten
from .._cholesky import cholesky_solve
from ._normal import (
    _add_diagonal,
    _matmul,
    _small_inverse,
    marquardt_diagonal,
    pair_block_sums,
    point_inverse,
)
from ._pairs import block_rows, same_point_pairs

# Observation pairs per row of the S assembly: a row's product is a sum of 24 broadcast
# products, which on the CPU ran ~7 % faster than rows of 16 and ~25 % faster than 32 (BAL).
PAIR_ROW_SIZE = 8
# The statistics' point cofactors pair-wise take ~n_pairs k² multiply-adds, as sums of
# broadcast products and scatters; densely, ~n_eliminated (n_r + 1)² in matrix products,
# which run faster per multiply-add: pair-wise where the first count times this is the
# smaller. Measured with the redundancy numbers (benchmarks/blocks.py, warm, one CPU):
# block A (26,200 points seen ~3.4 times each; 1.37e2 times fewer pair-wise) 0.19 s
# pair-wise against 0.92 s densely; block B (148 targets seen ~65 times each; 1.18 times
# fewer) 0.18 s against 0.09 s.
PAIRWISE_ADVANTAGE = 8.0


class BundleStructure(eqx.Module):
    """Index arrays of the Schur split of one `BundleProblem` (built by `bundle_structure`).

    Reduced columns are numbered 0..n_reduced-1 (cameras by sorted model name, then images,
    then mounts, then the reduced points); column n_reduced is a dummy that absorbs padding.
    Observation rows: the image observations of all ImagePoints groups, group after group,
    each group's by key (`image_order`: row r is observation `image_order[r]` of the groups
    concatenated), then one padding observation.
    - `image_columns`: (n_image_obs + 1, m) reduced columns of every observation row: the
      model's IOPs in `iop_columns`, the 6 EOPs (of a rig frame, then the 6 of the row's
      mount where the group has `mount`), padding, and the 3 columns of a reduced
      point (`point_width` 3 where some points are reduced, else 0: no such columns);
    - `image_point`: (n_image_obs + 1,) eliminated-point index, n_eliminated for a reduced
      point or the padding row;
    - `key`, `key_columns`: observations with equal reduced columns share a key; U sums the
      per-key blocks (n_keys, m) before one dense scatter; `key_rows` (n_key_chunks, rows,
      PAIR_ROW_SIZE), `key_row_block` (n_key_chunks, rows): the image observations in rows
      of one key each (`_pairs.block_rows`, padding as for the pairs below);
    - `pair_first`, `pair_second` (n_pair_chunks, rows, PAIR_ROW_SIZE), `pair_block`
      (n_pair_chunks, rows): the ordered pairs (i, j) of image observations of one
      eliminated point with key_i >= key_j (i = j included), in rows of one key pair each
      (`_pairs.block_rows`; padding: observation n_image_obs, block n_key_pairs);
      `key_pairs` (n_key_pairs, 2): the (key_i, key_j) of every block;
    - `chunk_obs` (n_chunks, max_obs), `chunk_local` (n_chunks, max_obs), `chunk_points`
      (n_chunks, points_per_chunk): the image observations of each chunk of eliminated
      points, for the statistics' point cofactors where they are formed densely (padding:
      observation n_image_obs / local point points_per_chunk / point n_eliminated);
      `pairwise`: they are summed over the pairs instead
      (`_schur_precision._observation_cofactors`);
    - `reduced_points`, `eliminated_points`: row numbers in `points`; `point_column`:
      (n_points,) first reduced column of a reduced point, -1 otherwise;
    - `eliminated_index`: (n_points,) row in the eliminated block, n_eliminated otherwise;
    - `camera_column`: the reduced column of every camera parameter (`flatten` order): its
      own, or its tie's source's (`BundleProblem.ties`; a tied one's own column stays
      empty, as a fixed unknown's);
    - `iop_columns`: per model (in `models` order), the IOPs free or tied in some camera of
      it: the only IOP columns an observation carries (fixed ones would be zero).
    """

    image_columns: Int[Array, "n_obs1 m"]
    image_point: Int[Array, " n_obs1"]
    image_order: Int[Array, " n_obs"]
    key: Int[Array, " n_obs1"]
    key_columns: Int[Array, "n_keys m"]
    key_rows: Int[Array, "n_key_chunks rows row_size"]
    key_row_block: Int[Array, "n_key_chunks rows"]
    pair_first: Int[Array, "n_pair_chunks rows row_size"]
    pair_second: Int[Array, "n_pair_chunks rows row_size"]
    pair_block: Int[Array, "n_pair_chunks rows"]
    key_pairs: Int[Array, "n_key_pairs 2"]
    chunk_obs: Int[Array, "n_chunks max_obs"]
    chunk_local: Int[Array, "n_chunks max_obs"]
    chunk_points: Int[Array, "n_chunks points_per_chunk"]
    reduced_points: Int[Array, " n_reduced_points"]
    eliminated_points: Int[Array, " n_eliminated"]
    point_column: Int[Array, " n_points"]
    eliminated_index: Int[Array, " n_points"]
    camera_column: Int[Array, " n_iop_all"]
    models: tuple[str, ...] = eqx.field(static=True)
    iop_columns: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    camera_offsets: tuple[int, ...] = eqx.field(static=True)
    image_offset: int = eqx.field(static=True)
    mount_offset: int = eqx.field(static=True)
    n_reduced: int = eqx.field(static=True)
    m: int = eqx.field(static=True)
    point_width: int = eqx.field(static=True)
    points_per_chunk: int = eqx.field(static=True)
    pairwise: bool = eqx.field(static=True)
    jacobian_batch: int = eqx.field(static=True)


def bundle_structure(
    problem: BundleProblem,
    *,
    chunk_mib: float = 64.0,
    jacobian_batch: int = 4096,
    pair_batch: int = 4096,
    pairwise: bool | None = None,
) -> BundleStructure:
    """The Schur split of `problem` (NumPy, before any tracing).

    `chunk_mib` bounds the dense coupling matrix of one chunk of points (3 P x n_reduced
    doubles) where the statistics form the point cofactors densely; `jacobian_batch` is the
    number of image observations differentiated at once, `pair_batch` the number of
    observation pairs multiplied at once in S and in the pair-wise cofactors; `pairwise`:
    how the cofactors are formed (`_schur_precision._observation_cofactors`), None: by the
    work each takes (`PAIRWISE_ADVANTAGE`). The split depends on `problem.free`
    (`iop_columns`): rebuild it when the free mask changes. Raises `ValueError` for
    observation groups other than ImagePoints, ParameterObservations and Distances.
    """
    initial = problem.initial
    models = tuple(sorted(initial.cameras))
    offsets, column = [], 0
    for model in models:
        offsets.append(column)
        column += int(np.size(initial.cameras[model]))
    image_offset = column
    column += int(np.size(initial.images))
    mount_offset = column
    column += 0 if initial.mounts is None else int(np.size(initial.mounts))
    n_points = int(initial.points.shape[0])
    coupled = []
    for group in problem.groups:
        if isinstance(group, Distances):
            coupled += [np.asarray(group.a), np.asarray(group.b)]
        elif not isinstance(group, ImagePoints | ParameterObservations):
            raise ValueError(
                f"solve_schur cannot split observation group {group.name!r} of type"
                f" {type(group).__name__}: only ImagePoints, ParameterObservations, Distances"
            )
    reduced_points = np.unique(np.concatenate(coupled)) if coupled else np.zeros(0, int)
    point_column = np.full(n_points, -1, dtype=np.int64)
    point_column[reduced_points] = column + 3 * np.arange(reduced_points.size)
    n_reduced = column + 3 * reduced_points.size
    is_eliminated = point_column < 0
    eliminated_points = np.flatnonzero(is_eliminated)
    n_eliminated = eliminated_points.size
    eliminated_index = np.full(n_points, n_eliminated, dtype=np.int64)
    eliminated_index[eliminated_points] = np.arange(n_eliminated)

    # A camera's reduced columns are its `flatten` positions (cameras come first in both
    # orders); a tied IOP's observations go to its source's column (`tie_source`).
    camera_column = tie_source(problem)[:image_offset]
    tied = unflatten(initial, np.isin(np.arange(flatten(initial).size),
                                      [dependent for dependent, _ in problem.ties]))
    iop_columns = tuple(
        tuple(int(c) for c in np.flatnonzero(np.any(
            np.asarray(problem.free.cameras[model]) | tied.cameras[model], 0)))
        for model in models
    )
    images = [g for g in problem.groups if isinstance(g, ImagePoints)]
    point_width = 3 if reduced_points.size else 0
    mounted = any(g.mount is not None for g in images)
    m = max([len(iop_columns[models.index(g.model)]) for g in images], default=0) + 6
    m += 6 * mounted + point_width
    columns, point_rows = [], []
    for group in images:
        model_index = models.index(group.model)
        n_iop = int(initial.cameras[group.model].shape[1])
        free_iop = np.asarray(iop_columns[model_index], dtype=np.int64)
        camera, image, point = (np.asarray(a) for a in (group.camera, group.image, group.point))
        block = np.full((camera.size, m), n_reduced, dtype=np.int64)
        block[:, : free_iop.size] = camera_column[
            offsets[model_index] + camera[:, None] * n_iop + free_iop]
        block[:, free_iop.size : free_iop.size + 6] = (
            image_offset + image[:, None] * 6 + np.arange(6)
        )
        if group.mount is not None:
            block[:, free_iop.size + 6 : free_iop.size + 12] = (
                mount_offset + np.asarray(group.mount)[:, None] * 6 + np.arange(6))
        reduced = point_column[point] >= 0
        block[reduced, m - 3 :] = point_column[point[reduced], None] + np.arange(3)
        columns.append(block)
        point_rows.append(eliminated_index[point])
    columns.append(np.full((1, m), n_reduced, dtype=np.int64))
    point_rows.append(np.array([n_eliminated]))
    columns, point_rows = np.concatenate(columns), np.concatenate(point_rows)
    key_columns, key = np.unique(columns, axis=0, return_inverse=True)
    key = np.ravel(key)
    n_obs = columns.shape[0] - 1
    # Each group's observations by key (stable), the padding row last: S's pair products
    # then gather from one key's rows at a time (Dubrovnik-16, listed by point: 19 -> 13 ms).
    group = np.repeat(np.arange(len(images)), [g.point.shape[0] for g in images])
    order = np.append(np.lexsort((key[:n_obs], group)), n_obs)
    columns, point_rows, key = columns[order], point_rows[order], key[order]
    *pairs, key_pairs = _observation_pairs(point_rows[:n_obs], key[:n_obs], n_eliminated,
                                           pair_batch)
    observations = np.arange(n_obs)
    key_rows, _, key_row_block = block_rows(
        observations, observations, key[:n_obs], key_columns.shape[0], fill=n_obs,
        row_size=PAIR_ROW_SIZE, rows_per_chunk=max(1, pair_batch // PAIR_ROW_SIZE),
    )
    chunks = _point_chunks(point_rows[:n_obs], n_eliminated, n_reduced, chunk_mib)
    if pairwise is None:  # multiply-adds of each way to form the cofactors
        k = m - point_width
        n_pairs = int(np.count_nonzero(pairs[0] < n_obs))
        pairwise = PAIRWISE_ADVANTAGE * n_pairs * k * k < n_eliminated * (n_reduced + 1) ** 2

    return BundleStructure(
        image_columns=jax.device_put(columns),
        image_point=jax.device_put(point_rows),
        image_order=jax.device_put(order[:n_obs]),
        key=jax.device_put(key),
        key_columns=jax.device_put(key_columns),
        key_rows=jax.device_put(key_rows),
        key_row_block=jax.device_put(key_row_block),
        pair_first=jax.device_put(pairs[0]),
        pair_second=jax.device_put(pairs[1]),
        pair_block=jax.device_put(pairs[2]),
        key_pairs=jax.device_put(key_pairs),
        chunk_obs=jax.device_put(chunks[0]),
        chunk_local=jax.device_put(chunks[1]),
        chunk_points=jax.device_put(chunks[2]),
        reduced_points=jax.device_put(reduced_points),
        eliminated_points=jax.device_put(eliminated_points),
        point_column=jax.device_put(point_column),
        eliminated_index=jax.device_put(eliminated_index),
        camera_column=jax.device_put(camera_column),
        models=models,
        iop_columns=iop_columns,
        camera_offsets=tuple(offsets),
        image_offset=image_offset,
        mount_offset=mount_offset,
        n_reduced=int(n_reduced),
        m=int(m),
        point_width=point_width,
        points_per_chunk=chunks[2].shape[1],
        pairwise=bool(pairwise),
        jacobian_batch=int(jacobian_batch),
    )


def _point_chunks(
    point_rows: np.ndarray, n_eliminated: int, n_reduced: int, chunk_mib: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`BundleStructure.chunk_obs`, `.chunk_local`, `.chunk_points` from every image
    observation's row in the eliminated block (`point_rows`, n_eliminated for reduced
    points): the eliminated points in chunks whose dense coupling (3 P x (n_r + 1)) fits
    in `chunk_mib`."""
    per_chunk = int(max(1, min(n_eliminated, chunk_mib * 2**20 / (24 * (n_reduced + 1)))))
    n_chunks = max(1, -(-n_eliminated // per_chunk))
    order = np.argsort(point_rows, kind="stable")
    order = order[point_rows[order] < n_eliminated]
    chunk_of = point_rows[order] // per_chunk
    counts = np.bincount(chunk_of, minlength=n_chunks)
    max_obs = max(1, int(counts.max(initial=0)))
    chunk_obs = np.full((n_chunks, max_obs), point_rows.size, dtype=np.int64)
    chunk_local = np.full((n_chunks, max_obs), per_chunk, dtype=np.int64)
    rank = np.arange(order.size) - (np.cumsum(counts) - counts)[chunk_of]
    chunk_obs[chunk_of, rank] = order
    chunk_local[chunk_of, rank] = point_rows[order] - chunk_of * per_chunk
    chunk_points = np.arange(n_chunks * per_chunk).reshape(n_chunks, per_chunk)
    return chunk_obs, chunk_local, np.minimum(chunk_points, n_eliminated)


def _observation_pairs(
    point_rows: np.ndarray, key: np.ndarray, n_eliminated: int, pair_batch: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of image observations of one eliminated point that S needs (NumPy).

    `point_rows`, `key`: (n_image_obs,) eliminated-point row (n_eliminated: none) and key
    of every observation. Returns first, second, block as `_pairs.block_rows` lays them
    out (pairs with key_i >= key_j, rows of `PAIR_ROW_SIZE` pairs of one key pair, padded
    with observation n_image_obs) and the key pairs (n_key_pairs, 2).
    """
    observed = np.flatnonzero(point_rows < n_eliminated)
    first, second = same_point_pairs(point_rows[observed], n_eliminated)
    first, second = observed[first], observed[second]
    lower = key[first] >= key[second]
    first, second = first[lower], second[lower]
    n_keys = int(key.max()) + 1 if key.size else 1
    codes, block = np.unique(key[first] * n_keys + key[second], return_inverse=True)
    key_pairs = np.stack([codes // n_keys, codes % n_keys], axis=1)  # (row-major) sorted
    rows = block_rows(
        first, second, np.ravel(block), key_pairs.shape[0], fill=point_rows.size,
        row_size=PAIR_ROW_SIZE, rows_per_chunk=max(1, pair_batch // PAIR_ROW_SIZE),
    )
    return *rows, key_pairs


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


def _reduced_vector(
    structure: BundleStructure, params: Parameters, xp=jnp
) -> Float[Array, " n_r"]:
    """The reduced-side entries of a Parameters tree (values, masks) as one vector; `xp`
    numpy for a tree of NumPy arrays (no program compiled)."""
    parts = [xp.ravel(params.cameras[model]) for model in structure.models]
    parts += [xp.ravel(params.images)]
    parts += [] if params.mounts is None else [xp.ravel(params.mounts)]
    parts += [xp.ravel(params.points[structure.reduced_points])]
    return xp.concatenate(parts).astype(params.images.dtype)


def _to_parameters(
    structure: BundleStructure, like: Parameters, reduced: Array, eliminated: Array
) -> Parameters:
    """Inverse of the split: reduced (n_r,) and eliminated (n_e, 3) into a Parameters tree."""
    cameras = {}
    for model, offset in zip(structure.models, structure.camera_offsets):
        shape = like.cameras[model].shape
        cameras[model] = reduced[offset : offset + int(np.prod(shape))].reshape(shape)
    n_images = like.images.shape[0]
    images = reduced[structure.image_offset : structure.image_offset + 6 * n_images]
    mounts = None
    if like.mounts is not None:
        mounts = reduced[structure.mount_offset:structure.mount_offset + like.mounts.size]
        mounts = mounts.reshape(like.mounts.shape)
    points = jnp.zeros_like(like.points)
    points = points.at[structure.eliminated_points].set(eliminated)
    start = structure.mount_offset + (0 if like.mounts is None else like.mounts.size)
    points = points.at[structure.reduced_points].set(reduced[start:].reshape(-1, 3))
    return Parameters(cameras=cameras, images=images.reshape(n_images, 6), points=points,
                      mounts=mounts)


def _free_masks(problem: BundleProblem, structure: BundleStructure, dtype) -> tuple[Array, Array]:
    """1.0 on free unknowns: reduced columns (n_r + 1,) and eliminated points (n_e + 1, 3),
    each with a padding entry 0."""
    free_r = jnp.append(_reduced_vector(structure, problem.free), 0.0).astype(dtype)
    free_e = problem.free.points.astype(dtype)[structure.eliminated_points]
    return free_r, jnp.concatenate([free_e, jnp.zeros((1, 3), dtype)])


def bundle_normal_equations(
    problem: BundleProblem,
    structure: BundleStructure,
    params: Parameters,
    min_diagonal: float = 1e-6,
    max_diagonal: float = 1e32,
) -> BundleNormalEquations:
    """U, V, W, g and the Marquardt damping of `problem` at `params` (all unknowns' values)."""
    n_r = structure.n_reduced
    n_e = structure.eliminated_points.shape[0]
    dtype = params.images.dtype
    free_r, free_e = _free_masks(problem, structure, dtype)
    free_points = problem.free.points.astype(dtype)

    jr, je, e = _image_blocks(problem, structure, params, free_r, free_e)
    per_key = pair_block_sums(
        jr, jr, structure.key_rows, structure.key_rows, structure.key_row_block,
        structure.key_columns.shape[0],
    )
    key_columns = structure.key_columns
    hessian = _dense_from_blocks(n_r, key_columns, key_columns, per_key)
    gradient = _add_at_columns(structure, _transposed_product(jr, e))
    point_hessian = jnp.zeros((n_e + 1, 3, 3), dtype).at[structure.image_point].add(_gram(je, je))
    point_gradient = jnp.zeros((n_e + 1, 3), dtype).at[structure.image_point].add(
        _transposed_product(je, e)
    )
    coupling = _gram(je, jr)

    # The direct observations' residuals only: the image points' are the blocks' own (the
    # whole `problem.residuals` traced and lowered them again, 0.1-0.2 s a program).
    full = problem.with_free(params)
    for group in problem.groups:
        if isinstance(group, ParameterObservations):
            # Whitened as `BundleProblem.whitened` (a robust loss is for image points only).
            residual = jnp.where(group.mask(), group.residuals(full, problem.refraction), 0.0)
            # e = (observed - x) / σ: ∂e/∂x = -1/σ on the observed entries.
            derivative = jnp.where(group.mask(), -1.0 / group.stddev, 0.0).astype(dtype)
            rows = jnp.asarray(group.rows)
            if group.block == "points":
                point_row_p = structure.eliminated_index[rows]
                column = jnp.where(
                    structure.point_column[rows] >= 0, structure.point_column[rows], n_r
                )
                sub = free_points[rows] * derivative
                eliminated = (point_row_p < n_e)[:, None]
                point_hessian = point_hessian.at[point_row_p].add(
                    jnp.where(eliminated, sub, 0.0)[:, :, None] ** 2 * jnp.eye(3, dtype=dtype)
                )
                point_gradient = point_gradient.at[point_row_p].add(
                    jnp.where(eliminated, sub * residual, 0.0)
                )
                reduced_sub = jnp.where(eliminated, 0.0, sub)
                reduced_columns = column[:, None] + jnp.arange(3)
                reduced_columns = jnp.where(eliminated, n_r, reduced_columns)
            else:
                reduced_columns = _block_columns(structure, group)
                reduced_sub = free_r[reduced_columns] * derivative
            hessian = hessian.at[reduced_columns, reduced_columns].add(reduced_sub**2)
            gradient = gradient.at[reduced_columns].add(reduced_sub * residual)
        elif isinstance(group, Distances):
            jd, e_d = _distance_jacobians(problem, group, params)
            cols = _distance_columns(structure, group)
            jd = jd * free_r[cols][:, None, :]
            hessian = hessian.at[cols[:, :, None], cols[:, None, :]].add(_gram(jd, jd))
            gradient = gradient.at[cols].add(jnp.sum(jd * e_d[:, :, None], axis=1))

    hessian, gradient = hessian[:n_r, :n_r], gradient[:n_r]
    point_hessian, point_gradient = point_hessian[:n_e], point_gradient[:n_e]
    fixed_r = 1.0 - free_r[:n_r]
    fixed_e = 1.0 - free_e[:n_e]
    hessian = hessian + jnp.diag(fixed_r)
    point_hessian = _add_diagonal(point_hessian, fixed_e)
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
    normal = bundle_normal_equations(problem, structure, params)
    point_inverse = _small_inverse(normal.point_hessian)
    product, _ = _schur_complement(structure, normal, point_inverse)
    return normal, normal.reduced_hessian + product, point_inverse


# One program of its own for the datum check (at the approximations) and the statistics (at
# the solution), which would otherwise each compile the normal equations inside theirs:
# `bundle_normal_equations` at `params`, S = U - Σ_p Y_pᵀ V_p⁻¹ Y_p (n_r, n_r) and V⁻¹
# (n_e, 3, 3). (The datum check's S was a second program, 0.2 s to load in every process.)
compiled_normal_equations = jax.jit(_normal_and_reduced)


def _block_columns(structure: BundleStructure, group: ParameterObservations) -> Array:
    """(n, width) reduced columns of the observed rows of a camera, image or mount block."""
    width = group.observed.shape[1]
    if group.block in ("images", "mounts"):
        start = structure.image_offset if group.block == "images" else structure.mount_offset
        return start + jnp.asarray(group.rows)[:, None] * width + jnp.arange(width)
    model = group.block.removeprefix("cameras/")
    start = structure.camera_offsets[structure.models.index(model)]
    return structure.camera_column[start + jnp.asarray(group.rows)[:, None] * width
                                   + jnp.arange(width)]


def _distance_columns(structure: BundleStructure, group: Distances) -> Array:
    """(n, 6) reduced columns of the two end points of every distance (reduced points)."""
    return jnp.concatenate([
        structure.point_column[group.a][:, None] + jnp.arange(3),
        structure.point_column[group.b][:, None] + jnp.arange(3),
    ], axis=1)


def _reduced_positions(problem: BundleProblem, structure: BundleStructure) -> np.ndarray:
    """(n_r,) `flatten` positions of the reduced columns."""
    positions = unflatten(problem.initial, np.arange(flatten(problem.initial).size))
    return _reduced_vector(structure, positions, np).astype(int)


def _add_at_columns(
    structure: BundleStructure, per_observation: Float[Array, "n_obs1 w"]
) -> Float[Array, " n_r1"]:
    """Σ_i per_observation_i added at observation i's first w reduced columns, (n_r + 1,)
    (last: padding): summed per key first (observations of one key share their columns),
    then n_keys rows scattered, not n_obs (a scatter-add of every observation's entries
    into a short vector runs serially on the CPU)."""
    width = per_observation.shape[1]
    per_key = jax.ops.segment_sum(per_observation, structure.key, structure.key_columns.shape[0])
    zero = jnp.zeros(structure.n_reduced + 1, per_observation.dtype)
    return zero.at[structure.key_columns[:, :width]].add(per_key)


def _at_columns(structure: BundleStructure, x_padded: Float[Array, " n_r1"]) -> Array:
    """(n_obs1, m) the entries of `x_padded` (n_r + 1,) at every image observation's
    reduced columns, gathered per key, then a row per observation."""
    return x_padded[structure.key_columns][structure.key]


def _gram(a: Float[Array, "n k i"], b: Float[Array, "n k j"]) -> Float[Array, "n i j"]:
    """aᵀb per observation, the short sum over the residual entries k written out."""
    return sum(a[:, k, :, None] * b[:, k, None, :] for k in range(a.shape[1]))


def _transposed_product(a: Float[Array, "n k i"], e: Float[Array, "n k"]) -> Float[Array, "n i"]:
    """aᵀe per observation (a Jacobian block times its residual: the gradient part)."""
    return jnp.sum(a * e[:, :, None], axis=1)


def _image_blocks(
    problem: BundleProblem,
    structure: BundleStructure,
    params: Parameters,
    free_r: Array,
    free_e: Array,
) -> tuple[Float[Array, "n_obs1 2 m"], Float[Array, "n_obs1 2 3"], Float[Array, "n_obs1 2"]]:
    """jr, je and e (`_image_jacobian_blocks`) of all image observations in the structure's
    order, with a zero padding row last; `structure.jacobian_batch` observations are
    differentiated at a time (`jax.lax.scan`). Memory O(n_obs m), as W's."""
    params = problem.with_free(params)
    dtype = params.images.dtype
    free_keys = free_r[structure.key_columns]  # (n_keys, m): observations of a key share it
    parts, start = [], 0
    for group in problem.groups:
        if not isinstance(group, ImagePoints):
            continue
        stop = start + group.point.shape[0]

        def blocks(_, chunk, group=group):
            return None, _image_jacobian_blocks(
                problem, structure, group, params, free_keys, free_e, list(chunk))

        _, out = jax.lax.scan(blocks, None, _image_group_chunks(structure, group, start, stop))
        parts.append([x.reshape(-1, *x.shape[2:])[: stop - start] for x in out])
        start = stop
    padding = [jnp.zeros((1, 2, structure.m), dtype), jnp.zeros((1, 2, 3), dtype),
               jnp.zeros((1, 2), dtype)]
    return tuple(jnp.concatenate([*(p[i] for p in parts), padding[i]]) for i in range(3))


def _image_group_chunks(structure: BundleStructure, group: ImagePoints, start: int, stop: int):
    """One ImagePoints group's observations (camera, image, point, measured, σ, mask,
    eliminated-point row, key, and the mount where the group has one), rows
    `start`..`stop` of the structure (the group's observations in `image_order`), in chunks
    of `structure.jacobian_batch` (n_chunks, batch, ...); padding repeats the last
    observation, masked out, with out-of-range point row and key."""
    n = stop - start
    batch = max(1, min(structure.jacobian_batch, n))
    pad = -n % batch
    rows = structure.image_order[start:stop] - start

    def chunked(x, fill=None):
        widths = [(0, pad)] + [(0, 0)] * (x.ndim - 1)
        if fill is None:
            x = jnp.pad(x, widths, mode="edge")
        else:
            x = jnp.pad(x, widths, constant_values=fill)
        return x.reshape(-1, batch, *x.shape[1:])

    mount = () if group.mount is None else (chunked(group.mount[rows]),)
    return (
        chunked(group.camera[rows]),
        chunked(group.image[rows]),
        chunked(group.point[rows]),
        chunked(group.measured[rows]),
        chunked(group.stddev[rows]),
        chunked(group.mask()[rows], False),
        chunked(structure.image_point[start:stop], structure.eliminated_points.shape[0]),
        chunked(structure.key[start:stop], structure.key_columns.shape[0]),
        *mount,
    )


def _image_jacobian_blocks(
    problem: BundleProblem,
    structure: BundleStructure,
    group: ImagePoints,
    params: Parameters,
    free_keys: Array,
    free_e: Array,
    observations: list[Array],
) -> tuple[Float[Array, "n 2 m"], Float[Array, "n 2 3"], Float[Array, "n 2"]]:
    """Jacobian blocks of a batch of one group's observations (`_image_group_chunks`
    rows) at `params` (all values set): jr over the observation's reduced columns (a
    reduced point's columns included), je over its eliminated point (0 for a reduced
    one), both 0 in fixed columns (`free_keys`: 1.0 on the free columns of every key;
    `free_e` as `_free_masks`'), and e. The residual differentiated is the one
    the solver minimises: whitened, masked, robustified (`BundleProblem.residuals`).
    Only the IOPs in `structure.iop_columns` are differentiated. The image's pose enters
    through its pose model's `row_frame` (from `row_inputs`, made once per image),
    differentiated by the parameter offset δ at δ = 0."""
    camera, image, point, measured, sigma, mask, point_row, key, *mount = observations
    iop_columns = np.asarray(structure.iop_columns[structure.models.index(group.model)], int)
    m, n_iop = structure.m, iop_columns.size
    all_iops = n_iop == params.cameras[group.model].shape[1]
    dtype = params.images.dtype
    pose = POSE_MODELS[group.pose]

    width = 12 if mount else 6

    def residual(free_iop, delta, point, iop, pose_inputs, data):
        iop = free_iop if all_iops else iop.at[iop_columns].set(free_iop)
        e = _frame_collinearity_residual(
            group.model, iop, row_pose(pose, pose_inputs, delta, bool(mount)), point,
            *data[:2], problem.refraction, group.constants,
        )
        e = jnp.where(data[2], e, 0.0)
        e = e if problem.robust is None else problem.robust(e)
        return e, e

    def one(iop, pose_inputs, point, *data):
        arguments = (iop[iop_columns], jnp.zeros(width, dtype), point, iop, pose_inputs, data)
        (j_iop, j_pose, j_point), e = jax.jacrev(residual, argnums=(0, 1, 2), has_aux=True)(
            *arguments)
        return jnp.concatenate([j_iop, j_pose], axis=1), j_point, e

    pose_inputs = jax.tree.map(lambda x: x.at[image].get(mode="clip"),
                               pose.row_inputs(params.images))
    if mount:
        mount_inputs = pose.row_inputs(params.mounts)
        pose_inputs = (pose_inputs,
                       jax.tree.map(lambda x: x.at[mount[0]].get(mode="clip"), mount_inputs))
    jc, jp, e = jax.vmap(one)(
        params.cameras[group.model].at[camera].get(mode="clip"),
        pose_inputs,
        params.points.at[point].get(mode="clip"),
        measured,
        sigma,
        mask,
    )
    mask = mask.astype(dtype)[:, :, None]
    jc, jp, e = jc * mask, jp * mask, e * mask[:, :, 0]
    reduced_point = (point_row == structure.eliminated_points.shape[0])[:, None, None]
    padding = jnp.zeros((*jc.shape[:2], m - structure.point_width - n_iop - width), dtype)
    point_part = [jnp.where(reduced_point, jp, 0.0)] if structure.point_width else []
    jr = jnp.concatenate([jc, padding, *point_part], axis=-1)
    jr = jr * free_keys.at[key].get(mode="fill", fill_value=0.0)[:, None, :]
    je = jnp.where(reduced_point, 0.0, jp) * free_e[point_row][:, None, :]
    return jr, je, e


def _distance_jacobians(
    problem: BundleProblem, group: Distances, params: Parameters
) -> tuple[Array, Array]:
    """∂e/∂(point a, point b) (n, 1, 6) and e (n, 1) of every distance."""
    params = problem.with_free(params)

    def residual(pair, observed, sigma, mask):
        distance = jnp.sqrt(jnp.sum((pair[:3] - pair[3:]) ** 2))
        return jnp.where(mask, (observed - distance) / sigma, 0.0)

    def one(pair, observed, sigma, mask):
        j = jax.jacfwd(residual)(pair, observed, sigma, mask)
        return jnp.where(mask[:, None], j, 0.0), residual(pair, observed, sigma, mask)

    pairs = jnp.concatenate([params.points[group.a], params.points[group.b]], axis=1)
    return jax.vmap(one)(pairs, group.observed, group.stddev, group.mask())


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
    damped = _add_diagonal(normal.point_hessian, damping * normal.point_damping)
    inverse = jax.lax.cond(damping == 0, point_inverse, _small_inverse, damped)
    reduced, rhs = _schur_complement(structure, normal, inverse)
    reduced = reduced + normal.reduced_hessian + jnp.diag(damping * normal.reduced_damping)
    rhs = normal.reduced_gradient - rhs
    if held is not None:
        kept = 1.0 - held
        reduced = reduced * kept[:, None] * kept[None, :] + jnp.diag(held)
        rhs = rhs * kept
    x_r = cholesky_solve(reduced, rhs)
    x_r_padded = jnp.append(x_r, jnp.zeros((), dtype))
    n_e = normal.point_gradient.shape[0]
    coupled = jnp.sum(normal.coupling * _at_columns(structure, x_r_padded)[:, None, :], axis=2)
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
    reduced = _reduced_positions(problem, structure)
    points = np.asarray(positions.points)[np.asarray(structure.eliminated_points)]
    normal, _, _ = compiled_normal_equations(problem, structure, params)
    x_r, x_e = _schur_solve(problem, structure, normal, jnp.asarray(rhs[:, reduced]),
                            jnp.asarray(rhs[:, points]))
    out = np.zeros_like(rhs)
    out[:, reduced] = np.asarray(x_r)
    out[:, points] = np.asarray(x_e)
    return out


@eqx.filter_jit
def _schur_solve(problem, structure, normal, rhs_r, rhs_e):
    """`schur_solve` with the normal equations `normal` formed (by their own program)."""
    free_r, free_e = _free_masks(problem, structure, rhs_r.dtype)

    def one(r, e):  # vmapped over the right-hand sides; S is assembled once
        system = eqx.tree_at(lambda n: (n.reduced_gradient, n.point_gradient), normal,
                             (r * free_r[:-1], e * free_e[:-1]))
        return solve_bundle_damped(structure, system, 0.0)

    return jax.vmap(one)(rhs_r, rhs_e)


def _dense_from_blocks(
    n_r: int, rows: Int[Array, "n a"], columns: Int[Array, "n b"], blocks: Float[Array, "n a b"]
) -> Float[Array, "n_r1 n_r1"]:
    """Σ_k blocks[k] added at (rows[k], columns[k]) of a dense (n_r + 1, n_r + 1) matrix
    (row and column n_r: padding)."""
    flat = rows[:, :, None] * (n_r + 1) + columns[:, None, :]
    dense = jnp.zeros(((n_r + 1) ** 2,), blocks.dtype).at[flat].add(blocks)
    return dense.reshape(n_r + 1, n_r + 1)


def _schur_complement(
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
    left = _matmul(inverse, coupling_t)  # L_i (n_obs1, 3, k)
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
    product = _dense_from_blocks(
        n_r, jnp.concatenate([first, second]), jnp.concatenate([second, first]),
        jnp.concatenate([blocks, mirrored]),
    )
    gradient = jnp.concatenate([normal.point_gradient, jnp.zeros((1, 3), dtype)])
    gradient = gradient[structure.image_point]
    rhs = _add_at_columns(structure, _transposed_product(left, gradient))
    return -product[:n_r, :n_r], rhs[:n_r]
