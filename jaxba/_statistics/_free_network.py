"""Free-network datum: inner constraints over all or chosen object points, at any size.

A free network is rank deficient by a similarity transformation (translation, rotation
and, without distances, scale). The datum is fixed by the inner constraints
Bᵀ (x - x₀) = 0, where the columns of B span the unobservable directions restricted to
the coordinates of the datum points (x₀: the approximations). Which similarity motions
are unobservable is found without a Jacobian matrix: each of the seven motions is pushed
through the residuals (a Jacobian-vector product) and compared with how far it moves the
unknowns in the observations' own scale (the whitened Jacobian's column norms).

The constraints are an observation group (`InnerConstraints`) whose residuals vanish at
the solution: the redundancy counts them as constraints, r = n - u + d, and on the dense
backend `jaxba.precision` returns the inner-constraint cofactor, the top-left block of
[[N, B], [Bᵀ, 0]]⁻¹. Both backends solve in a minimal datum (below) rather than with the
constraints as stiff rows, on which Levenberg-Marquardt crawls on weak blocks.

The Schur backend cannot hold a row that couples every point (`holds_inner_constraints`).
It solves the network with a minimal datum instead (`minimal_constraints`: d unknowns held,
chosen from the geometry as a dependent relative orientation: one well-observed image's EOPs
and a base),
moves the solution by the similarity that satisfies the inner constraints
(`to_inner_datum`: the residuals are invariant, so this is the inner-constraint solution)
and carries its cofactors over by Baarda's S-transformation (`free_network_precision`):
Q_i = S Q_m Sᵀ, S = I - G (C G)⁻¹ C, G the null space at the solution, C the constraints.
Gauge-invariant quantities (residuals, σ̂0, redundancy numbers) need no transformation.

This is statistics, not a backend's linear algebra: which datum a free network is reported in
is a choice about the result (the similarity that moves the solution, the S-transformation of
its cofactors), made from what any backend forms in the minimal datum (`cofactors`,
`normal_solve`, `leverages`).
"""


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from .._problem._bundle import BundleProblem, free_indices
from .._problem._inner_constraints import InnerConstraints
from .._problem._linearisation import column_norms
from .._problem._parameters import Parameters, flatten, positions_of, unflatten
from .._solvers._backend import Backend
from .._solvers._compiled import solver_jit
from .._solvers._schur._descent import Schur
from ._covariance import (
    Precision,
    SchurCovariance,
    precision_from_blocks,
    precision_from_cofactors,
    redundancy_numbers,
)
from ._datum import DatumError, network_centre, similarity_directions, similarity_transform

STIFFNESS = 100.0
# A similarity motion is unobservable when the observations see less than this fraction
# of it (‖J b‖ / ‖diag(column norms) b‖): rounding gives ~1e-13, the weakest observed
# motion of a real network (scale from one scale bar in 180k image observations) ~1e-2.
UNOBSERVABLE_RTOL = 1e-7
NEWTON_STEPS = 8
# A candidate of the minimal datum fixes a further motion when its pivot is above this
# fraction of the first (the motions' columns in object units and radians).
RANK_RTOL = 1e-6


def constraint_null_space(group: InnerConstraints, params: Parameters, free: Parameters
                          ) -> Float[np.ndarray, "d n_all"]:
    """The unobservable directions of the inner constraints `group` at `params` (rows,
    `flatten` positions), 0 on the fixed unknowns of `free`."""
    motions = similarity_directions(params, group.centre, pose=group.pose)
    return np.asarray(group.similarity).T @ motions * flatten(free)


@eqx.filter_jit
def _residual_changes(problem: BundleProblem, moves: Array) -> Array:
    """J m for every row m of `moves` (k, n_all): how the whitened residuals change."""
    flat, unravel = ravel_pytree(problem.initial)

    def whitened(x):
        return jnp.concatenate([jnp.ravel(e) for e in problem.whitened(unravel(x))])

    return jax.vmap(lambda move: jax.jvp(whitened, (flat,), (move,))[1])(moves)


def _unobservable_similarity(
    problem: BundleProblem, motions: np.ndarray, norms: np.ndarray
) -> Float[np.ndarray, "7 d"]:
    """The similarity motions (coefficients of the rows of `motions`, (7, n_all)) the
    observations do not see: the generalised eigenvectors of (J B)ᵀ(J B) against
    (D B)ᵀ(D B) (D: column norms `norms` of the free unknowns) whose eigenvalue is below
    `UNOBSERVABLE_RTOL`²."""
    import scipy.linalg  # on first use: its import (0.2-0.4 s) is not every run's

    index = free_indices(problem)
    moves = np.zeros_like(motions)
    moves[:, index] = motions[:, index]
    seen = np.asarray(_residual_changes(problem, jnp.asarray(moves)))
    extent = motions[:, index] * norms
    moving = np.flatnonzero(np.linalg.norm(extent, axis=1) > 0)
    scale = 1.0 / np.linalg.norm(extent[moving], axis=1)
    seen, extent = seen[moving] * scale[:, None], extent[moving] * scale[:, None]
    values, vectors = scipy.linalg.eigh(seen @ seen.T, extent @ extent.T)
    unobservable = vectors[:, values < UNOBSERVABLE_RTOL**2] * scale[:, None]
    coefficients = np.zeros((7, unobservable.shape[1]))
    coefficients[moving] = unobservable
    return coefficients


def inner_constraints(
    problem: BundleProblem, *, datum_points: list[int] | None = None
) -> BundleProblem:
    """The problem with inner constraints over `datum_points` (point rows; None: all).

    The unobservable similarity motions are found at the approximations (module
    docstring); if there are none, `DatumError`. A defect of any other kind is named by
    the datum check before the solve. The datum points must fix the defect (`DatumError`
    otherwise).
    """
    norms = np.asarray(column_norms(problem, problem.initial))
    centre = network_centre(problem)
    motions = similarity_directions(problem.initial, centre, pose=problem.pose)
    similarity = _unobservable_similarity(problem, motions, norms)
    if similarity.shape[1] == 0:
        raise DatumError("the network has no datum defect: it needs no inner constraints")
    index = free_indices(problem)
    null = similarity.T @ motions[:, index]
    positions = np.asarray(positions_of(problem.initial)
                           .points)
    rows = np.arange(positions.shape[0]) if datum_points is None else np.asarray(datum_points)
    selected = np.zeros(flatten(problem.initial).size, dtype=bool)
    selected[positions[rows].ravel()] = True
    directions = np.zeros((null.shape[0], selected.size))
    directions[:, index] = null
    directions[:, ~selected] = 0.0
    if np.linalg.matrix_rank(directions[:, index] @ null.T) < null.shape[0]:
        raise DatumError("the datum points do not fix the network's datum defect: choose "
                         "points with free coordinates spread over the network")
    # Any scaling of the rows gives the same constraints (their residuals vanish at the
    # solution); in Jacobi-scaled unknowns the rows get norm STIFFNESS, comparable to the
    # observations' columns in the bordered normal matrix. (As stiff observations in the
    # solve they left Levenberg-Marquardt crawling: the solvers hold a minimal datum.)
    weight = np.linalg.norm(directions[:, index] / norms, axis=1) / STIFFNESS
    group = InnerConstraints(
        directions=jnp.asarray(directions / weight[:, None]),
        reference=jnp.asarray(flatten(problem.initial)),
        stddev=jnp.ones((null.shape[0], 1)),
        similarity=jnp.asarray(similarity),
        centre=jnp.asarray(centre),
        pose=problem.pose,
    )
    return eqx.tree_at(lambda p: p.groups, problem, (*problem.groups, group))


def inner_constraint_group(problem: BundleProblem) -> InnerConstraints | None:
    """The free network's inner constraints (the last group, the one whose rows are
    constraints), or None for a bundle with a datum."""
    found = [k for k, group in enumerate(problem.groups) if group.constraint]
    if not found:
        return None
    if found != [len(problem.groups) - 1]:
        raise ValueError("a free network has one group of inner constraints, the last")
    return problem.groups[-1]


def minimal_constraints(problem: BundleProblem, params: Parameters) -> BundleProblem:
    """The free network `problem` with a minimal datum instead of its inner constraints:
    the constraints dropped and the d unknowns `minimal_datum` chooses (at the
    approximations: the same ones for any `params`, so one `bundle_structure` serves the
    solve and the statistics) held at their values in `params`. Its solutions are the free
    network's up to the similarity `to_inner_datum` removes."""
    group = inner_constraint_group(problem)
    free = flatten(problem.free).copy()
    null = constraint_null_space(group, problem.initial, problem.free)
    free[minimal_datum(problem, null)] = False
    return eqx.tree_at(
        lambda p: (p.initial, p.free, p.groups), problem,
        (params, jax.tree.map(jnp.asarray, unflatten(problem.free, free)), problem.groups[:-1]))


def minimal_datum(problem: BundleProblem, null: Float[np.ndarray, "d n_all"]) -> np.ndarray:
    """d flat positions (`flatten` order) of free unknowns that fix the unobservable motions
    `null` (rows), chosen from the geometry as a dependent relative orientation: the EOPs
    of the image with the most observations, then the EOPs of the other images the
    remaining motions move the most (pivoted QR: the longest base), then, were any motion
    left, point coordinates. Not the points' coordinates first: those a similarity moves
    the most are the far, weakly intersected points, and a datum there leaves the rest of
    the network poorly determined (Levenberg-Marquardt crawls)."""
    import scipy.linalg  # on first use: its import (0.2-0.4 s) is not every run's

    positions = unflatten(problem.initial, np.arange(null.shape[1]))
    images = np.asarray(positions.images)
    counts = np.zeros(images.shape[0])
    for group in problem.groups:
        for _, block, rows in group.row_references():
            if block == "images":
                np.add.at(counts, np.asarray(rows), 1)
    best = int(np.argmax(counts))
    stages = (images[best], np.delete(images, best, axis=0).ravel(),
              np.asarray(positions.points).ravel())
    chosen: list[int] = []
    for candidates in stages:
        remaining = scipy.linalg.null_space(null[:, chosen].T)  # motions still free (d, k)
        candidates = candidates[np.any(null[:, candidates] != 0, axis=0)]
        if remaining.shape[1] == 0 or candidates.size == 0:
            continue
        moves = remaining.T @ null[:, candidates]
        _, r, pivots = scipy.linalg.qr(moves, mode="economic", pivoting=True)
        diagonal = np.abs(np.diag(r))
        rank = int(np.sum(diagonal > RANK_RTOL * diagonal[0])) if diagonal.size else 0
        chosen += candidates[pivots[:rank]].tolist()
    if len(chosen) != null.shape[0]:
        raise DatumError("no free unknowns fix the free network's datum defect")
    return np.asarray(chosen)


@solver_jit  # top level only: the move of an adjusted solution
def _inner_datum(group: InnerConstraints, refraction, params: Parameters) -> Parameters:
    def moved(phi):
        return similarity_transform(params, group.similarity @ phi, group.centre,
                                    pose=group.pose)

    def violation(phi):
        return group.residuals(moved(phi), refraction)[:, 0]

    def newton(_, phi):
        return phi - jnp.linalg.solve(jax.jacfwd(violation)(phi), violation(phi))

    phi = jax.lax.fori_loop(0, NEWTON_STEPS, newton, jnp.zeros(group.similarity.shape[1]))
    return moved(phi)


def to_inner_datum(problem: BundleProblem, params: Parameters) -> Parameters:
    """A solution `params` of the free network in any datum, moved by the unobservable
    similarity that makes it satisfy the inner constraints (Newton on the d similarity
    parameters, `NEWTON_STEPS`): the same residuals, the inner-constraint datum."""
    return _inner_datum(inner_constraint_group(problem), problem.refraction, params)


def free_network_precision(
    problem: BundleProblem,
    params: Parameters,
    *,
    sigma0: float = 1.0,
    backend: Backend | None = None,
) -> Precision:
    """The `Precision` of a free network at its inner-constraint solution `params`, in the
    inner-constraint datum, for a backend that forms its cofactors in blocks (one that
    cannot hold the inner constraints: default `Schur`): the minimal-datum covariance Q_m
    carried over by the S-transformation Q_i = S Q_m Sᵀ (module docstring) for the blocks
    a `SchurCovariance` holds. With P = (C G)⁻¹ C and K = Q_m Pᵀ (d normal-equation solves),
    a block is Q_i[a, b] = Q_m[a, b] - G_a K_bᵀ - K_a G_bᵀ + G_a (P K) G_bᵀ. `backend`: made
    ready for the minimal-datum problem (the same for any `params`), if it is already."""
    group = inner_constraint_group(problem)
    minimal = minimal_constraints(problem, params)
    backend = (Schur() if backend is None else backend).ready(minimal)
    # With the redundancy numbers (gauge invariant: from the minimal datum) in one program.
    base = precision_from_cofactors(minimal, params, backend.cofactors(minimal, params),
                                    sigma0=sigma0)
    variance_factor = base.sigma0_squared / sigma0**2
    null = constraint_null_space(group, params, problem.free)  # G (d, n_all)
    constraint = np.asarray(group.directions)  # C
    projector = np.linalg.solve(constraint @ null.T, constraint)  # P (d, n_all)
    k = variance_factor * backend.normal_solve(minimal, params, projector)
    middle = projector @ k.T  # P K (d, d)

    def transformed(block, g, k_block):  # (..., m, m) and (..., m, d) -> Q_i blocks
        return (block - g @ np.swapaxes(k_block, -1, -2) - k_block @ np.swapaxes(g, -1, -2)
                + g @ middle @ np.swapaxes(g, -1, -2))

    reduced_positions = base.schur.reduced_positions
    reduced = transformed(base.schur.reduced, null[:, reduced_positions].T,
                          k[:, reduced_positions].T)
    point_positions = np.asarray(unflatten(params, np.arange(null.shape[1])).points)
    points = transformed(base.schur.points, np.moveaxis(null[:, point_positions], 0, -1),
                         np.moveaxis(k[:, point_positions], 0, -1))
    redundancy = _with_constraint_rows(problem, params, *base.schur.redundancy)
    return precision_from_blocks(problem, params, base.sigma0_squared, base.redundancy,
                                 SchurCovariance(reduced_positions, reduced, points, redundancy))


def free_network_redundancy_numbers(
    problem: BundleProblem, params: Parameters, *, backend: Backend | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) of a free network's real observations at `params` from the minimal datum
    (gauge invariant; `backend` as `free_network_precision`'s); the inner constraints'
    rows have r = 0."""
    minimal = minimal_constraints(problem, params)
    backend = (Schur() if backend is None else backend).ready(minimal)
    r, e = redundancy_numbers(backend.leverages(minimal, params))
    return _with_constraint_rows(problem, params, r, e)


def _with_constraint_rows(problem, params, r, e) -> tuple[np.ndarray, np.ndarray]:
    """The minimal datum's (r_i, e_i) with the inner constraints' rows appended (r = 0)."""
    group = inner_constraint_group(problem)
    constraint_e = np.ravel(np.asarray(group.residuals(params, problem.refraction)))
    return np.concatenate([r, np.zeros(constraint_e.size)]), np.concatenate([e, constraint_e])

