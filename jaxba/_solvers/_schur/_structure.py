"""The Schur split of a photogrammetric bundle (`BundleProblem`): which unknowns stay on the
reduced ("camera") side and which object points are eliminated, as index arrays.

- reduced side, r: all IOPs of all camera models (shared by the images that use them), all
  EOPs, the rig cameras' relative poses (`Parameters.mounts`, where there are rigs) and the
  object points that a row of some other group than image points couples with further
  unknowns (`AbstractObservationGroup.row_blocks`: a distance couples two points, so they
  cannot be eliminated one by one), in that order;
- point side, e: every other object point, 3 unknowns each.

Image observation i touches one IOP row, one EOP row (and in a rig one mount row) and one
point: its reduced columns (the model's free IOPs + 6 EOPs (+ 6 of the mount), plus 3 for
a reduced-side point) and its eliminated point. Observations with equal reduced columns
share a key; the pairs of observations of one eliminated point, grouped by key pair, are
what the reduced camera matrix sums (`_assembly`).
"""

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Int

from ..._problem._bundle import BundleProblem, tie_source
from ..._problem._parameters import flatten, unflatten
from ..._problem._unique_rows import unique_rows
from ._pairs import block_rows, same_point_pairs

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
    Observation rows: the image observations of all image-point groups (`kind()`
    "image_points"), group after group,
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
      (`_cofactors.observation_cofactors`);
    - `reduced_points`, `eliminated_points`: row numbers in `points`; `point_column`:
      (n_points,) first reduced column of a reduced point, -1 otherwise;
    - `eliminated_index`: (n_points,) row in the eliminated block, n_eliminated otherwise;
    - `camera_column`: the reduced column of every camera parameter (`flatten` order): its
      own, or its tie's source's (`BundleProblem.ties`; a tied one's own column stays
      empty, as a fixed unknown's);
    - `iop_columns`: per model (in `models` order), the IOPs free or tied in some camera of
      it: the only IOP columns an observation carries (fixed ones would be zero);
      `camera_offsets`, `camera_widths`: per model, its cameras' first reduced column and
      its number of IOPs; `image_offset`, `mount_offset`: the first EOP and mount column.
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
    camera_widths: tuple[int, ...] = eqx.field(static=True)
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
    how the cofactors are formed (`_cofactors.observation_cofactors`), None: by the
    work each takes (`PAIRWISE_ADVANTAGE`). The split depends on `problem.free`
    (`iop_columns`): rebuild it when the free mask changes. Raises `ValueError` for an
    observation group that is not row-local (no `row_blocks`: inner constraints), and for
    a board warp (`Parameters.warp`: no columns for it here; the dense backend adjusts it).
    """
    initial = problem.initial
    if initial.warp is not None:
        raise ValueError("the Schur backend does not adjust a board warp (kx, ky): take the"
                         " dense backend, a calibration's size")
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
        blocks = group.row_blocks()
        if not blocks:
            raise ValueError(
                f"the Schur backend cannot split observation group {group.name!r}: its rows are"
                " not row-local (a free network's inner constraints: `minimal_constraints`)")
        if group.kind() != "image_points" and len(blocks) > 1:
            coupled += [np.asarray(index) for block, index in blocks if block == "points"]
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
    images = [g for g in problem.groups if g.kind() == "image_points"]
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
    key_columns, key = unique_rows(columns)
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
        camera_widths=tuple(int(initial.cameras[model].shape[1]) for model in models),
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

