"""The Dense backend's normal equations at given parameters, from the dense whitened Jacobian
J (real observations x free unknowns, `dense_jacobian`): rank, N⁻¹ and the leverages, in
NumPy (one problem, outside jax; the batches' jax versions: `_dense.cofactors`)."""

import numpy as np

from .._problem._bundle import BundleProblem, free_indices
from .._problem._linearisation import dense_jacobian
from .._problem._parameters import Parameters
from ._backend import Cofactors, Leverages, Rank

# The datum check's threshold on the equilibrated Jacobian's singular values (smallest /
# largest): a defect where one is below it.
SINGULAR_VALUE_RTOL = 1e-9


def jacobian_rank(jacobian: np.ndarray, *, rtol: float = SINGULAR_VALUE_RTOL) -> Rank:
    """`Rank` from the whitened Jacobian (n_obs, n_free) at the approximations: the null
    space from the singular values of the column-equilibrated Jacobian (smallest / largest
    < `rtol`)."""
    finite = np.all(np.isfinite(jacobian), axis=0)
    column_norms = np.linalg.norm(jacobian, axis=0)
    if not (np.all(finite) and np.all(column_norms > 0)):
        return Rank(finite, column_norms, None)
    scaled = jacobian / column_norms
    if scaled.shape[0] > scaled.shape[1]:  # J = QR: R has J's singular values and V
        scaled = np.linalg.qr(scaled, mode="r")
    _, singular, vt = np.linalg.svd(scaled, full_matrices=False)
    null_rows = singular < rtol * singular[0]
    return Rank(finite, column_norms,
                vt[null_rows] / column_norms if null_rows.any() else None)


def equilibrated_jacobian(jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J D, D) with D = 1/‖column‖ of the whitened Jacobian J (n_obs, n_free): N⁻¹ =
    D (D N D)⁻¹ D, factorised with unit columns."""
    column_scale = 1.0 / np.maximum(np.linalg.norm(jacobian, axis=0), np.finfo(float).tiny)
    return jacobian * column_scale, column_scale


def scaled_cofactor(scaled: np.ndarray) -> np.ndarray:
    """(AᵀA)⁻¹ by Cholesky of the equilibrated Jacobian A = J D (`equilibrated_jacobian`):
    the dense cofactor matrix of a problem with a datum."""
    import scipy.linalg  # on first use: its import (0.2-0.4 s) is not every run's

    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(scaled.T @ scaled),
                                  np.eye(scaled.shape[1]))


def _constraint_rows(problem: BundleProblem) -> np.ndarray:
    """Flat mask over the real observations: True on rows of constraint groups."""
    return np.concatenate([
        np.full(int(np.sum(np.asarray(group.mask()))), group.constraint)
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


def dense_cofactors(problem: BundleProblem, params: Parameters) -> Cofactors:
    """All of N⁻¹ at `params` (up to a few thousand unknowns): of a free network (rows of
    a constraint group) the inner-constraint generalised inverse."""
    jacobian, whitened = (np.asarray(a) for a in dense_jacobian(problem, params))
    scaled, column_scale = equilibrated_jacobian(jacobian)
    constraint = _constraint_rows(problem)
    if constraint.any():
        cofactor = _inner_constraint_cofactor(scaled[~constraint], scaled[constraint])
    else:
        cofactor = scaled_cofactor(scaled)
    return Cofactors(squares=float(whitened @ whitened),
                     matrix=column_scale[:, None] * cofactor * column_scale[None, :])


def dense_leverages(problem: BundleProblem, params: Parameters) -> Leverages:
    """diag(J N⁻¹ Jᵀ) at `params`, from the column-scaled dense Jacobian."""
    jacobian, whitened = (np.asarray(a) for a in dense_jacobian(problem, params))
    scaled = equilibrated_jacobian(jacobian)[0]
    return Leverages(np.sum((scaled @ scaled_cofactor(scaled)) * scaled, axis=1), whitened)


def dense_normal_solve(problem: BundleProblem, params: Parameters, rhs: np.ndarray
                       ) -> np.ndarray:
    """N⁻¹ b for each row b of `rhs` (m, n_all) from the dense N⁻¹ (`dense_cofactors`)."""
    index = free_indices(problem)
    rhs = np.asarray(rhs)
    out = np.zeros_like(rhs)
    out[:, index] = rhs[:, index] @ dense_cofactors(problem, params).matrix
    return out
