"""Variance component estimation per observation group (Förstner / Helmert iteration).

σ̂k² = e_kᵀe_k / r_k, r_k = Σ_{i in k} r_i (the group's share of the redundancy, from
the diagonal of R). Each group's σ is multiplied by σ̂k and the bundle re-adjusted until
every σ̂k² is 1 within `tolerance`; the component reported is the product of the factors,
i.e. the estimated σ of the group relative to its a priori σ. A group here is a part of an
observation group (`AbstractObservationGroup.parts`): the image points of one camera.
"""

import dataclasses

import equinox as eqx
import numpy as np

from .._problem._bundle import BundleProblem, observation_mask
from .._problem._observations import named_parts
from .._statistics._adjustable import adjusted_redundancy_numbers
from .._statistics._adjustment import Adjustment
from .._statistics._ids import index_ids
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


def _parts(problem, camera_ids):
    """(k, name, rows) of every part (`named_parts`) of every group k of `problem`."""
    return [(k, name, rows) for k, group in enumerate(problem.groups)
            for name, rows in named_parts(group, camera_ids)]


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
    part name (the group's name, or "image_points:<camera ID>" per camera: the IDs of
    `result.ids`), and the number of iterations.
    """
    reference = reference or result.problem
    camera_ids = (result.ids or index_ids(result.parameters)).cameras
    parts = _parts(result.problem, camera_ids)
    factors = {
        name: float(np.nanmedian(_finite_ratio(np.asarray(result.problem.groups[k].stddev)[rows],
                                               np.asarray(reference.groups[k].stddev)[rows])))
        for k, name, rows in parts
    }
    current = result
    for iteration in range(1, max_iterations + 1):
        problem = current.problem
        r, whitened = adjusted_redundancy_numbers(current)
        mask = observation_mask(problem)
        full_r, full_e = np.zeros(mask.shape), np.zeros(mask.shape)
        full_r[mask], full_e[mask] = r, whitened
        starts = np.cumsum([0] + [int(np.size(g.stddev)) for g in problem.groups])
        estimates = {}
        for k, name, rows in parts:
            group_r = full_r[starts[k]:starts[k + 1]].reshape(np.shape(problem.groups[k].stddev))
            group_e = full_e[starts[k]:starts[k + 1]].reshape(group_r.shape)
            r_k = float(np.sum(group_r[rows]))
            variance = float(np.sum(group_e[rows] ** 2)) / r_k if r_k > 0 else 1.0
            estimates[name] = (variance, r_k)
        converged = all(
            abs(v - 1.0) < tolerance for v, r_k in estimates.values() if r_k >= min_redundancy
        )
        if converged:
            break
        scale = [np.ones(np.shape(g.stddev)[0]) for g in problem.groups]
        for k, name, rows in parts:
            variance, r_k = estimates[name]
            if r_k >= min_redundancy:
                factors[name] *= np.sqrt(variance)
                scale[k][rows] = np.sqrt(variance)
        groups = tuple(
            eqx.tree_at(lambda g: g.stddev, group, group.stddev * s[:, None])
            if (s != 1).any() else group for group, s in zip(problem.groups, scale))
        reweighted = eqx.tree_at(lambda p: p.groups, problem, groups)
        restart = restart_from(reweighted, current.parameters)
        current = adjust(restart, check=False, **adjust_options)
    components = {
        name: VarianceComponent(
            sigma0=factors[name] * float(np.sqrt(estimates[name][0])),
            redundancy=estimates[name][1],
            n_observations=int(np.sum(np.isfinite(
                np.asarray(current.problem.groups[k].stddev)[rows]))),
        )
        for k, name, rows in parts
    }
    return current, components, iteration
