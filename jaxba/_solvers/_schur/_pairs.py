"""Which observation pairs the Schur backend multiplies, laid out for vectorised work (NumPy).

The reduced camera matrix sums W_i V⁻¹ W_jᵀ over the pairs (i, j) of observations of one
point (Triggs et al., "Bundle adjustment - a modern synthesis", 2000, section 6.1);
`same_point_pairs` lists them and `block_rows` lays them out in rows of one block each
(`pair_block_sums`).
"""

import numpy as np


def same_point_pairs(point_index: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """All ordered pairs (i, j) of observations with point_index[i] == point_index[j].

    Returns two int64 arrays of length Σ_points count², i == j included.
    """
    order = np.argsort(point_index, kind="stable")
    counts = np.bincount(point_index, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per_obs = counts[point_index[order]]  # for each sorted observation: its point's count
    first_sorted = np.repeat(np.arange(order.size), per_obs)
    group_start = np.repeat(starts[point_index[order]], per_obs)
    offset = np.arange(first_sorted.size) - np.repeat(np.cumsum(per_obs) - per_obs, per_obs)
    return order[first_sorted], order[group_start + offset]


def block_rows(
    first: np.ndarray,
    second: np.ndarray,
    block: np.ndarray,
    n_blocks: int,
    *,
    fill: int,
    row_size: int,
    rows_per_chunk: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs laid out in rows of `row_size` pairs of one block each, rows in chunks.

    Returns first, second (n_chunks, rows_per_chunk, row_size), padded with `fill`, and
    the block of every row (n_chunks, rows_per_chunk), padded with `n_blocks`. Rows are
    in increasing block order.
    """
    order = np.argsort(block, kind="stable")
    first, second, block = first[order], second[order], block[order]
    counts = np.bincount(block, minlength=n_blocks)
    rows_per_block = -(-counts // row_size)
    row_start = np.cumsum(rows_per_block) - rows_per_block
    rank = np.arange(block.size) - (np.cumsum(counts) - counts)[block]
    slot = row_start[block] * row_size + rank
    n_rows = int(rows_per_block.sum())
    n_rows_padded = n_rows + (-n_rows % rows_per_chunk)
    out_first = np.full(n_rows_padded * row_size, fill, dtype=np.int64)
    out_second = np.full(n_rows_padded * row_size, fill, dtype=np.int64)
    out_first[slot], out_second[slot] = first, second
    row_block = np.full(n_rows_padded, n_blocks, dtype=np.int64)
    row_block[:n_rows] = np.repeat(np.arange(n_blocks), rows_per_block)
    shape = (-1, rows_per_chunk, row_size)
    return out_first.reshape(shape), out_second.reshape(shape), row_block.reshape(shape[:2])
