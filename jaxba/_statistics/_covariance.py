"""Precision at the solution: σ̂0², redundancy and the covariance of the free unknowns, from
the cofactors N⁻¹ that a backend forms (`Backend.cofactors`: all of it, or in blocks)."""

import dataclasses

import jax
import numpy as np

from .._problem._bundle import BundleProblem, free_indices, tie_source
from .._problem._parameters import Parameters, flatten, positions_of, unflatten
from .._solvers._backend import Backend, Cofactors, Leverages
from .._solvers._dense import Dense
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import BundleStructure


@dataclasses.dataclass(frozen=True)
class SchurCovariance:
    """Cxx of a bundle adjusted with the object points eliminated (`Schur`): the
    reduced side (IOPs, EOPs, points in distances) in full and every object point's 3 x 3
    block; the cross-covariances of an eliminated point with any other unknown are not
    formed (they would make Cxx dense).

    - `reduced_positions`: (n_r,) `flatten` positions of the reduced unknowns;
    - `reduced`: (n_r, n_r) their covariance (rows of fixed unknowns 0);
    - `points`: (n_points, 3, 3) every point's covariance (0 for fixed coordinates);
    - `redundancy`: the redundancy numbers and whitened residuals (r_i, e_i) of the real
      observations at the same solution (`redundancy_numbers`), where they were
      computed with the covariance (`Schur.cofactors`: one program for both), else None.
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
    point_positions = np.asarray(positions_of(std).points)
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


def redundancy_numbers(leverages: Leverages) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) of the real observations (flat, `observation_mask` order): r_i = 1 - j N⁻¹ jᵀ."""
    return 1.0 - leverages.leverage, leverages.whitened


def precision(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    backend: Backend | None = None,
) -> Precision:
    """σ̂0², σ of every unknown and the covariance of the free unknowns at `params`, from
    `backend`'s cofactors (`precision_from_cofactors`; default `Dense`: all of Cxx, up to a
    few thousand unknowns; `LinAlgError` where N is singular)."""
    backend = Dense() if backend is None else backend.ready(problem)
    return precision_from_cofactors(problem, params, backend.cofactors(problem, params),
                                    sigma0=sigma0)


def precision_from_cofactors(
    problem: BundleProblem, params: Parameters, cofactors: Cofactors, *, sigma0: float = 1.0
) -> Precision:
    """The `Precision` of N⁻¹ (`cofactors`, any backend's) at `params`: σ̂0² = σ0² eᵀe / r and
    Cxx = σ̂0² (σ0² JᵀJ)⁻¹, all of it where the backend formed all of N⁻¹, else its blocks
    (`SchurCovariance`, with the redundancy numbers where the backend formed them)."""
    n_observations = problem.n_observations()
    redundancy = n_observations - free_indices(problem).size
    sigma0_squared = sigma0**2 * cofactors.squares / redundancy
    variance_factor = sigma0_squared / sigma0**2
    if cofactors.matrix is not None:
        return precision_from_covariance(problem, params, variance_factor * cofactors.matrix,
                                         sigma0_squared, redundancy, n_observations)
    leverages = cofactors.leverages
    return precision_from_blocks(problem, params, sigma0_squared, redundancy, SchurCovariance(
        reduced_positions=cofactors.reduced_positions,
        reduced=variance_factor * cofactors.reduced,
        points=variance_factor * cofactors.points,
        redundancy=None if leverages is None else redundancy_numbers(leverages),
    ))


def precision_from_blocks(
    problem: BundleProblem,
    params: Parameters,
    sigma0_squared: float,
    redundancy: int,
    blocks: SchurCovariance,
) -> Precision:
    """The `Precision` of Cxx in blocks (`blocks`) of `problem`'s unknowns at `params`: σ
    from the blocks' diagonals (0 for fixed unknowns)."""
    n_all = flatten(params).size
    std = np.zeros(n_all)
    std[blocks.reduced_positions] = np.sqrt(np.clip(np.diag(blocks.reduced), 0.0, None))
    point_positions = np.asarray(unflatten(params, np.arange(n_all)).points)
    std[point_positions] = np.sqrt(np.clip(np.diagonal(blocks.points, axis1=1, axis2=2), 0.0,
                                           None))
    index = free_indices(problem)
    return with_ties(Precision(
        sigma0_squared=sigma0_squared,
        redundancy=redundancy,
        n_observations=problem.n_observations(),
        n_unknowns=index.size,
        free_index=index,
        covariance=None,
        std=unflatten(jax.tree.map(np.asarray, params), std * flatten(problem.free)),
        schur=blocks,
    ), problem)


def precision_from_covariance(
    problem: BundleProblem,
    params: Parameters,
    covariance: np.ndarray,
    sigma0_squared: float,
    redundancy: int,
    n_observations: int,
    index: np.ndarray | None = None,
) -> Precision:
    """The `Precision` of Cxx (n_free, n_free) of `problem`'s free unknowns at `params`;
    `index`: their positions, `free_indices(problem)` (computed where not given)."""
    index = free_indices(problem) if index is None else index
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


def schur_precision(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    structure: BundleStructure | None = None,
) -> Precision:
    """`precision` from the Schur split, without any dense n x n inverse: σ̂0², σ of every
    unknown, and as covariance a `SchurCovariance` (`covariance` None): Cxx of the reduced
    side and every object point's 3 x 3 block, with the redundancy numbers. For bundles
    with a datum (a free network: `free_network_precision`). `structure`: the problem's
    `bundle_structure`, if already built."""
    return precision(problem, params, sigma0=sigma0, backend=Schur(structure))


@dataclasses.dataclass(frozen=True)
class BundleCofactors:
    """Cofactors (JᵀJ)⁻¹ of the whitened bundle at a solution, from the Schur split.

    - `reduced`: (n_r, n_r) = S⁻¹, the full cofactor block of the reduced side (IOPs, EOPs,
      distance points; `BundleStructure` column order), rows/columns of fixed unknowns 0;
    - `points`: (n_points, 3, 3) the 3 x 3 cofactor block of every object point;
    - `sigma0_squared`: σ0² eᵀe / (n_observations - n_unknowns);
    - `std`: Parameters of σ = sqrt(σ̂0²/σ0² diag Q), as `Precision.std`.
    """

    reduced: np.ndarray
    points: np.ndarray
    sigma0_squared: float
    std: Parameters


def schur_cofactors(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    structure: BundleStructure | None = None,
) -> BundleCofactors:
    """The cofactor blocks behind `schur_precision` (`Schur.cofactors`), unscaled, with σ̂0²
    and σ: the same numbers as the dense `precision` for bundles with a datum; not for
    free networks."""
    backend = Schur(structure).ready(problem)
    cofactors = backend.cofactors(problem, params)
    scaled = precision_from_cofactors(problem, params, cofactors, sigma0=sigma0)
    return BundleCofactors(cofactors.reduced, cofactors.points, scaled.sigma0_squared,
                           scaled.std)
