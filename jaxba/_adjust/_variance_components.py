"""Variance component estimation per observation group (Förstner / Helmert iteration).

σ̂k² = e_kᵀe_k / r_k, r_k = Σ_{i in k} r_i (the group's share of the redundancy, from
the diagonal of R). Each group's σ is multiplied by σ̂k and the bundle re-adjusted until
every σ̂k² is 1 within `tolerance`; the component reported is the product of the factors,
i.e. the estimated σ of the group relative to its a priori σ.
"""

import dataclasses

import equinox as eqx
import numpy as np

from .._problem._bundle import BundleProblem, observation_mask
from .._statistics._adjustment import Adjustment
from .._statistics._backends import adjusted_redundancy_numbers
from ._adjust import adjust
from ._snooping import restart_from


@dataclasses.dataclass(frozen=True)
class VarianceComponent:
    """sigma0: estimated σ factor of the group (1 = prior right); redundancy r_k."""

    sigma0: float
    redundancy: float
    n_observations: int


def _finite_ratio(stddev, prior) -> np.ndarray:
    """σ_current / σ_prior over the entries observed in both (NaN if none)."""
    stddev, prior = np.asarray(stddev), np.asarray(prior)
    both = np.isfinite(stddev) & np.isfinite(prior)
    return stddev[both] / prior[both] if both.any() else np.array([np.nan])


def _group_slices(problem):
    start = 0
    for group in problem.groups:
        size = int(np.size(group.stddev))
        yield group, slice(start, start + size)
        start += size


def estimate_variance_components(
    result: Adjustment,
    *,
    max_iterations: int = 30,
    tolerance: float = 1e-4,
    min_redundancy: float = 1.0,
    reference: BundleProblem | None = None,
    **adjust_options,
) -> tuple[Adjustment, dict[str, VarianceComponent], int]:
    """Iterate variance components from an adjusted bundle.

    Groups with r_k < `min_redundancy` are reported but not re-weighted (their estimate
    is unreliable). Components are relative to the σ of `reference` (default: the
    adjusted problem itself), so a second pass can continue a first one. Returns the
    final adjustment (its σ̂0 ≈ 1 when the components are right), the components by
    group name, and the number of iterations.
    """
    reference = reference or result.problem
    factors = {
        group.name: float(np.nanmedian(_finite_ratio(group.stddev, prior.stddev)))
        for group, prior in zip(result.problem.groups, reference.groups)
    }
    current = result
    for iteration in range(1, max_iterations + 1):
        problem = current.problem
        r, whitened = adjusted_redundancy_numbers(current)
        full_r = np.zeros(observation_mask(problem).shape)
        full_e = np.zeros_like(full_r)
        full_r[observation_mask(problem)] = r
        full_e[observation_mask(problem)] = whitened
        estimates = {}
        for group, part in _group_slices(problem):
            r_k = float(np.sum(full_r[part]))
            variance = float(np.sum(full_e[part] ** 2)) / r_k if r_k > 0 else 1.0
            estimates[group.name] = (variance, r_k)
        converged = all(
            abs(v - 1.0) < tolerance for v, r_k in estimates.values() if r_k >= min_redundancy
        )
        if converged:
            break
        groups = []
        for group in problem.groups:
            variance, r_k = estimates[group.name]
            if r_k >= min_redundancy:
                factors[group.name] *= np.sqrt(variance)
                group = eqx.tree_at(lambda g: g.stddev, group, group.stddev * np.sqrt(variance))
            groups.append(group)
        reweighted = eqx.tree_at(lambda p: p.groups, problem, tuple(groups))
        restart = restart_from(reweighted, current.parameters)
        current = adjust(restart, check=False, **adjust_options)
    components = {
        group.name: VarianceComponent(
            sigma0=factors[group.name] * float(np.sqrt(estimates[group.name][0])),
            redundancy=estimates[group.name][1],
            n_observations=int(np.sum(np.isfinite(np.asarray(group.stddev)))),
        )
        for group in current.problem.groups
    }
    return current, components, iteration
