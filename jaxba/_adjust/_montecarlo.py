"""Empirical precision on the batch API: Monte Carlo and bootstrap replicates of one bundle,
solved in vmapped chunks (`_batch.solve_batch`: one compilation, no padding needed).

- `monte_carlo`: fresh Gaussian noise N(0, σ²) on every image coordinate (σ of each
  observation from its group's `stddev`), added to the computed image coordinates at the
  given solution (`at`, default: the adjusted solution of `problem`), so the replicates
  scatter about a consistent truth. Other groups (control, distances, priors) are kept.
- `bootstrap`: residual bootstrap (Efron & Tibshirani, ch. 9): measured* = computed(x̂) +
  σ ⊙ e*, with e* drawn with replacement from the whitened image residuals of the
  adjustment, rescaled by sqrt(n / r) so that they have the variance of the errors (not of
  the residuals). Resampling whole observations instead would change the structure (which
  image sees which point) and with it the padded shape; the residual bootstrap keeps the
  geometry and still uses the empirical (not the Gaussian) error distribution.

Both return the stacked solutions and the empirical covariance of the free unknowns, to
compare with the formal `Precision.covariance`.

The replicates are drawn here and solved in vmapped chunks of `chunk_size` (default
`CHUNK`), all of one length (the last filled up with copies of its last replicate, dropped
after): one compiled program. The chunks run one after the other in this process, or, with a
`scheduler` (as `jaxba batch --scheduler`: "local[:N]", an address or a `distributed.Client`),
as tasks on the workers of a Dask cluster; the results are the same.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from .._dask import executor
from .._problem._bundle import BundleProblem
from .._problem._linearisation import linearisation_plan
from .._problem._parameters import Parameters, flatten, unflatten
from .._solvers._solution import Solution
from ._adjust import adjust
from ._batch import solve_batch
from ._padding import broadcast_plan


@dataclasses.dataclass(frozen=True)
class Replicates:
    """Replicated adjustments of one bundle.

    - `solutions`: a Solution with a leading axis of `n` replicates;
    - `free`: (n, n_free) the free unknowns of every replicate (`free_indices` order);
    - `mean`, `covariance`: their empirical mean (n_free,) and covariance (n_free, n_free);
    - `std`: Parameters of empirical standard deviations (0 for fixed unknowns).
    """

    solutions: Solution
    free: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    std: Parameters


def _image_groups(problem: BundleProblem) -> list[int]:
    return [k for k, g in enumerate(problem.groups) if g.kind() == "image_points"]


def _computed(problem: BundleProblem, params: Parameters, k: int) -> Array:
    """Computed image coordinates of group k at params: measured - σ e."""
    group = problem.groups[k]
    e = group.residuals(params, problem.refraction)
    sigma = jnp.where(group.mask(), group.stddev, 0.0)
    return group.measured - sigma * jnp.where(group.mask(), e, 0.0)


@eqx.filter_jit
def _simulated(problem: BundleProblem, at: Parameters, key: PRNGKeyArray, n: int) -> list[Array]:
    """Per image group, `n` replicates (n, rows, 2) of its coordinates computed at `at` plus
    noise N(0, σ²); one compiled program (op by op: ~30 small ones)."""
    measured = []
    for k, key_k in zip(_image_groups(problem), jax.random.split(key, len(problem.groups))):
        group = problem.groups[k]
        computed = _computed(problem, at, k)
        sigma = jnp.where(group.mask(), group.stddev, 0.0)
        noise = jax.random.normal(key_k, (n, *computed.shape)) * sigma
        measured.append(computed + noise)
    return measured


@eqx.filter_jit
def _image_residuals(problem: BundleProblem, params: Parameters) -> tuple[list, list]:
    """The whitened residuals (rows, 2) of every image group at `params`, and their masks."""
    groups = [problem.groups[k] for k in _image_groups(problem)]
    return ([g.residuals(params, problem.refraction) for g in groups],
            [g.mask() for g in groups])


@eqx.filter_jit
def _resampled(problem: BundleProblem, params: Parameters, pool, key: PRNGKeyArray,
               n: int) -> list[Array]:
    """Per image group, `n` replicates of its coordinates computed at `params` plus σ times
    draws from `pool` (with replacement); one compiled program."""
    ks = _image_groups(problem)
    measured = []
    for k, key_k in zip(ks, jax.random.split(key, len(ks))):
        group = problem.groups[k]
        computed = _computed(problem, params, k)
        draws = jax.random.choice(key_k, jnp.asarray(pool), (n, *computed.shape))
        sigma = jnp.where(group.mask(), group.stddev, 0.0)
        measured.append(computed + sigma * draws)
    return measured


def _replicate(problem: BundleProblem, measured: list[Array]) -> BundleProblem:
    ks = _image_groups(problem)
    return eqx.tree_at(lambda p: [p.groups[k].measured for k in ks], problem, measured)


CHUNK = 10  # replicates per vmapped solve (one Dask task), by default


def _solve_chunk(task) -> Solution:
    """The replicates of `task` = (problem, measured per image group, solver options)."""
    problem, measured, options = task
    return _solve_stacked(problem, linearisation_plan(problem), measured, **options)


@eqx.filter_jit
def _solve_stacked(problem, plan, measured, *, max_steps, rtol, atol) -> Solution:
    """`solve_batch` of the replicates of `problem` with image coordinates `measured` (per
    image group, a leading replicate axis), stacked in the same program: op by op, the
    stacking compiled a small program per leaf."""
    n = measured[0].shape[0]
    stacked = jax.vmap(lambda m: _replicate(problem, m))(measured)
    return solve_batch(stacked, broadcast_plan(plan, n), max_steps=max_steps, rtol=rtol,
                       atol=atol)


@eqx.filter_jit
def _concatenate(parts: list[Solution], n: int) -> Solution:
    """The first `n` replicates of the chunks' solutions `parts`, in order."""
    return jax.tree.map(lambda *leaves: jnp.concatenate(leaves)[:n], *parts)


def _solve_all(problem, measured, options, scheduler, chunk_size) -> Solution:
    """All replicates, in chunks of `chunk_size`, here (no scheduler) or on Dask."""
    if chunk_size is not None and chunk_size < 1:
        raise ValueError(f"chunk_size {chunk_size}: must be at least 1")
    n = measured[0].shape[0]
    size = min(chunk_size or CHUNK, n)
    rows = [np.minimum(np.arange(start, start + size), n - 1) for start in range(0, n, size)]
    parts = {}
    with executor(scheduler) as run:
        tasks = [(problem, [m[r] for m in measured], options) for r in rows]
        for k, solution in run.map(_solve_chunk, tasks):
            if isinstance(solution, BaseException):
                raise solution
            parts[k] = solution
    return _concatenate([parts[k] for k in range(len(rows))], n)


def _solve_replicates(problem, measured, *, max_steps, rtol, atol, scheduler=None,
                      chunk_size=None) -> Replicates:
    n = measured[0].shape[0]
    options = dict(max_steps=max_steps, rtol=rtol, atol=atol)
    solutions = _solve_all(problem, measured, options, scheduler, chunk_size)
    index = np.asarray(linearisation_plan(problem).free_index)
    parameters = jax.device_get(solutions.parameters)
    flat = np.stack([flatten(jax.tree.map(lambda leaf: leaf[r], parameters)) for r in range(n)])
    free = flat[:, index]
    covariance = np.atleast_2d(np.cov(free, rowvar=False))
    std = np.zeros(flat.shape[1])
    std[index] = np.sqrt(np.diag(covariance))
    return Replicates(solutions, free, free.mean(axis=0), covariance,
                      unflatten(problem.initial, std))


def monte_carlo(
    problem: BundleProblem,
    n: int,
    key: PRNGKeyArray,
    *,
    at: Parameters | None = None,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    scheduler=None,
    chunk_size: int | None = None,
) -> Replicates:
    """`n` replicates with simulated image noise N(0, σ²), solved in vmapped chunks of
    `chunk_size`, here or on a Dask `scheduler` (module docstring).

    The replicates start from `problem.initial`. `at`: the parameters the noise-free image
    coordinates are computed at (default: `adjust(problem)`'s solution).
    """
    at = at if at is not None else adjust(problem, check=False).parameters
    measured = _simulated(problem, at, key, n)
    return _solve_replicates(problem, measured, max_steps=max_steps, rtol=rtol, atol=atol,
                             scheduler=scheduler, chunk_size=chunk_size)


def bootstrap(
    problem: BundleProblem,
    n: int,
    key: PRNGKeyArray,
    *,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    scheduler=None,
    chunk_size: int | None = None,
) -> Replicates:
    """`n` residual-bootstrap replicates (module docstring), solved as `monte_carlo`'s.

    Whitened image residuals are pooled over all image groups and resampled per coordinate
    with replacement, scaled by sqrt(n_obs / r).
    """
    result = adjust(problem, check=False)
    params, redundancy = result.parameters, result.precision.redundancy
    residuals, masks = jax.device_get(_image_residuals(problem, params))
    pool = np.concatenate([e[mask] for e, mask in zip(residuals, masks)])
    pool = (pool - pool.mean()) * np.sqrt(problem.n_observations() / redundancy)
    measured = _resampled(problem, params, pool, key, n)
    return _solve_replicates(problem, measured, max_steps=max_steps, rtol=rtol, atol=atol,
                             scheduler=scheduler, chunk_size=chunk_size)


__all__ = ["Replicates", "bootstrap", "monte_carlo"]
