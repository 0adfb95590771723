"""A bundle-adjustment problem: parameter blocks, their fixing, and observation groups."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Bool, Float, Int

from .._models._cameras import AbstractRefraction, NoRefraction
from .._models._robust import RobustLoss
from ._observations import AbstractObservationGroup, ImagePoints
from ._parameters import Parameters, flatten, where_free


class BundleProblem(eqx.Module):
    """Everything the solver needs; pure arrays and static structure, no file names.

    - `initial`: approximations of all unknowns and the values of the fixed ones;
    - `free`: Parameters of booleans, True where the scalar is estimated (free or
      weighted: weighted ones are free with a prior observation in `groups`);
    - `groups`: the observation groups (image points per camera, control, distances...);
    - `refraction`: the atmospheric refraction model (NoRefraction for close range);
    - `robust`: an optional robust loss applied to the image-point groups;
    - `ties`: (dependent, source) pairs of `flatten` positions of camera parameters that
      are one unknown (fy = fx, one lens's distortion shared by two cameras): the
      dependent takes its source's value everywhere (`with_free`, `params_from_free`), is
      False in `free` itself, and the solvers and statistics see the source's column
      only (the Jacobian J·T, T the 0/1 tie map; `tie_source`). No source is a dependent;
    - `gauge`: `flatten` positions of fixed unknowns that only define the datum, a minimal
      one (the 7, or 6 with a scale from distances, similarity parameters: a dependent
      relative orientation). The Schur backend moves them with the damped steps and then
      moves the solution back into this datum by a similarity (a gauge left free converges
      as Ceres on BAL's problems: Dubrovnik-16 in 7 steps instead of 12); () for none.

    `pose` (a property) is the pose model that reads `images` rows; every image group of a
    problem names the same one (checked at construction).
    """

    initial: Parameters
    free: Parameters
    groups: tuple[AbstractObservationGroup, ...]
    refraction: AbstractRefraction = NoRefraction()
    robust: RobustLoss | None = None
    ties: tuple[tuple[int, int], ...] = eqx.field(static=True, default=())
    gauge: tuple[int, ...] = eqx.field(static=True, default=())

    def __check_init__(self):
        _check_ties(self)
        poses = {group.pose for group in self.groups if isinstance(group, ImagePoints)}
        if len(poses) > 1:
            raise ValueError(f"the image groups name different pose models {sorted(poses)}:"
                             " one problem reads its images rows one way")

    @property
    def pose(self) -> str:
        """The pose model (`POSE_MODELS`) of the images rows: its image groups' ("opk"
        without image groups)."""
        poses = [group.pose for group in self.groups if isinstance(group, ImagePoints)]
        return poses[0] if poses else "opk"

    def whitened(self, params: Parameters) -> tuple[Array, ...]:
        """Whitened residuals e = v/σ of every group, masked entries exactly 0."""
        return tuple(
            jnp.where(group.mask(), group.residuals(params, self.refraction), 0.0)
            for group in self.groups
        )

    def residuals(self, params: Parameters) -> tuple[Array, ...]:
        """The residuals the solver minimises: whitened, robustified where a loss is set."""
        whitened = self.whitened(params)
        if self.robust is None:
            return whitened
        return tuple(
            self.robust(e) if isinstance(group, ImagePoints) else e
            for group, e in zip(self.groups, whitened)
        )

    def with_free(self, values: Parameters) -> Parameters:
        """`values` on the free entries, the fixed values of `initial` elsewhere, tied
        entries at their sources' values."""
        return tie(where_free(self.free, values, self.initial), self.ties)

    def n_observations(self) -> int:
        """Number of real scalar observations over all groups."""
        return int(observation_counts(self.groups))

    def n_unknowns(self) -> int:
        """Number of free (estimated) scalars."""
        return int(free_mask(self.free).sum())


def observed_minus_computed(problem: BundleProblem, whitened) -> tuple[np.ndarray, ...]:
    """Residuals v = observed - computed in each group's units from its whitened e = v/σ
    (masked entries 0), as NumPy arrays of the groups' shapes."""
    return tuple(
        np.asarray(e) * np.where(_host_mask(g), np.asarray(g.stddev), 0.0)
        for e, g in zip(whitened, problem.groups)
    )


def _check_ties(problem: BundleProblem) -> None:
    """`ValueError` unless the ties join distinct camera positions, each dependent once,
    no source a dependent, and (where `free` is concrete) no dependent free."""
    if not problem.ties:
        return
    n_cameras = sum(int(np.size(block)) for block in problem.initial.cameras.values())
    dependent, source = (np.array(column) for column in zip(*problem.ties))
    positions = np.concatenate([dependent, source])
    if np.any((positions < 0) | (positions >= n_cameras)):
        raise ValueError("ties join camera parameters only: a position is not a camera's")
    if np.unique(dependent).size != dependent.size or np.any(dependent == source):
        raise ValueError("a tied parameter has one source, other than itself")
    if np.isin(source, dependent).any():
        raise ValueError("a tie's source is itself tied: tie to the chain's first source")
    leaves = jax.tree.leaves(problem.free.cameras)
    if not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        free = np.concatenate([np.ravel(np.asarray(leaf)) for leaf in leaves])
        if free[dependent].any():
            raise ValueError("a tied parameter is free itself: only its source is estimated")


def tie(params: Parameters, ties: tuple[tuple[int, int], ...]) -> Parameters:
    """`params` with every tied camera entry (`BundleProblem.ties`) set to its source's
    value (a gather: derivatives w.r.t. a source collect its dependents'). Traceable."""
    if not ties:
        return params
    dependent, source = (np.array(column) for column in zip(*ties))
    models = sorted(params.cameras)
    flat = jnp.concatenate([jnp.ravel(params.cameras[m]) for m in models])
    flat = flat.at[dependent].set(flat[source])
    cameras, start = {}, 0
    for model in models:
        shape = jnp.shape(params.cameras[model])
        size = int(np.prod(shape))
        cameras[model] = flat[start:start + size].reshape(shape)
        start += size
    return eqx.tree_at(lambda p: p.cameras, params, cameras)


def tie_source(problem: BundleProblem) -> np.ndarray:
    """(n_all,) for every `flatten` position the position of the unknown it is: its tie's
    source for a tied entry, itself otherwise."""
    source = np.arange(flatten(problem.initial).size)
    for dependent, origin in problem.ties:
        source[dependent] = origin
    return source


def free_indices(problem: BundleProblem) -> np.ndarray:
    """Positions of the free scalars in `flatten(Parameters)` order."""
    return np.flatnonzero(free_mask(problem.free))


def free_mask(free: Parameters, batch: tuple[int, ...] = ()) -> Bool[np.ndarray, "*batch n_all"]:
    """`free` in `flatten` order: (n_all,) of one problem's, (*batch, n_all) of problems
    stacked along `batch` leading axes of every leaf (a padded batch's)."""
    return np.concatenate([np.reshape(np.asarray(leaf), (*batch, -1))
                           for leaf in jax.tree.leaves(free)], axis=-1)


def free_positions(mask: Bool[np.ndarray, "n n_all"], length: int,
                   fill: int) -> Int[np.ndarray, "n length"]:
    """Per row of `mask` (`free_mask` of stacked problems) the positions of its free
    scalars in order, padded with `fill` to `length`."""
    out = np.full((len(mask), length), fill)
    for row, free in zip(out, mask):
        index = np.flatnonzero(free)
        row[: index.size] = index
    return out


def observation_counts(groups: tuple[AbstractObservationGroup, ...],
                       batch: tuple[int, ...] = ()) -> Int[np.ndarray, "*batch"]:
    """Real scalar observations (σ finite) over `groups`: () of one problem's, (*batch,) of
    problems stacked along `batch` leading axes (a padded batch's)."""
    return sum((np.reshape(_host_mask(group), (*batch, -1)).sum(-1) for group in groups),
               np.zeros(batch, int))


def _host_mask(group: AbstractObservationGroup) -> Bool[np.ndarray, "n k"]:
    """`group.mask()` outside a program (σ finite), without the bound method an equinox
    Module makes on every method read (~0.1 ms; the host's bookkeeping runs once per
    project of a batch)."""
    return np.isfinite(np.asarray(group.stddev))


def observation_mask(problem: BundleProblem) -> Bool[np.ndarray, " n_residuals"]:
    """Flat mask of real observations, in the order of the raveled residuals."""
    return np.concatenate([np.ravel(_host_mask(group)) for group in problem.groups])


def params_from_free(
    problem: BundleProblem, x_free: Float[Array, " n_free"], index: Array
) -> Parameters:
    """The Parameters with the free scalars (positions `index` in `flatten` order) set to
    `x_free`, tied ones to their sources' and all others at their values in
    `problem.initial`. Traceable."""
    flat, unravel = ravel_pytree(problem.initial)
    return tie(unravel(flat.at[index].set(x_free)), problem.ties)


def params_from_scaled(
    problem: BundleProblem, z: Float[Array, " n_free"], index: Array, scale: Float[Array, " n_free"]
) -> Parameters:
    """The Parameters at the solvers' Jacobi-scaled unknowns z: x_free = x_free,0 + scale ⊙ z
    (x_free,0 from `problem.initial`), all other scalars as in `problem.initial`."""
    x_free = ravel_pytree(problem.initial)[0][index]
    return params_from_free(problem, x_free + scale * z, index)
