"""Precision at the solution: σ̂0², redundancy and the covariance of the free unknowns."""

import dataclasses

import numpy as np
import scipy.linalg

from ._free_network import InnerConstraints
from ._parameters import Parameters, flatten, unflatten
from ._problem import BundleProblem, dense_jacobian, free_indices


@dataclasses.dataclass(frozen=True)
class Precision:
    """Cxx = σ̂0² N⁻¹, N = AᵀPA (whitened Jacobian J: N = σ0² JᵀJ), free unknowns only;
    for a free network N⁻¹ is the inner-constraint generalised inverse.

    - `sigma0_squared`: a posteriori variance factor σ0² vᵀΣ⁻¹v / r;
    - `covariance`: (n_free, n_free) in the order of `free_index`;
    - `std`: Parameters of standard deviations, 0 for fixed unknowns.
    """

    sigma0_squared: float
    redundancy: int
    n_observations: int
    n_unknowns: int
    free_index: np.ndarray
    covariance: np.ndarray
    std: Parameters


def _constraint_rows(problem: BundleProblem) -> np.ndarray:
    """Flat mask over the real observations: True on rows of inner-constraint groups."""
    return np.concatenate([
        np.full(int(np.sum(np.asarray(group.mask()))), isinstance(group, InnerConstraints))
        for group in problem.groups
    ])


def _inner_constraint_cofactor(observations: np.ndarray, constraints: np.ndarray) -> np.ndarray:
    """Top-left block of [[N, B], [Bᵀ, 0]]⁻¹, N = AᵀA, B = Cᵀ: the cofactor of a free
    network under the inner constraints C dx = 0 (a generalised inverse of N)."""
    n, d = observations.shape[1], constraints.shape[0]
    bordered = np.block([
        [observations.T @ observations, constraints.T],
        [constraints, np.zeros((d, d))],
    ])
    return np.linalg.solve(bordered, np.eye(n + d)[:, :n])[:n]


def precision(problem: BundleProblem, params: Parameters, *, sigma0: float = 1.0) -> Precision:
    """Dense covariance of the free unknowns at `params` (up to a few thousand unknowns)."""
    jacobian, whitened = (np.asarray(a) for a in dense_jacobian(problem, params))
    n_observations, n_unknowns = jacobian.shape
    redundancy = n_observations - n_unknowns
    sigma0_squared = sigma0**2 * float(whitened @ whitened) / redundancy
    # Equilibrate columns before factorising; N⁻¹ = D (D N D)⁻¹ D.
    column_scale = 1.0 / np.maximum(np.linalg.norm(jacobian, axis=0), np.finfo(float).tiny)
    scaled = jacobian * column_scale
    constraint = _constraint_rows(problem)
    if constraint.any():
        cofactor = _inner_constraint_cofactor(scaled[~constraint], scaled[constraint])
    else:
        cofactor = scipy.linalg.cho_solve(
            scipy.linalg.cho_factor(scaled.T @ scaled), np.eye(n_unknowns)
        )
    # Cxx = σ̂0² (σ0² JᵀJ)⁻¹
    covariance = (sigma0_squared / sigma0**2) * (
        column_scale[:, None] * cofactor * column_scale[None, :]
    )
    return precision_from_covariance(
        problem, params, covariance, sigma0_squared, redundancy, n_observations)


def precision_from_covariance(
    problem: BundleProblem,
    params: Parameters,
    covariance: np.ndarray,
    sigma0_squared: float,
    redundancy: int,
    n_observations: int,
) -> Precision:
    """The `Precision` of Cxx (n_free, n_free) of `problem`'s free unknowns at `params`."""
    index = free_indices(problem)
    std = np.zeros(flatten(params).shape)
    std[index] = np.sqrt(np.diag(covariance))
    return Precision(
        sigma0_squared=sigma0_squared,
        redundancy=redundancy,
        n_observations=n_observations,
        n_unknowns=index.size,
        free_index=index,
        covariance=covariance,
        std=unflatten(params, std),
    )
