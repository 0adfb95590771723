"""Empirical precision on the batch API: Monte Carlo and bootstrap replicates of one bundle,
all solved in one vmapped call (`_batch.solve_batch`: one compilation, no padding needed).

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
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from .._problem._bundle import BundleProblem
from .._problem._linearisation import linearisation_plan
from .._problem._observations import ImagePoints
from .._problem._parameters import Parameters, flatten, unflatten
from .._solvers._solution import Solution
from ._adjust import adjust
from ._batch import broadcast_plan, solve_batch


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
    return [k for k, g in enumerate(problem.groups) if isinstance(g, ImagePoints)]


def _computed(problem: BundleProblem, params: Parameters, k: int) -> Array:
    """Computed image coordinates of group k at params: measured - σ e."""
    group = problem.groups[k]
    e = group.residuals(params, problem.refraction)
    sigma = jnp.where(group.mask(), group.stddev, 0.0)
    return group.measured - sigma * jnp.where(group.mask(), e, 0.0)


def _replicate(problem: BundleProblem, measured: list[Array]) -> BundleProblem:
    ks = _image_groups(problem)
    return eqx.tree_at(lambda p: [p.groups[k].measured for k in ks], problem, measured)


def _solve_replicates(problem, measured, *, max_steps, rtol, atol) -> Replicates:
    n = measured[0].shape[0]
    stacked = jax.vmap(lambda m: _replicate(problem, m))(measured)
    plan = linearisation_plan(problem)
    index = np.asarray(plan.free_index)
    solutions = solve_batch(stacked, broadcast_plan(plan, n), max_steps=max_steps, rtol=rtol,
                            atol=atol)
    flat = np.stack([flatten(jax.tree.map(lambda leaf: leaf[r], solutions.parameters))
                     for r in range(n)])
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
) -> Replicates:
    """`n` replicates with simulated image noise N(0, σ²), solved in one vmapped call.

    The replicates start from `problem.initial`. `at`: the parameters the noise-free image
    coordinates are computed at (default: `adjust(problem)`'s solution).
    """
    at = at if at is not None else adjust(problem, check=False).parameters
    measured = []
    for k, key_k in zip(_image_groups(problem), jax.random.split(key, len(problem.groups))):
        group = problem.groups[k]
        computed = _computed(problem, at, k)
        sigma = jnp.where(group.mask(), group.stddev, 0.0)
        noise = jax.random.normal(key_k, (n, *computed.shape)) * sigma
        measured.append(computed + noise)
    return _solve_replicates(problem, measured, max_steps=max_steps, rtol=rtol, atol=atol)


def bootstrap(
    problem: BundleProblem,
    n: int,
    key: PRNGKeyArray,
    *,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
) -> Replicates:
    """`n` residual-bootstrap replicates (module docstring), solved in one vmapped call.

    Whitened image residuals are pooled over all image groups and resampled per coordinate
    with replacement, scaled by sqrt(n_obs / r).
    """
    result = adjust(problem, check=False)
    params, redundancy = result.parameters, result.precision.redundancy
    ks = _image_groups(problem)
    pool = np.concatenate([
        np.asarray(problem.groups[k].residuals(params, problem.refraction))[
            np.asarray(problem.groups[k].mask())]
        for k in ks
    ])
    pool = (pool - pool.mean()) * np.sqrt(problem.n_observations() / redundancy)
    measured = []
    for k, key_k in zip(ks, jax.random.split(key, len(ks))):
        group = problem.groups[k]
        computed = _computed(problem, params, k)
        draws = jax.random.choice(key_k, jnp.asarray(pool), (n, *computed.shape))
        sigma = jnp.where(group.mask(), group.stddev, 0.0)
        measured.append(computed + sigma * draws)
    return _solve_replicates(problem, measured, max_steps=max_steps, rtol=rtol, atol=atol)


__all__ = ["Replicates", "bootstrap", "monte_carlo"]
