"""The rank of a bundle's normal equations from the Schur split, without a dense Jacobian.

The normal matrix N = JᵀJ at the approximations is formed in blocks (`bundle_normal_equations`)
and its null space found in two parts: an eliminated point whose 3 x 3 block V_p is singular
(seen along a single ray) is a defect of its own; with every V_p regular, N x = 0 exactly
when S x_r = 0 (S = U - W V⁻¹ Wᵀ, the reduced camera matrix, n_r x n_r) and
x_p = -V_p⁻¹ Y_pᵀ x_r, so S's null vectors, extended to the points, span the defect
(`jaxba._statistics._datum` names it).

Eigenvalues of the normal matrices rather than singular values of the Jacobian: the
condition number is squared, so a defect shows as an eigenvalue ratio at rounding level
(~1e-15) and the threshold is `EIGENVALUE_RTOL` (a Jacobian condition number of 1e6).
"""

import numpy as np

from ..._problem._bundle import BundleProblem, free_indices
from ..._problem._parameters import flatten, unflatten
from .._backend import Rank
from ._assembly import compiled_normal_equations
from ._columns import reduced_positions
from ._structure import BundleStructure

EIGENVALUE_RTOL = 1e-12


def schur_rank(problem: BundleProblem, structure: BundleStructure) -> Rank:
    """`Rank` of `problem`'s normal equations at its approximations, from the blocks
    (`structure`: `bundle_structure(problem)`; see the module docstring)."""
    normal, reduced, point_inverse, _ = compiled_normal_equations(problem, structure,
                                                                  problem.initial)
    index = free_indices(problem)
    n_all = flatten(problem.initial).size
    row_of = np.full(n_all, -1)
    row_of[index] = np.arange(index.size)
    positions = unflatten(problem.initial, np.arange(n_all))
    reduced_rows = row_of[reduced_positions(problem, structure)]
    point_rows = row_of[np.asarray(positions.points)[np.asarray(structure.eliminated_points)]]
    reduced_free, point_free = reduced_rows >= 0, point_rows >= 0

    hessian = np.asarray(normal.reduced_hessian)
    point_hessian = np.asarray(normal.point_hessian)
    diagonal = np.zeros(index.size)
    diagonal[reduced_rows[reduced_free]] = np.diag(hessian)[reduced_free]
    diagonal[point_rows[point_free]] = np.diagonal(point_hessian, axis1=1, axis2=2)[point_free]
    finite = np.isfinite(diagonal)
    column_norms = np.sqrt(np.where(finite, diagonal, 0.0))
    if not (np.all(finite) and np.all(column_norms > 0)):
        return Rank(finite, column_norms, None)
    basis = _single_ray_points(point_hessian, point_rows, index.size)
    if basis is None:
        basis = _reduced_null_space(structure, normal, reduced, point_inverse, reduced_rows,
                                    point_rows, index.size)
    return Rank(finite, column_norms, basis)


def _equilibrated_null_space(matrix: np.ndarray) -> np.ndarray:
    """Null vectors (columns) of a symmetric positive semi-definite matrix, found on its
    diagonally equilibrated form and returned in the original units."""
    if matrix.size == 0:
        return np.zeros((0, 0))
    scale = 1.0 / np.sqrt(np.maximum(np.diag(matrix), np.finfo(float).tiny))
    values, vectors = np.linalg.eigh(matrix * scale[:, None] * scale[None, :])
    null = values < EIGENVALUE_RTOL * values[-1]
    return vectors[:, null] * scale[:, None]


def _single_ray_points(point_hessian, point_rows, n_free) -> np.ndarray | None:
    """(d, n_free) null vectors of the points whose 3 x 3 block is singular (fixed
    coordinates have a unit row there, so they never are)."""
    diagonal = np.diagonal(point_hessian, axis1=1, axis2=2)
    scale = 1.0 / np.sqrt(np.maximum(diagonal, np.finfo(float).tiny))
    values, vectors = np.linalg.eigh(point_hessian * scale[:, :, None] * scale[:, None, :])
    point, k = np.nonzero(values < EIGENVALUE_RTOL * values[:, -1:])
    if point.size == 0:
        return None
    null = vectors[point, :, k] * scale[point]  # (d, 3)
    rows = point_rows[point]
    d, coordinate = np.nonzero(rows >= 0)
    basis = np.zeros((point.size, n_free))
    basis[d, rows[d, coordinate]] = null[d, coordinate]
    return basis


def _reduced_null_space(
    structure, normal, reduced, point_inverse, reduced_rows, point_rows, n_free
) -> np.ndarray | None:
    """(d, n_free) null vectors of S (`reduced`) on the free reduced unknowns, extended to
    the points by x_p = -V_p⁻¹ Y_pᵀ x_r (`point_inverse`: V⁻¹); None if S is regular."""
    reduced, point_inverse = np.asarray(reduced), np.asarray(point_inverse)
    free = reduced_rows >= 0
    null = _equilibrated_null_space(reduced[np.ix_(free, free)])
    if null.shape[1] == 0:
        return None
    x_r = np.zeros((reduced.shape[0] + 1, null.shape[1]))  # + the padding column
    x_r[np.flatnonzero(free)] = null
    coupling = np.asarray(normal.coupling)  # W_iᵀ (n_obs + 1, 3, m)
    columns = np.asarray(structure.image_columns)
    n_e = point_rows.shape[0]
    coupled = np.einsum("ocm,omd->odc", coupling, x_r[columns])  # (n_obs + 1, d, 3)
    per_point = np.zeros((n_e + 1, null.shape[1], 3))
    np.add.at(per_point, np.asarray(structure.image_point), coupled)
    x_e = -np.einsum("pij,pdj->pdi", np.asarray(point_inverse), per_point[:n_e])
    basis = np.zeros((null.shape[1], n_free))
    basis[:, reduced_rows[free]] = null.T
    point_free = point_rows >= 0
    basis[:, point_rows[point_free]] = x_e.transpose(1, 0, 2)[:, point_free]
    return basis
