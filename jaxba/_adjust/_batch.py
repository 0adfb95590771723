"""Many bundles in one call: problems padded to a common shape (`_padding.py`), solved
vmapped, then the statistics of each, also vmapped.

Padding (`_padding.py`) changes no result.

The solver is `solve` on the Dense backend (Levenberg-Marquardt on the Jacobi-scaled
unknowns, Cholesky of the normal equations), traced into the batch's one program without
progress reports: under `jax.vmap` a `jax.debug.callback` is unrolled once per batch
element, which would make compile time grow with the batch size.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._gc import paused_gc
from .._problem._bundle import (
    BundleProblem,
    free_mask,
    observed_minus_computed,
)
from .._problem._linearisation import (
    LinearisationPlan,
    _whole_group_jacobian,
    key_blocks,
    normal_equations,
)
from .._problem._parameters import Parameters, parameter_labels
from .._programs import call_stored
from .._solvers._compiled import solver_jit
from .._solvers._dense import Dense, cofactors, equilibrated, scale_from_normal
from .._solvers._progress import Iteration
from .._solvers._solution import Solution, stop_reason
from .._solvers._solve import solve
from .._statistics._adjustment import Adjustment
from .._statistics._covariance import precision_from_covariance
from .._statistics._datum import DatumError, check_datum, check_structure
from .._statistics._reliability import group_reliability
from ._padding import (
    BatchShape,
    PaddedBatch,
    _take,
    _unpad_parameters,
    batch_shape,
    pad_problems,
)


@eqx.filter_jit
def solve_batch(
    problem: BundleProblem,
    plan: LinearisationPlan,
    *,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    chunk_size: int | None = None,
) -> Solution:
    """`solve` vmapped over a leading batch axis of `problem` and `plan` (`pad_plans`, or
    one plan broadcast with `broadcast_plan` for problems of one structure): one
    compilation per padded shape. Returns a Solution with a leading batch axis.

    `chunk_size`: solve `chunk_size` problems at a time (vmapped), the chunks one after the
    other (`jax.lax.map`), in one compiled call. A vmapped solve runs every problem until
    the slowest of its chunk has converged, and its per-row arrays outgrow the CPU caches:
    for Zhang-size calibrations (1280 rows) chunks of 10 ran ~1.3x faster than one chunk
    of 250 (benchmarks/README.md). None: all at once.
    """
    return _solve_batch(problem, plan, max_steps, rtol, atol, chunk_size)


@eqx.filter_jit
def _solve_batch(problem, plan, max_steps, rtol, atol, chunk_size) -> Solution:
    arrays, static = eqx.partition((problem, plan), eqx.is_array)

    def one(arrays):
        problem, plan = eqx.combine(arrays, static)
        return solve(problem, Dense(plan), max_steps=max_steps, rtol=rtol, atol=atol)

    if chunk_size is None:
        return jax.vmap(one)(arrays)
    return jax.lax.map(one, arrays, batch_size=chunk_size)


class BatchStatistics(eqx.Module):
    """Per problem (leading batch axis): cost ½eᵀe at the start and the solution, the
    cofactor matrix (JᵀJ)⁻¹ of the (padded) free unknowns, the leverages diag(J(JᵀJ)⁻¹Jᵀ)
    of every residual entry, the whitened residuals e and `suspect`, the datum screen at
    the approximations (`_datum_suspect`)."""

    initial_cost: Float[Array, " n_batch"]
    cofactor: Float[Array, "n_batch n_free n_free"]
    leverage: Float[Array, "n_batch n_residuals"]
    whitened: Float[Array, "n_batch n_residuals"]
    suspect: Bool[Array, " n_batch"]


def _datum_suspect(normal: Float[Array, "n n"], n_free, rtol: float):
    """False where the datum is surely defined at the approximations, from N = JᵀJ there
    (`n_free` of its leading unknowns real): N finite, every real column observed, and the
    equilibrated N (unit diagonal, padding I: its largest eigenvalue at most its trace n)
    minus (4·rtol² + 1e-12)·n·I positive definite (its Cholesky factor finite), so that its
    eigenvalues λ = s² (s the singular values of the equilibrated J) have λ_min/λ_max above
    4·rtol² + 1e-12: a defect, s_min/s_max < rtol, lies below it even with N's rounding
    (~1e-16 λ_max). True: `check_datum` decides (the exact test, from J itself, and the
    message). Vmapped over 10 projects of 278 unknowns the factorisation takes 5-7 ms, the
    eigenvalues it replaces took 71-75 ms."""
    n = normal.shape[0]
    real = jnp.arange(n) < n_free
    finite = jnp.all(jnp.isfinite(normal))
    observed = jnp.all(jnp.where(real, jnp.diag(normal) > 0, True))
    scaled = equilibrated(jnp.where(finite, normal, 1.0), real)[0]
    shifted = jnp.where(finite, scaled, jnp.eye(n)) - (4 * rtol**2 + 1e-12) * n * jnp.eye(n)
    regular = jnp.all(jnp.isfinite(jnp.linalg.cholesky(shifted)))
    return ~(finite & observed & regular)


def _initial_normal(problem: BundleProblem, plan: LinearisationPlan):
    """N = JᵀJ at the approximations: the datum screen's and the solve's column scale's."""
    return normal_equations(problem, problem.initial, plan)[0]


def _leverages(problem: BundleProblem, params: Parameters, plan: LinearisationPlan, cofactor,
               keyed: tuple):
    """diag(J Q Jᵀ) of every residual entry (flat, in `problem.whitened`'s order), Q the
    cofactor matrix (n_free, n_free): per key of the plan from its rows' Jacobian blocks
    (`keyed`: `key_blocks` at `params`) and Q's block of the key's columns (no dense
    Jacobian); whole groups from their Jacobian."""
    n = plan.n_free
    padded = jnp.zeros((n + 1, n + 1), cofactor.dtype).at[:n, :n].set(cofactor)
    parts = []
    for group, rows, columns, slots, key in zip(
        problem.groups, plan.key_rows, plan.key_columns, plan.live, keyed
    ):
        n_rows, k = jnp.shape(group.stddev)
        if slots is None:
            jacobian, _ = _whole_group_jacobian(problem, params, plan.free_index, [group])
            parts.append(jnp.einsum("ei,ij,ej->e", jacobian, cofactor, jacobian))
            continue
        if not slots:
            parts.append(jnp.zeros(n_rows * k, cofactor.dtype))
            continue
        blocks = key[1]
        block_q = padded[columns[:, :, None], columns[:, None, :]]
        leverage = jnp.einsum("kmci,kij,kmcj->kmc", blocks, block_q, blocks)
        target = jnp.where(rows >= 0, rows, n_rows)  # key padding: a dropped extra row
        parts.append(jnp.zeros((n_rows + 1, k), cofactor.dtype).at[target].set(leverage)
                     [:n_rows].ravel())
    return jnp.concatenate(parts)


def _statistics_one(problem: BundleProblem, plan: LinearisationPlan, params: Parameters,
                    n_free, suspect) -> BatchStatistics:
    """The statistics of one problem at its solution `params`, from one linearisation there
    (`key_blocks`: N and the leverages); `suspect` as given (`_datum_suspect`)."""
    real = jnp.arange(plan.n_free) < n_free
    keyed = key_blocks(problem, params, plan)
    cofactor = cofactors(normal_equations(problem, params, plan, keyed)[0], real)
    whitened = jnp.concatenate([jnp.ravel(e) for e in problem.whitened(params)])
    initial = 0.5 * sum(jnp.sum(e**2) for e in problem.whitened(problem.initial))
    return BatchStatistics(initial, cofactor, _leverages(problem, params, plan, cofactor, keyed),
                           whitened, suspect)


def _each(function, problem, plan, n_free, chunk_size):
    """`function(problem, plan, n_free)` of every problem of a padded batch: vmapped, or
    `chunk_size` at a time (vmapped) one chunk after the other (`jax.lax.map`)."""
    arrays, static = eqx.partition((problem, plan), eqx.is_array)

    def one(args):
        arrays, n = args
        return function(*eqx.combine(arrays, static), n)

    if chunk_size is None:
        return jax.vmap(one)((arrays, n_free))
    return jax.lax.map(one, (arrays, n_free), batch_size=chunk_size)


@solver_jit
def _adjust_program(problem, plan, n_free, max_steps, rtol, atol, datum_rtol, chunk_size):
    """Datum screen, solve and statistics of every problem of a padded batch: one compiled
    program, two linearisations besides the solve's steps (the approximations' N serves
    the screen and the solve's column scale; the solution's, the statistics). Compiled with
    the solvers' XLA options (`solver_jit`: no YNNPACK reductions; Zhang-size chunks of 10
    ran 1.4x faster)."""

    def one(problem, plan, n):
        normal = _initial_normal(problem, plan)
        backend = Dense(plan, scale=scale_from_normal(normal))
        solution = solve(problem, backend, max_steps=max_steps, rtol=rtol, atol=atol)
        return solution, _statistics_one(problem, plan, solution.parameters, n,
                                         _datum_suspect(normal, n, datum_rtol))

    return _each(one, problem, plan, n_free, chunk_size)


@eqx.filter_jit
def _screen_program(problem, plan, n_free, datum_rtol):
    return _each(lambda problem, plan, n: _datum_suspect(_initial_normal(problem, plan), n,
                                                         datum_rtol),
                 problem, plan, n_free, None)


def _datum_error(problem, suspect: bool, labels, rtol: float, n_observations: int,
                 n_unknowns: int) -> DatumError | None:
    """`check_datum`'s error of one problem, or None: the exact check where the batched
    screen found it `suspect`; otherwise only the checks that need no Jacobian
    (`check_structure`: redundancy from the padding's counts, separable camera parameters),
    the screen having found every column finite and observed."""
    try:
        if suspect:
            check_datum(problem, labels=labels, rtol=rtol)
        else:
            check_structure(problem, labels or parameter_labels(problem.initial),
                            n_observations, n_unknowns)
    except DatumError as error:
        return error
    return None


def check_datum_batch(
    problems, *, labels: list | None = None, rtol: float = 1e-9, shape: BatchShape | None = None
) -> list[DatumError | None]:
    """`check_datum` of every problem, screened in one vmapped program (one compilation):
    per problem None, or the `DatumError` that `check_datum` would raise. `shape`: as
    `pad_problems`'."""
    batch = pad_problems(problems, shape)
    suspect = np.asarray(_screen_program(batch.problem, batch.plan, jax.device_put(batch.n_free),
                                         rtol))
    labels = labels if labels is not None else [None] * batch.n_batch
    return [_datum_error(problem, bool(flag), names, rtol, int(n_obs), int(n))
            for problem, flag, names, n_obs, n in zip(batch.problems, suspect, labels,
                                                      batch.n_observations, batch.n_free)]


def adjust_batch(
    problems,
    *,
    sigma0: float | list[float] = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    alpha: float | list[float] | None = None,
    familywise: bool | list[bool] = False,
    shape: BatchShape | None = None,
) -> list[Adjustment]:
    """Adjust bundles of one kind in one padded, jitted, vmapped program: the solve and
    the statistics of each.

    Each returned `Adjustment` equals `adjust(problem)` of that problem alone (to rounding):
    parameters, σ̂0² = σ0² eᵀe / r, Cxx = σ̂0² (σ0² JᵀJ)⁻¹, residuals. Its `iterations`
    hold only the start and the solution, numbered as the solve counted its accepted steps
    (no per-step report inside a batch). With `alpha`
    (one per problem or one for all) `reliability` is filled in as `reliability(result,
    alpha=..., familywise=...)` would. No datum check: call `check_datum` first, or
    `adjust_padded(..., check=True)` (the CLI's `run_batch` does). `shape`: the padded
    shape (`pad_problems`).
    """
    return adjust_padded(pad_problems(problems, shape), sigma0=sigma0, max_steps=max_steps,
                         rtol=rtol, atol=atol, alpha=alpha, familywise=familywise)


def adjust_padded(
    batch: PaddedBatch,
    *,
    sigma0: float | list[float] = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    alpha: float | list[float] | None = None,
    familywise: bool | list[bool] = False,
    check: bool = False,
    labels: list | None = None,
    datum_rtol: float = 1e-9,
    chunk_size: int | None = None,
) -> list[Adjustment | DatumError]:
    """`adjust_batch` of a padded batch (`pad_problems`). With `check`, the datum of every
    problem is checked in the same program (`check_datum_batch`'s screen; `labels`: one
    list per problem, or None): a problem whose datum is not defined gets its `DatumError`
    in place of an Adjustment. `chunk_size`: as `solve_batch`'s."""
    n = batch.n_batch
    sigma0s = [sigma0] * n if np.ndim(sigma0) == 0 else list(sigma0)
    alphas = [alpha] * n if alpha is None or np.ndim(alpha) == 0 else list(alpha)
    familywises = [familywise] * n if np.ndim(familywise) == 0 else list(familywise)
    labels = labels if labels is not None else [None] * n
    # Called through a stored export where one exists: a later process skips the trace.
    solution, stats = jax.device_get(call_stored(
        "batch_adjust", _adjust_program,
        (batch.problem, batch.plan, jax.device_put(batch.n_free)),
        (max_steps, rtol, atol, datum_rtol, chunk_size)))
    with paused_gc():  # many small objects, none in a cycle
        return _results(batch, solution, stats, sigma0s, alphas, familywises, check, labels,
                        datum_rtol, max_steps)


def _results(batch, solution, stats, sigma0s, alphas, familywises, check, labels, datum_rtol,
             max_steps):
    """`adjust_padded`'s Adjustments (or DatumErrors) from the program's outputs (NumPy)."""
    stddev = [group.stddev for group in batch.host.groups]
    whitened = _group_rows(batch.host, stats.whitened)
    residuals = observed_minus_computed(batch.host, whitened)
    redundancy = None
    if any(a is not None for a in alphas):  # r_i = 1 - leverage, NaN where masked
        redundancy = [np.where(np.isfinite(sigma), 1.0 - leverage, np.nan) for sigma, leverage
                      in zip(stddev, _group_rows(batch.host, stats.leverage))]
    results = []
    for k, problem in enumerate(batch.problems):
        n_observations, n_free = int(batch.n_observations[k]), int(batch.n_free[k])
        if check:
            error = _datum_error(problem, bool(stats.suspect[k]), labels[k], datum_rtol,
                                 n_observations, n_free)
            if error is not None:
                results.append(error)
                continue
        rows = [slice(np.shape(group.stddev)[0]) for group in problem.groups]
        results.append(_adjustment(
            problem, solution, batch.host.free, k, float(stats.initial_cost[k]), stats.cofactor[k],
            [s[k, n] for s, n in zip(stddev, rows)], [e[k, n] for e, n in zip(whitened, rows)],
            [v[k, n] for v, n in zip(residuals, rows)],
            None if alphas[k] is None else [r[k, n] for r, n in zip(redundancy, rows)],
            n_observations, n_free, sigma0s[k], alphas[k], familywises[k], max_steps,
        ))
    return results


def _group_rows(host: BundleProblem, flat: np.ndarray) -> list[np.ndarray]:
    """A padded batch's flat per-residual values (n_batch, n_residuals), `problem.whitened`'s
    order, as per group (n_batch, rows, k) views shaped like the stacked `host`'s σ."""
    parts, start = [], 0
    for group in host.groups:
        shape = np.shape(group.stddev)
        size = int(np.prod(shape[1:]))
        parts.append(flat[:, start:start + size].reshape(shape))
        start += size
    return parts


def _adjustment(problem, solution, free, k, initial_cost, cofactor, stddev, whitened, residuals,
                redundancy, n_observations, n_free, sigma0, alpha, familywise, max_steps
                ) -> Adjustment:
    """The `Adjustment` of problem `k` of a padded batch: from the batch's `solution` and
    `free` (the stacked problem's, NumPy), its ½eᵀe at the start, its cofactors (padded),
    and per group its rows of the stacked σ, the batch's whitened residuals e, residuals v
    and (with `alpha`) redundancy numbers r (NaN where masked); `max_steps` the solve's
    (its message where it was reached)."""
    params = _unpad_parameters(solution.parameters, problem.initial, k)
    redundancy_total = n_observations - n_free
    final_cost = 0.5 * float(sum(np.sum(e**2) for e in whitened))
    sigma0_squared = sigma0**2 * 2 * final_cost / redundancy_total
    covariance = (sigma0_squared / sigma0**2) * cofactor[:n_free, :n_free]
    # Its free positions from the batch's NumPy mask, not its own (device) arrays.
    index = np.flatnonzero(free_mask(_unpad_parameters(free, problem.initial, k)))
    prec = precision_from_covariance(problem, params, covariance, sigma0_squared,
                                     redundancy_total, n_observations, index)
    # The start and the solution, numbered as the solve counted its accepted steps.
    iterations = [
        Iteration(0, initial_cost, sigma0**2 * 2 * initial_cost / max(redundancy_total, 1))]
    last = int(solution.accepted_steps[k]) - 1  # step 0, the start, is accepted
    if last > 0:
        iterations.append(Iteration(last, final_cost, sigma0_squared))
    reliability = None
    if alpha is not None:
        reliability = group_reliability(tuple(stddev), tuple(redundancy), tuple(whitened),
                                        n_observations, alpha=alpha, familywise=familywise)
    converged = bool(solution.converged[k])
    return Adjustment(
        problem=problem,
        parameters=params,
        precision=prec,
        residuals=tuple(residuals),
        iterations=iterations,
        converged=converged,
        message="converged" if converged else stop_reason(_take(solution.result, k), max_steps),
        steps=int(solution.steps[k]),
        sigma0_prior=float(sigma0),
        reliability=reliability,
    )


__all__ = [
    "BatchShape", "PaddedBatch", "adjust_batch", "adjust_padded", "batch_shape",
    "check_datum_batch", "pad_problems", "solve_batch",
]
