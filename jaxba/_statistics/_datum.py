"""Refuse rank-deficient bundles before solving, naming what cannot be determined: from the
rank of the normal equations that a backend finds (`Backend.rank`: the dense Jacobian's SVD,
or the Schur split's null space)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._models._cameras._names import INSEPARABLE_PARAMETERS, lens_model
from .._models._poses import POSE_MODELS
from .._models._rotation import rodrigues_to_matrix
from .._problem._bundle import BundleProblem, free_indices, tie_source
from .._problem._parameters import Parameters, flatten, parameter_labels, positions_of, unflatten
from .._programs import stored
from .._solvers._backend import Rank
from .._solvers._dense import Dense
from .._solvers._dense_statistics import SINGULAR_VALUE_RTOL
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import BundleStructure
from ._causes import intersection_cause, nonfinite_observations

SIMILARITY_NAMES = (
    "translation in X", "translation in Y", "translation in Z",
    "rotation about X", "rotation about Y", "rotation about Z", "scale",
)


class DatumError(ValueError):
    """The observations and constraints do not determine all unknowns."""


def similarity_transform(params: Parameters, theta, centre, *, pose: str = "opk") -> Parameters:
    """Apply X -> centre + (1 + s) R(a) (X - centre) + t to all points and stations.

    theta = (t, a, s) (7,): translation (object units), Rodrigues rotation vector (rad),
    scale change; camera attitudes turn with the network: M -> M R(a)ᵀ. IOPs stay; rig
    cameras' relative poses (`Parameters.mounts`) keep their rotations, their perspective
    centres in the rig frame scale by 1 + s, and so does a board's warp. `pose`:
    the pose model of the images rows (`BundleProblem.pose`), which converts them to and
    from M and X0.
    """
    t, a, s = theta[:3], theta[3:6], theta[6]
    rotation = rodrigues_to_matrix(a)
    model = POSE_MODELS[pose]

    def move(xyz):
        return centre + (1 + s) * (xyz - centre) @ rotation.T + t

    poses = jax.vmap(model.from_parameters)(params.images)
    stations = move(jax.vmap(model.station)(poses))
    turned = jax.vmap(model.rotation)(poses) @ rotation.T

    def pose(m, station):
        return model.from_rotation(m, station).parameters()

    images = jax.vmap(pose)(turned, stations)
    mounts = params.mounts
    if mounts is not None:  # a rig scales with the network; its cameras turn with it
        relative = jax.vmap(model.from_parameters)(mounts)
        mounts = jax.vmap(pose)(jax.vmap(model.rotation)(relative),
                                (1 + s) * jax.vmap(model.station)(relative))
    warp = None if params.warp is None else (1 + s) * params.warp  # a length: scales
    return Parameters(params.cameras, images, move(params.points), mounts, warp)


def similarity_directions(params: Parameters, centre, *, pose: str = "opk") -> np.ndarray:
    """(7, n_all): how every unknown (`flatten` order) changes under each similarity
    direction of `similarity_transform` about `centre` (3,), at `params` (images rows of
    the pose model `pose`)."""
    return np.asarray(_similarity_jacobian(params, jnp.asarray(centre), pose)).T


@eqx.filter_jit
def _similarity_jacobian(params: Parameters, centre, pose: str):
    """(n_all, 7) Jacobian of `similarity_transform` at θ = 0, as one program (run op by
    op it compiled ~100 small programs)."""

    def flat(theta):
        moved = similarity_transform(params, theta, centre, pose=pose)
        return jnp.concatenate([jnp.ravel(leaf) for leaf in jax.tree.leaves(moved)])

    return jax.jacfwd(flat)(jnp.zeros(7))


def network_centre(problem: BundleProblem) -> np.ndarray:
    """(3,) the centroid of the object points' approximations: the similarity's fixed point."""
    return np.mean(np.asarray(problem.initial.points), axis=0)


def _describe_similarity(null_basis, directions, index) -> str | None:
    """Name the similarity components spanned by the null space, or None if it is not one.

    Null vectors move free unknowns only: extended with zeros on the fixed ones, a fit
    by similarity directions that would move a fixed unknown leaves a residual there.
    """
    n_total = directions.shape[1]
    names = set()
    for vector in null_basis:
        full = np.zeros(n_total)
        full[index] = vector
        norms = np.linalg.norm(directions, axis=1)
        unit = directions / norms[:, None]
        theta, *_ = np.linalg.lstsq(unit.T, full, rcond=None)
        if np.linalg.norm(unit.T @ theta - full) > 1e-3 * np.linalg.norm(full):
            return None
        significant = np.abs(theta) >= 0.2 * np.max(np.abs(theta))
        names.update(SIMILARITY_NAMES[k] for k in np.flatnonzero(significant))
    return ", ".join(name for name in SIMILARITY_NAMES if name in names)


def describe_defect(problem, null_basis, index, labels, *, column_norms) -> None:
    """Raise `DatumError` naming the defect spanned by `null_basis` (d, n_free).

    `column_norms` (n_free,): the norms of the whitened Jacobian's columns.
    """
    rank_defect = null_basis.shape[0]
    directions = similarity_directions(problem.initial, network_centre(problem), pose=problem.pose)
    similarity = _describe_similarity(null_basis, directions, index)
    if similarity is not None:
        hint = (
            " The scale is not defined: add distance observations or control coordinates "
            "that fix the scale."
            if "scale" in similarity
            else " Fix or weight more control coordinates, or choose datum = \"free\"."
        )
        raise DatumError(
            f"datum defect (rank deficiency {rank_defect}): the observations do not "
            f"determine a similarity transformation of the network involving {similarity}."
            + hint
        )
    # Rank the unknowns in Jacobi-scaled units (as the observations see them).
    scaled = null_basis * column_norms
    magnitude = np.max(np.abs(scaled / np.linalg.norm(scaled, axis=1, keepdims=True)), axis=0)
    significant = magnitude > 0.1 * magnitude.max()
    # Not a datum matter where the geometry says why: points that no two rays intersect.
    cause = intersection_cause(problem, labels, _involved_points(problem, index, significant))
    if cause is not None:
        raise DatumError(f"rank deficiency {rank_defect}: {cause}")
    involved = np.argsort(-magnitude)[: min(10, int(np.sum(significant)))]
    names = ", ".join(labels[index[k]] for k in involved)
    raise DatumError(
        f"rank deficiency {rank_defect}: these unknowns can change together without "
        f"changing any observation: {names}"
    )


def _involved_points(problem: BundleProblem, index, significant) -> np.ndarray:
    """(n_points,) True for the points with a coordinate among the `significant` free
    unknowns (positions `index`) of a null space."""
    marked = np.zeros(flatten(problem.initial).size, bool)
    marked[index[significant]] = True
    return unflatten(problem.initial, marked).points.any(axis=1)


def check_datum(
    problem: BundleProblem, *, labels: list[str] | None = None,
    rtol: float = SINGULAR_VALUE_RTOL
) -> None:
    """Raise `DatumError` if the bundle is rank deficient at its approximations.

    The message names the defect: a similarity transformation of the network (which of
    translation, rotation, scale) or the unknowns that can change together without
    changing any observation. From the dense Jacobian (`Dense.rank`, `rtol`: its threshold
    on the singular values); `check_rank` for another backend's rank.
    """
    check_rank(problem, Dense().rank(problem, rtol=rtol), labels=labels)


def check_datum_schur(
    problem: BundleProblem,
    *,
    labels: list[str] | None = None,
    structure: BundleStructure | None = None,
) -> None:
    """`check_datum` without a dense Jacobian: from the Schur split (`Schur.rank`;
    `structure`: the problem's `bundle_structure`, if already built)."""
    backend = Schur(structure).ready(problem)
    check_rank(problem, backend.rank(problem), labels=labels)


def check_rank(problem: BundleProblem, rank: Rank, *, labels: list[str] | None = None) -> None:
    """Raise `DatumError` naming what the observations cannot determine, from the rank of
    the normal equations at the approximations (any backend's `rank`): the checks before any
    decomposition (`check_columns`), then the defect its null space spans
    (`describe_defect`)."""
    labels = labels or parameter_labels(problem.initial)
    check_columns(problem, rank.finite, rank.column_norms, labels)
    if rank.null_space is not None:
        describe_defect(problem, rank.null_space, free_indices(problem), labels,
                        column_norms=rank.column_norms)


# `BundleProblem.whitened` as one compiled program (op by op it compiled ~60 small ones).
whitened_residuals = stored("whitened_residuals")(eqx.filter_jit(BundleProblem.whitened))


def nonfinite_start_error(problem: BundleProblem, labels: list[str]) -> DatumError | None:
    """A `DatumError` naming the observations whose residuals are not finite at the
    approximations (None if all are finite)."""
    observations = nonfinite_observations(problem, whitened_residuals(problem, problem.initial),
                                          labels)
    if observations is None:
        return None
    return DatumError(
        f"the residuals are not finite at the approximations of {observations} (a point at"
        " or beside an image's projection centre?): check these approximations")


def check_columns(
    problem: BundleProblem, finite: np.ndarray, column_norms: np.ndarray, labels: list[str]
) -> None:
    """The checks before any decomposition: a positive redundancy, no inseparable camera
    parameters free together (`check_separable`), a finite model and an observation for
    every free unknown (`finite`, `column_norms`: (n_free,) per column of
    the whitened Jacobian at the approximations)."""
    check_structure(problem, labels, problem.n_observations(), problem.n_unknowns())
    index = free_indices(problem)
    if not np.all(finite):
        error = nonfinite_start_error(problem, labels)
        if error is not None:
            raise error
        bad = sorted({labels[index[k]] for k in np.flatnonzero(~finite)})
        raise DatumError(f"the model is not finite at the approximations of: {', '.join(bad[:8])}")
    unobserved = np.flatnonzero(column_norms == 0)
    if unobserved.size:
        names = ", ".join(labels[index[k]] for k in unobserved[:8])
        it, acts = ("it", "it acts") if unobserved.size == 1 else ("them", "they act")
        raise DatumError(
            f"no observation depends on {names} at the approximations (not a datum matter:"
            " an unknown with no effect there, such as P3 while P1 = P2 = 0): fix"
            f" {it}, or start from approximations where {acts}")


def check_structure(problem: BundleProblem, labels: list[str], n_observations: int,
                    n_unknowns: int) -> None:
    """`check_columns`' checks that need no Jacobian: a positive redundancy (`n_observations`
    real observations, `n_unknowns` free unknowns: `problem`'s, counted by the caller) and
    `check_separable`."""
    if n_observations <= n_unknowns:
        raise DatumError(
            f"{n_observations} observations cannot determine {n_unknowns} unknowns "
            "(redundancy must be positive)"
        )
    check_separable(problem, labels)


def check_separable(problem: BundleProblem, labels: list[str]) -> None:
    """Refuse a camera whose model's inseparable pair (`INSEPARABLE_PARAMETERS`, e.g. SMAC's
    K0 and c) is free with no prior on either: the observations cannot tell them apart (a
    solve from there collapses, e.g. to c = 0, K0 = 1)."""
    if not any(INSEPARABLE_PARAMETERS.get(lens_model(model)) for model in problem.free.cameras):
        return
    # A tied parameter is as free as its source (`BundleProblem.ties`).
    estimated = unflatten(problem.free, flatten(problem.free)[tie_source(problem)])
    positions = positions_of(problem.initial)
    priors = np.concatenate([np.zeros(0, int)] + [  # the unknowns with a prior
        group.prior_positions(positions) for group in problem.groups])
    for model, free in estimated.cameras.items():
        pairs = INSEPARABLE_PARAMETERS.get(lens_model(model), ())
        if not pairs:
            continue
        free = np.asarray(free, dtype=bool)
        prior = np.isin(np.asarray(positions.cameras[model]), priors)
        names = CAMERA_MODELS[model].parameter_names
        for a, b, reason in pairs:
            ia, ib = names.index(a), names.index(b)
            both = free[:, ia] & free[:, ib] & ~prior[:, ia] & ~prior[:, ib]
            for row in np.flatnonzero(both):
                camera = labels[int(np.asarray(positions.cameras[model])[row, ia])]
                camera = camera.removesuffix(f" {a}")
                raise DatumError(
                    f"datum defect: {a} and {b} of {camera} are not separable ({reason}):"
                    f" fix one of them, or give it a prior σ")

