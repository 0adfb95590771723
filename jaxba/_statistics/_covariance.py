"""Precision at the solution: σ̂0², redundancy and the covariance of the free unknowns."""

import dataclasses

import numpy as np

from .._problem._bundle import BundleProblem, free_indices, tie_source
from .._problem._linearisation import dense_jacobian
from .._problem._parameters import Parameters, flatten, unflatten


@dataclasses.dataclass(frozen=True)
class SchurCovariance:
    """Cxx of a bundle adjusted with the object points eliminated (`solve_schur`): the
    reduced side (IOPs, EOPs, points in distances) in full and every object point's 3 x 3
    block; the cross-covariances of an eliminated point with any other unknown are not
    formed (they would make Cxx dense).

    - `reduced_positions`: (n_r,) `flatten` positions of the reduced unknowns;
    - `reduced`: (n_r, n_r) their covariance (rows of fixed unknowns 0);
    - `points`: (n_points, 3, 3) every point's covariance (0 for fixed coordinates);
    - `redundancy`: the redundancy numbers and whitened residuals (r_i, e_i) of the real
      observations at the same solution (`schur_redundancy_numbers`), where they were
      computed with the covariance (`adjust`: one program for both), else None.
    """

    reduced_positions: np.ndarray
    reduced: np.ndarray
    points: np.ndarray
    redundancy: tuple[np.ndarray, np.ndarray] | None = None


@dataclasses.dataclass(frozen=True)
class Precision:
    """Cxx = σ̂0² N⁻¹, N = AᵀPA (whitened Jacobian J: N = σ0² JᵀJ), free unknowns only;
    for a free network N⁻¹ is the inner-constraint generalised inverse.

    - `sigma0_squared`: a posteriori variance factor σ0² vᵀΣ⁻¹v / r;
    - `covariance`: (n_free, n_free) in the order of `free_index`, or None for a bundle
      adjusted with its points eliminated, whose covariance is `schur` instead;
    - `std`: Parameters of standard deviations, 0 for fixed unknowns, a tied parameter's
      its source's (`BundleProblem.ties`);
    - `source`: (n_all,) `tie_source` of a problem with ties (None without): a tied
      parameter is its source's unknown, so its rows of Cxx are the source's (T C Tᵀ).

    `covariance_of(positions)` serves both.
    """

    sigma0_squared: float
    redundancy: int
    n_observations: int
    n_unknowns: int
    free_index: np.ndarray
    covariance: np.ndarray | None
    std: Parameters
    schur: SchurCovariance | None = None
    source: np.ndarray | None = None

    def covariance_of(self, positions: np.ndarray) -> np.ndarray:
        """Cxx among the unknowns at `positions` (`flatten` order over all unknowns; rows
        and columns of fixed ones 0). From `schur`, the positions must all be reduced
        unknowns or all coordinates of one object point (`ValueError` otherwise)."""
        positions = self._untied(positions)
        if self.covariance is not None:
            rows = self.covariance_rows(positions)
            free = rows >= 0
            out = np.zeros((positions.size, positions.size))
            out[np.ix_(free, free)] = self.covariance[np.ix_(rows[free], rows[free])]
            return out
        return _schur_block(self.schur, self.std, positions)

    def covariance_rows(self, positions: np.ndarray) -> np.ndarray:
        """Rows of `covariance` of the unknowns at `positions` (any shape), -1 where fixed."""
        return _rows_of(flatten(self.std).size, self.free_index)[self._untied(positions)]

    def _untied(self, positions) -> np.ndarray:
        """`positions` with every tied parameter's replaced by its source's."""
        positions = np.asarray(positions, dtype=int)
        return positions if self.source is None else self.source[positions]


def with_ties(precision: Precision, problem: BundleProblem) -> Precision:
    """`precision` of a problem with `ties`: every tied parameter's σ its source's, and its
    covariances read at its source (`Precision.source`). Unchanged without ties."""
    if not problem.ties:
        return precision
    source = tie_source(problem)
    std = unflatten(precision.std, flatten(precision.std)[source])
    return dataclasses.replace(precision, std=std, source=source)


def _rows_of(n_all: int, index: np.ndarray) -> np.ndarray:
    """(n_all,) the row of each position in `index`, -1 for positions not in it."""
    rows = np.full(n_all, -1)
    rows[index] = np.arange(index.size)
    return rows


def _schur_block(schur: SchurCovariance, std: Parameters, positions: np.ndarray) -> np.ndarray:
    """`Precision.covariance_of` from a `SchurCovariance`."""
    rows = _rows_of(flatten(std).size, schur.reduced_positions)[positions]
    if np.all(rows >= 0):
        return schur.reduced[np.ix_(rows, rows)]
    point_positions = np.asarray(unflatten(std, np.arange(flatten(std).size)).points)
    where = np.isin(point_positions, positions)
    point_rows = np.flatnonzero(where.any(axis=1))
    if point_rows.size == 1 and np.all(np.isin(positions, point_positions[point_rows[0]])):
        coordinate = {int(p): k for k, p in enumerate(point_positions[point_rows[0]])}
        index = np.array([coordinate[int(p)] for p in positions])
        return schur.points[point_rows[0]][np.ix_(index, index)]
    raise ValueError(
        "this bundle was adjusted with its object points eliminated (Schur complement): "
        "covariances are available among IOPs, EOPs and distance points, or within one "
        "object point, not between an eliminated point and other unknowns"
    )


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


def equilibrated_jacobian(jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J D, D) with D = 1/‖column‖ of the whitened Jacobian J (n_obs, n_free): N⁻¹ =
    D (D N D)⁻¹ D, factorised with unit columns."""
    column_scale = 1.0 / np.maximum(np.linalg.norm(jacobian, axis=0), np.finfo(float).tiny)
    return jacobian * column_scale, column_scale


def scaled_cofactor(scaled: np.ndarray) -> np.ndarray:
    """(AᵀA)⁻¹ by Cholesky of the equilibrated Jacobian A = J D (`equilibrated_jacobian`):
    the dense cofactor matrix of a problem with a datum, NumPy (one problem, outside jax)."""
    import scipy.linalg  # on first use: its import (0.2-0.4 s) is not every run's

    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(scaled.T @ scaled),
                                  np.eye(scaled.shape[1]))


def precision(problem: BundleProblem, params: Parameters, *, sigma0: float = 1.0) -> Precision:
    """Dense covariance of the free unknowns at `params` (up to a few thousand unknowns)."""
    jacobian, whitened = (np.asarray(a) for a in dense_jacobian(problem, params))
    n_observations, n_unknowns = jacobian.shape
    redundancy = n_observations - n_unknowns
    sigma0_squared = sigma0**2 * float(whitened @ whitened) / redundancy
    scaled, column_scale = equilibrated_jacobian(jacobian)
    constraint = _constraint_rows(problem)
    if constraint.any():
        cofactor = _inner_constraint_cofactor(scaled[~constraint], scaled[constraint])
    else:
        cofactor = scaled_cofactor(scaled)
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
    return with_ties(Precision(
        sigma0_squared=sigma0_squared,
        redundancy=redundancy,
        n_observations=n_observations,
        n_unknowns=index.size,
        free_index=index,
        covariance=covariance,
        std=unflatten(params, std),
    ), problem)
