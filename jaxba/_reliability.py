"""Internal reliability: redundancy numbers, normalised residuals, MDB, data snooping.

With the whitened Jacobian J (real observations) the redundancy matrix in whitened
space is R = I - J (JᵀJ)⁻¹ Jᵀ; its diagonal equals that of R = I - A N⁻¹ AᵀP, so the
redundancy numbers r_i = R_ii sum to the redundancy n - u. Normalised residuals
w_i = v_i / (σ0 sqrt(q_vv,i)) = e_i / sqrt(r_i) (Baarda); the minimal detectable bias
∇_i = δ0 σ_i / sqrt(r_i) with δ0 = z(1 - α/2) + z(power).
"""

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.stats

from ._free_network import free_network_redundancy_numbers, inner_constraint_group
from ._linearisation import dense_jacobian
from ._observations import ImagePoints
from ._problem import BundleProblem, observation_mask
from ._schur._reliability import schur_redundancy_numbers
from ._solve import Adjustment, adjust


@dataclasses.dataclass(frozen=True)
class Reliability:
    """Per observation group, arrays shaped like the group's residuals (NaN where masked).

    - `redundancy_numbers`: r_i in [0, 1];
    - `normalised_residuals`: w_i (Baarda's w-test statistic);
    - `mdb`: minimal detectable bias, units of the observation;
    - `critical_value`: |w| above which an observation is rejected at `alpha`.
    """

    redundancy_numbers: tuple[np.ndarray, ...]
    normalised_residuals: tuple[np.ndarray, ...]
    mdb: tuple[np.ndarray, ...]
    alpha: float
    critical_value: float


def _split(problem: BundleProblem, flat_real: np.ndarray) -> tuple[np.ndarray, ...]:
    """Scatter values of the real observations back into group-shaped arrays (NaN elsewhere)."""
    mask = observation_mask(problem)
    full = np.full(mask.shape, np.nan)
    full[mask] = flat_real
    parts, start = [], 0
    for group in problem.groups:
        shape = np.shape(group.stddev)
        parts.append(full[start:start + int(np.prod(shape))].reshape(shape))
        start += int(np.prod(shape))
    return tuple(parts)


def redundancy_numbers(
    problem: BundleProblem, params, *, schur: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) of the real observations, flat, at `params`: dense, or with `schur` from
    the Schur split (`schur_redundancy_numbers`, for bundles adjusted that way; free
    networks through their minimal datum)."""
    if schur and inner_constraint_group(problem) is not None:
        return free_network_redundancy_numbers(problem, params)
    if schur:
        return schur_redundancy_numbers(problem, params)
    jacobian, whitened = (np.asarray(a) for a in dense_jacobian(problem, params))
    column_scale = 1.0 / np.linalg.norm(jacobian, axis=0)
    scaled = jacobian * column_scale
    factor = scipy.linalg.cho_factor(scaled.T @ scaled)
    leverage = np.sum(scaled * scipy.linalg.cho_solve(factor, scaled.T).T, axis=1)
    return 1.0 - leverage, whitened


def per_test_alpha(alpha: float, n_tests: int, *, familywise: bool) -> float:
    """Significance of one w-test: `alpha` itself, or for a family-wise `alpha` over
    `n_tests` tests Šidák's α0 = 1 - (1 - α)^(1/n)."""
    return -math.expm1(math.log1p(-alpha) / n_tests) if familywise else alpha


def reliability(
    result: Adjustment, *, alpha: float = 0.001, power: float = 0.8, familywise: bool = False
) -> Reliability:
    """Redundancy numbers, w-test statistics and MDBs at the adjusted solution.

    `alpha` is the significance of each w-test, or with `familywise=True` that of the
    whole set of tests (see `per_test_alpha`); `Reliability.alpha` is the per-test one.
    """
    schur = result.precision.schur
    if schur is not None and schur.redundancy is not None:  # computed with the covariance
        r, whitened = schur.redundancy
    else:
        r, whitened = redundancy_numbers(result.problem, result.parameters,
                                         schur=schur is not None)
    return reliability_from_redundancy(
        result.problem, r, whitened, alpha=alpha, power=power, familywise=familywise
    )


def reliability_from_redundancy(
    problem: BundleProblem,
    r: np.ndarray,
    whitened: np.ndarray,
    *,
    alpha: float = 0.001,
    power: float = 0.8,
    familywise: bool = False,
) -> Reliability:
    """`reliability` from the redundancy numbers r_i and whitened residuals e_i of the real
    observations (flat, `observation_mask` order), e.g. from a batched computation."""
    alpha = per_test_alpha(alpha, problem.n_observations(), familywise=familywise)
    safe_r = np.where(r > 1e-12, r, np.nan)
    critical = float(scipy.stats.norm.ppf(1 - alpha / 2))
    delta0 = critical + float(scipy.stats.norm.ppf(power))
    sigma = np.concatenate([np.ravel(np.asarray(g.stddev)) for g in problem.groups])
    sigma = sigma[observation_mask(problem)]
    return Reliability(
        redundancy_numbers=_split(problem, r),
        normalised_residuals=_split(problem, whitened / np.sqrt(safe_r)),
        mdb=_split(problem, delta0 * sigma / np.sqrt(safe_r)),
        alpha=alpha,
        critical_value=critical,
    )


@dataclasses.dataclass(frozen=True)
class Rejection:
    """An observation removed by data snooping: group name, row, coordinate and its |w|."""

    group: str
    row: int
    coordinate: int
    w: float


def remove_observation(problem: BundleProblem, group_index: int, row: int, coordinate: int):
    """The problem with one observation switched off (σ = inf).

    An image point is removed whole (x and y): a wrong measurement is wrong in both.
    """
    group = problem.groups[group_index]
    columns = slice(None) if isinstance(group, ImagePoints) else coordinate
    stddev = group.stddev.at[row, columns].set(jnp.inf)
    groups = list(problem.groups)
    groups[group_index] = eqx.tree_at(lambda g: g.stddev, group, stddev)
    return eqx.tree_at(lambda p: p.groups, problem, tuple(groups))


def restart_from(problem: BundleProblem, params) -> BundleProblem:
    """The problem with `params` as its approximations (fixed values are unchanged)."""
    return eqx.tree_at(lambda p: p.initial, problem, params)


def data_snooping(
    result: Adjustment,
    *,
    alpha: float = 0.001,
    familywise: bool = False,
    max_rejections: int = 50,
    **adjust_options,
) -> tuple[Adjustment, list[Rejection], Reliability]:
    """Baarda's iterative data snooping.

    Test every observation's w against the two-sided normal critical value at `alpha`
    (per test, or family-wise over all tests with `familywise=True`); remove the worst
    one above it, re-adjust from the current solution, and repeat.
    Returns the final adjustment, the rejected observations in order, and the final
    reliability. `adjust_options` go to `adjust` (sigma0, max_steps, ...).
    """
    rejections: list[Rejection] = []
    current = result
    while True:
        report = reliability(current, alpha=alpha, familywise=familywise)
        worst = [
            (np.nanmax(np.abs(w)) if np.isfinite(w).any() else 0.0, k)
            for k, w in enumerate(report.normalised_residuals)
        ]
        size, group_index = max(worst)
        if size <= report.critical_value or len(rejections) >= max_rejections:
            return current, rejections, report
        w = np.abs(np.nan_to_num(report.normalised_residuals[group_index], nan=0.0))
        row, coordinate = np.unravel_index(np.argmax(w), w.shape)
        group = current.problem.groups[group_index]
        rejections.append(Rejection(group.name, int(row), int(coordinate), float(size)))
        problem = remove_observation(current.problem, group_index, int(row), int(coordinate))
        current = adjust(restart_from(problem, current.parameters), check=False, **adjust_options)
