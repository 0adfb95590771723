"""Normal equations of a bundle from per-row Jacobian blocks.

Every residual row of a bundle depends on few unknowns: an image observation on its
camera's IOPs, its image's six EOPs and its object point; a control observation on one
point. Each row-local observation group differentiates its row function in reverse mode
(`AbstractObservationGroup.row_jacobians`: k = 1..3 outputs, so k backward passes
whatever the number of unknowns), which for a calibration of 5 images x 256 points is ~10x
cheaper than one forward tangent per unknown through all residuals.

The blocks are summed into JᵀJ and Jᵀe by key: rows whose unknowns are the same share a
key; the blocks of a key's rows are gathered into one (rows·k, n_live) matrix whose Gram
matrix is one batched matrix product (an image of a calibration: 256 rows), and the
per-key sums are scattered once into the dense n x n normal matrix (per-row outer
products summed by `segment_sum` were ~15x slower on the CPU). Only the "live" slots of
a group's rows enter (a slot is live where some row has a free unknown in it; fixed
target points or fixed IOPs drop out). Rows of groups that are not row-local (inner
constraints) are differentiated as a whole in reverse mode.

The plan is NumPy structure computed once per problem (`linearisation_plan`); its arrays
can be stacked over a batch of padded problems (`pad_plans`) and vmapped.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, Int

from .._programs import stored
from ._bundle import (
    BundleProblem,
    free_indices,
    observation_mask,
    params_from_free,
    tie_source,
)
from ._observations import ImagePoints, local_positions
from ._parameters import Parameters, flatten, positions_of
from ._unique_rows import unique_rows


class LinearisationPlan(eqx.Module):
    """How to assemble one problem's normal equations (arrays, so it batches).

    - `free_index`: (n_free,) free positions in `flatten` order (the solver's unknowns);
    - per observation group (None for a group that is not row-local):
      `key_rows` (n_keys, max_rows) the rows of every key (-1 pads: a zero row),
      `key_columns` (n_keys, n_live) the free column of each live slot of the key's rows
      (n_free, a dummy column, where the unknown is fixed), and `live` (static) the live
      slots of the group's rows.
    """

    free_index: Int[Array, " n_free"]
    key_rows: tuple[Int[Array, "n_keys max_rows"] | None, ...]
    key_columns: tuple[Int[Array, "n_keys n_live"] | None, ...]
    live: tuple[tuple[int, ...] | None, ...] = eqx.field(static=True)

    @property
    def n_free(self) -> int:
        return self.free_index.shape[-1]


def _local_positions(problem: BundleProblem) -> list[np.ndarray | None]:
    """Per group: the `flatten` positions of the unknowns each row depends on (n_rows,
    width), or None for a group that is not row-local. In NumPy (`local_positions`)."""
    positions = positions_of(problem.initial)
    return [local_positions(group, positions) for group in problem.groups]


def _free_columns(problem: BundleProblem, free_index: np.ndarray) -> np.ndarray:
    """(n_all,) the free column of every position in `flatten` order, a tied one's its
    source's (`tie_source`); len(free_index), a dummy column, for fixed unknowns (a
    repeated, padding position keeps its last column). Scatter-adds into these columns
    sum a row's tied slots: the Jacobian J·T of the independent unknowns."""
    column_of = np.full(flatten(problem.initial).size, free_index.size)
    column_of[free_index] = np.arange(free_index.size)
    return column_of[tie_source(problem)]


def live_slots(problem: BundleProblem, free_index: np.ndarray, local=None) -> list:
    """Per group: the slots (columns of `local_values`) that hold a free unknown in at least
    one row, or None for a group that is not row-local. `local`: `_local_positions`."""
    is_free = np.zeros(flatten(problem.initial).size, dtype=bool)
    is_free[free_index] = True
    is_free = is_free[tie_source(problem)]
    local = _local_positions(problem) if local is None else local
    return [None if depends is None
            else tuple(int(k) for k in np.flatnonzero(is_free[depends].any(0)))
            for depends in local]


def linearisation_plan(
    problem: BundleProblem, free_index: np.ndarray | None = None, live: list | None = None,
    local: list | None = None,
) -> LinearisationPlan:
    """The keys of `problem`'s rows (NumPy, before any tracing).

    `free_index` defaults to `free_indices(problem)`; a padded batch passes a longer one
    whose extra entries repeat an unreferenced position (their columns stay empty), and
    `live` (default `live_slots`) the union of the live slots of all its problems.
    `local`: `_local_positions(problem)` where the caller has it already.
    """
    free_index = free_indices(problem) if free_index is None else np.asarray(free_index)
    local = _local_positions(problem) if local is None else local
    live = live_slots(problem, free_index, local) if live is None else live
    column_of = _free_columns(problem, free_index)
    key_rows, key_columns = [], []
    for group, slots, depends in zip(problem.groups, live, local):
        if slots is None:
            key_rows.append(None)
            key_columns.append(None)
            continue
        observed = _planned_rows(np.asarray(group.mask()).any(axis=1),
                                 column_of[depends[:, list(slots)]])
        columns = column_of[depends[observed][:, list(slots)]]
        unique, key = unique_rows(columns)
        rows = _rows_by_key(key, unique.shape[0])
        key_rows.append(jax.device_put(np.where(rows >= 0, observed[rows], -1)))
        key_columns.append(jax.device_put(unique))
    return LinearisationPlan(jax.device_put(free_index), tuple(key_rows), tuple(key_columns),
                             tuple(live))


def _planned_rows(observed: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The rows of a group that the plan keeps: every observed one, and of the rows that
    observe nothing (a blunder switched off, batch padding) the first of each key no
    observed row has. They add nothing (σ = inf), but a blunder switched off keeps its key,
    so that the re-adjustments of data snooping have the shapes of the first adjustment
    (and its compiled programs); padded rows, copies of row 0, join row 0's key only where
    it is unobserved itself, once (hundreds of them made its key hundreds long)."""
    _, key = unique_rows(columns)
    unobserved = np.flatnonzero(~observed)
    _, first = np.unique(key[unobserved], return_index=True)
    first = unobserved[first]
    keep = observed.copy()
    keep[first[~np.isin(key[first], key[observed])]] = True
    return np.flatnonzero(keep)


def _rows_by_key(key: np.ndarray, n_keys: int) -> np.ndarray:
    """(n_keys, max_rows) the rows of every key, padded with -1."""
    counts = np.bincount(key, minlength=n_keys)
    out = np.full((n_keys, int(counts.max(initial=0))), -1)
    order = np.argsort(key, kind="stable")
    slot = np.arange(key.size) - np.repeat(np.cumsum(counts) - counts, counts)
    out[key[order], slot] = order
    return out


def pad_plans(plans: list[LinearisationPlan], keys: tuple | None = None) -> LinearisationPlan:
    """Stack plans of padded problems (same free-index length, rows and live slots) along
    a leading batch axis, padding every group's keys and key rows with empty ones: to the
    largest of these plans, or per group to `keys` (n_keys, max_rows) where given (None
    for a group that is not row-local), which must hold them."""

    def pad(array, shape, fill):
        out = np.full(shape, fill)
        out[: array.shape[0], : array.shape[1]] = np.asarray(array)
        return out

    padded = []
    for plan in plans:
        rows, columns = [], []
        for g, (key_rows, key_columns) in enumerate(zip(plan.key_rows, plan.key_columns)):
            if key_rows is None:
                rows.append(None)
                columns.append(None)
                continue
            n_keys = max(p.key_rows[g].shape[0] for p in plans)
            max_rows = max(p.key_rows[g].shape[1] for p in plans)
            if keys is not None:
                if keys[g][0] < n_keys or keys[g][1] < max_rows:
                    raise ValueError(f"pad_plans: group {g} has {n_keys} keys of up to"
                                     f" {max_rows} rows; more than {keys[g]}")
                n_keys, max_rows = keys[g]
            rows.append(pad(key_rows, (n_keys, max_rows), -1))
            columns.append(pad(key_columns, (n_keys, key_columns.shape[1]), plan.n_free))
        padded.append(LinearisationPlan(np.asarray(plan.free_index), tuple(rows),
                                        tuple(columns), plan.live))
    # Padded and stacked in NumPy, one transfer per leaf (jnp.stack compiled a program per
    # shape and number of plans).
    return jax.tree.map(lambda *leaves: jax.device_put(np.stack(leaves)), *padded)


def _robust(problem: BundleProblem, group, e: Array) -> tuple[Array, Array]:
    """ẽ and dẽ/de of the residual transform `problem.residuals` applies to the whitened
    residuals e of this group (identity unless a robust loss acts on image points)."""
    if problem.robust is None or not isinstance(group, ImagePoints):
        return e, jnp.ones_like(e)
    return jax.jvp(problem.robust, (e,), (jnp.ones_like(e),))


def _row_blocks(problem: BundleProblem, group, params: Parameters) -> tuple[Array, Array]:
    """A row-local group's residuals (n, k) as `problem.residuals` gives them (masked
    entries 0, robustified) and their Jacobian blocks (n, k, width) w.r.t. each row's
    unknowns (`local_values`), masked rows 0."""
    mask = group.mask()
    residuals, blocks = group.row_jacobians(params, problem.refraction)
    e, chain = _robust(problem, group, jnp.where(mask, residuals, 0.0))
    return e, jnp.where(mask[:, :, None], blocks * chain[:, :, None], 0.0)


def key_blocks(problem: BundleProblem, params: Parameters, plan: LinearisationPlan) -> tuple:
    """Per group, the residuals (n_keys, max_rows, k) and Jacobian blocks (n_keys, max_rows,
    k, n_live) of `_row_blocks` gathered by the plan's keys (row -1: zeros), or None for a
    group that is not row-local or has no live slot: one linearisation at `params`, which
    `normal_equations` sums and the batch's leverages read again."""
    keyed = []
    for group, rows, slots in zip(problem.groups, plan.key_rows, plan.live):
        if not slots:
            keyed.append(None)
            continue
        e, blocks = _row_blocks(problem, group, params)
        blocks = blocks[:, :, list(slots)]  # (n, k, n_live)
        keyed.append((jnp.concatenate([e, jnp.zeros_like(e[:1])])[rows],
                      jnp.concatenate([blocks, jnp.zeros_like(blocks[:1])])[rows]))
    return tuple(keyed)


def normal_equations(
    problem: BundleProblem, params: Parameters, plan: LinearisationPlan,
    keyed: tuple | None = None,
) -> tuple[Float[Array, "n_free n_free"], Float[Array, " n_free"]]:
    """N = JᵀJ and g = Jᵀẽ of the residuals `problem.residuals` at `params`, J the
    derivative w.r.t. the free unknowns `plan.free_index` (their own units). `keyed`:
    `key_blocks` at `params`, where already made."""
    n = plan.n_free
    dtype = ravel_pytree(params)[0].dtype
    normal = jnp.zeros((n + 1, n + 1), dtype)
    gradient = jnp.zeros(n + 1, dtype)
    keyed = key_blocks(problem, params, plan) if keyed is None else keyed
    for group, columns, key in zip(problem.groups, plan.key_columns, keyed):
        if key is None:
            continue
        e, blocks = key
        # Every key's rows as one (max_rows·k, n_live) matrix: one batched product.
        blocks = blocks.reshape(blocks.shape[0], -1, blocks.shape[-1])
        e = e.reshape(e.shape[0], -1)
        normal = _add_key_products(normal, columns, blocks)
        gradient = gradient.at[columns].add(jnp.einsum("kmi,km->ki", blocks, e))
    normal, gradient = normal[:n, :n], gradient[:n]
    whole_groups = [g for g, slots in zip(problem.groups, plan.live) if slots is None]
    if whole_groups:
        rows, e = _whole_group_jacobian(problem, params, plan.free_index, whole_groups)
        normal = normal + rows.T @ rows
        gradient = gradient + rows.T @ e
    return normal, gradient


def _add_key_products(normal: Float[Array, "n n"], columns: Int[Array, "keys s"],
                      blocks: Float[Array, "keys m s"]) -> Float[Array, "n n"]:
    """`normal` plus every key's BᵀB (its rows' blocks B, m x s) added at the key's columns.

    A key of many rows (m > s: an image's points on a fixed target) forms BᵀB by one
    batched product and adds its s² entries. A key of few rows (a row per measured point,
    m = 2) is dominated by the adding (XLA's scatter): each pair of slots i <= j is formed
    and added once, to the upper triangle, which is then mirrored; the pairs i = j, in both
    halves, are taken off once. 10 projects of 278 unknowns and 17 slots a row: 19 against
    40 ms per N."""
    _, m, s = blocks.shape
    if m > s:
        outer = jnp.einsum("kmi,kmj->kij", blocks, blocks)
        return normal.at[columns[:, :, None], columns[:, None, :]].add(outer)
    size = normal.shape[0]
    i, j = np.triu_indices(s)  # (0, 0), (0, 1), ... (s-1, s-1): i[i == j] is 0 .. s-1
    pairs = jnp.einsum("kmp,kmp->kp", blocks[:, :, i], blocks[:, :, j])
    upper = jnp.zeros(size * size, normal.dtype).at[
        (columns[:, i] * size + columns[:, j]).ravel()].add(pairs.ravel()).reshape(size, size)
    squares = jnp.zeros(size, normal.dtype).at[columns.ravel()].add(
        pairs[:, np.flatnonzero(i == j)].ravel())
    return normal + upper + upper.T - jnp.diag(squares)


def _group_columns(problem: BundleProblem, index: np.ndarray) -> tuple:
    """Per group, the free column (n_free: none) of every row's unknowns (`local_values`),
    or None for a group that is not row-local."""
    column_of = _free_columns(problem, index)
    return tuple(None if depends is None else jax.device_put(column_of[depends])
                 for depends in _local_positions(problem))


def column_norms(problem: BundleProblem, params: Parameters) -> Float[Array, " n_free"]:
    """‖column‖ of the whitened Jacobian dẽ/dx_free at `params` (`free_indices` order),
    summed from the per-row blocks: no dense Jacobian or normal matrix at any size."""
    index = free_indices(problem)
    return _column_norms(problem, params, jax.device_put(index),
                         _group_columns(problem, index))


@eqx.filter_jit
def _column_norms(problem, params, index, columns):
    n = index.shape[0]
    squares = jnp.zeros(n + 1, ravel_pytree(params)[0].dtype)
    for group, group_columns in zip(problem.groups, columns):
        if group_columns is None:
            jacobian, _ = _whole_group_jacobian(problem, params, index, [group])
            squares = squares.at[:n].add(jnp.sum(jacobian**2, axis=0))
        else:
            blocks = _row_blocks(problem, group, params)[1]
            merged = blocks
            if problem.ties:  # a row's slots of one unknown: Σ_i∈c b_i·Σ_j∈c b_j = (Σ b)²
                same = group_columns[:, :, None] == group_columns[:, None, :]
                merged = jnp.einsum("nkj,nij->nki", blocks, same.astype(blocks.dtype))
            squares = squares.at[group_columns].add(jnp.sum(blocks * merged, axis=1))
    return jnp.sqrt(squares[:n])


def dense_jacobian(
    problem: BundleProblem, params: Parameters
) -> tuple[Float[np.ndarray, "n_obs n_free"], Float[np.ndarray, " n_obs"]]:
    """Whitened Jacobian dẽ/dx_free and residuals ẽ (`problem.residuals`), real observations
    only, in the order of the raveled residuals; columns in `free_indices` order (NumPy).

    Dense: for problems of up to a few thousand unknowns (statistics, datum check). Built
    from the per-row reverse-mode blocks the solver uses (`row_jacobians`), scattered into
    their free columns; groups that are not row-local are differentiated whole.
    """
    index = free_indices(problem)
    # All rows compiled, the real ones selected after: an observation switched off (data
    # snooping) keeps the compiled program's shapes.
    jacobian, residuals = _dense_jacobian(problem, params, jax.device_put(index),
                                          _group_columns(problem, index))
    rows = np.flatnonzero(observation_mask(problem))
    return np.asarray(jacobian)[rows], np.asarray(residuals)[rows]


@stored("dense_jacobian")
@eqx.filter_jit
def _dense_jacobian(problem, params, index, columns):
    n = index.shape[0]
    jacobians, residuals = [], []
    for group, group_columns in zip(problem.groups, columns):
        if group_columns is None:
            jacobian, e = _whole_group_jacobian(problem, params, index, [group])
        else:
            e, blocks = _row_blocks(problem, group, params)
            n_rows, k, _ = blocks.shape
            jacobian = jnp.zeros((n_rows, k, n + 1), blocks.dtype).at[
                jnp.arange(n_rows)[:, None, None], jnp.arange(k)[None, :, None],
                group_columns[:, None, :]].add(blocks)
            jacobian = jacobian.reshape(n_rows * k, n + 1)[:, :n]
        jacobians.append(jacobian)
        residuals.append(jnp.ravel(e))
    return jnp.concatenate(jacobians), jnp.concatenate(residuals)


def _whole_group_jacobian(problem, params, index, groups) -> tuple[Array, Array]:
    """Jacobian (n_entries, n_free) and residuals of groups that are not row-local."""
    at = eqx.tree_at(lambda p: p.initial, problem, params)

    def residual_vector(x_free):
        values = params_from_free(at, x_free, index)
        return jnp.concatenate(
            [jnp.ravel(jnp.where(g.mask(), g.residuals(values, problem.refraction), 0.0))
             for g in groups])

    x_free = ravel_pytree(params)[0][index]
    return jax.jacrev(residual_vector)(x_free), residual_vector(x_free)
