"""Internal reliability: redundancy numbers, normalised residuals, MDB.

With the whitened Jacobian J (real observations) the redundancy matrix in whitened
space is R = I - J (JᵀJ)⁻¹ Jᵀ; its diagonal equals that of R = I - A N⁻¹ AᵀP, so the
redundancy numbers r_i = R_ii sum to the redundancy n - u. Normalised residuals
w_i = v_i / (σ0 sqrt(q_vv,i)) = e_i / sqrt(r_i) (Baarda); the minimal detectable bias
∇_i = δ0 σ_i / sqrt(r_i) with δ0 = z(1 - α/2) + z(power).
"""

import dataclasses
import math

import numpy as np

from .._problem._bundle import BundleProblem, observation_mask
from .._problem._parameters import Parameters
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import BundleStructure
from ._adjustable import adjusted_redundancy_numbers
from ._adjustment import Adjustment
from ._covariance import redundancy_numbers


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


def _split(problem: BundleProblem, mask: np.ndarray, flat_real: np.ndarray
           ) -> tuple[np.ndarray, ...]:
    """Scatter values of the real observations (`mask`: `observation_mask(problem)`) back
    into group-shaped arrays (NaN elsewhere)."""
    full = np.full(mask.shape, np.nan)
    full[mask] = flat_real
    parts, start = [], 0
    for group in problem.groups:
        shape = np.shape(group.stddev)
        parts.append(full[start:start + int(np.prod(shape))].reshape(shape))
        start += int(np.prod(shape))
    return tuple(parts)


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
    r, whitened = adjusted_redundancy_numbers(result)
    return reliability_from_redundancy(
        result.problem, r, whitened, alpha=alpha, power=power, familywise=familywise
    )


def schur_redundancy_numbers(
    problem: BundleProblem, params: Parameters, *, structure: BundleStructure | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) of the real observations, flat in `observation_mask` order, at `params`
    from the Schur split (`Schur.leverages`): the dense ones without a dense Jacobian or
    N⁻¹. For bundles with a datum; `structure`: the problem's `bundle_structure`, if built."""
    return redundancy_numbers(Schur(structure).ready(problem).leverages(problem, params))


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
    mask = observation_mask(problem)
    return group_reliability(
        tuple(np.asarray(group.stddev) for group in problem.groups), _split(problem, mask, r),
        _split(problem, mask, whitened), int(mask.sum()), alpha=alpha, power=power,
        familywise=familywise)


def group_reliability(
    stddev: tuple[np.ndarray, ...],
    r: tuple[np.ndarray, ...],
    whitened: tuple[np.ndarray, ...],
    n_observations: int,
    *,
    alpha: float = 0.001,
    power: float = 0.8,
    familywise: bool = False,
) -> Reliability:
    """`reliability_from_redundancy` from arrays shaped like each group's residuals: σ of
    its observations, r_i (NaN where masked) and e_i; `n_observations` the real ones (the
    tests of a family-wise `alpha`)."""
    alpha = per_test_alpha(alpha, n_observations, familywise=familywise)
    import scipy.special  # here: scipy.stats, for norm.ppf alone, took 0.8 s to import

    critical = float(scipy.special.ndtri(1 - alpha / 2))  # the standard normal's ppf
    delta0 = critical + float(scipy.special.ndtri(power))
    root = [np.sqrt(np.where(x > 1e-12, x, np.nan)) for x in r]  # NaN where masked
    return Reliability(
        redundancy_numbers=tuple(r),
        normalised_residuals=tuple(e / q for e, q in zip(whitened, root)),
        mdb=tuple(delta0 * sigma / q for sigma, q in zip(stddev, root)),
        alpha=alpha,
        critical_value=critical,
    )
