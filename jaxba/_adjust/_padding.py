"""Bundles of one kind padded to a common shape and stacked, so that one compiled program
solves them all (`jax.vmap`); and the padding taken off the results.

Padding changes no result:

- observation rows added to a group repeat the group's first row with σ = inf, so they are
  whitened to exactly 0 and counted nowhere (`AbstractObservationGroup.mask`);
- camera, image and point rows added to a block copy its first row and are fixed
  (free = False); no real observation references them;
- one extra point row is always added; the free-index vector of every problem is padded to
  the longest one with the flat position of that spare point's X. The padded entries of
  the solver vector therefore move an unreferenced coordinate: their Jacobian columns are
  exactly 0, the damped Gauss-Newton step decouples them (JᵀJ + λI is block diagonal) and
  they stay 0. The statistics drop them (their block of N is replaced by I), and the
  redundancy r = n - u counts real observations and unknowns only.
"""

import dataclasses
import hashlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from .._gc import paused_gc
from .._problem._bundle import (
    BundleProblem,
    free_indices,
    free_mask,
    free_positions,
    observation_counts,
)
from .._problem._linearisation import (
    LinearisationPlan,
    _local_positions,
    linearisation_plan,
    live_slots,
    pad_plans,
)
from .._problem._observations import AbstractObservationGroup
from .._problem._parameters import Parameters, positions_of, unflatten


@dataclasses.dataclass(frozen=True)
class PaddedBatch:
    """Problems padded to one shape and stacked along a leading batch axis.

    - `problem`: a BundleProblem whose every array leaf has a leading axis of `n_batch`;
    - `plan`: the stacked `LinearisationPlan`s of the padded problems; `plan.free_index`
      (n_batch, n_free_max) the free positions in `flatten` order, padded;
    - `problems`: the original (unpadded) problems;
    - `n_free`, `n_observations`: per problem, real unknowns and observations;
    - `host`: `problem` with NumPy leaves (the host's bookkeeping reads its σ).
    """

    problem: BundleProblem
    plan: LinearisationPlan
    problems: tuple[BundleProblem, ...]
    n_free: np.ndarray
    n_observations: np.ndarray
    host: BundleProblem

    @property
    def n_batch(self) -> int:
        return len(self.problems)

    @property
    def free_index(self) -> Int[Array, "n_batch n_free_max"]:
        return self.plan.free_index


def batch_kind(problem: BundleProblem) -> tuple:
    """What must agree between problems for them to share a padded shape (one kind)."""
    groups = tuple(
        (type(g).__name__, getattr(g, "model", None), getattr(g, "block", None),
         tuple(np.shape(g.stddev)[1:]), getattr(g, "mount", None) is None)
        for g in problem.groups
    )
    cameras = tuple((m, np.shape(b)[1]) for m, b in sorted(problem.initial.cameras.items()))
    return (groups, cameras, problem.initial.mounts is None, problem.refraction, problem.robust,
            _tied_entries(problem))


def _tied_entries(problem: BundleProblem) -> tuple:
    """`problem.ties` as ((model, camera row, parameter), source's) pairs: the same whatever
    rows padding adds (a padded batch holds one set of ties)."""
    if not problem.ties:
        return ()
    entry = {}
    for model, block in positions_of(problem.initial).cameras.items():
        for (row, column), position in np.ndenumerate(np.asarray(block)):
            entry[int(position)] = (model, row, column)
    return tuple((entry[dependent], entry[source]) for dependent, source in problem.ties)


def _stack_rows(leaves, n: int, fill=None) -> np.ndarray:
    """Arrays padded along their leading axis to `n` rows (repeating each one's row 0, or
    with `fill`) and stacked: (len(leaves), n, ...)."""
    leaves = [np.asarray(leaf) for leaf in leaves]
    out = np.empty((len(leaves), n, *leaves[0].shape[1:]), np.result_type(*leaves))
    for k, leaf in enumerate(leaves):
        out[k, : len(leaf)] = leaf
        out[k, len(leaf):] = leaf[:1] if fill is None else fill
    return out


def _stack_groups(groups: list[AbstractObservationGroup], n: int) -> AbstractObservationGroup:
    """One group of each problem padded to `n` rows and stacked: rows repeated from row 0,
    σ = inf on the added rows; the first one's static fields (its name)."""
    first = groups[0]
    names = [field.name for field in dataclasses.fields(first)
             if not field.metadata.get("static", False) and getattr(first, field.name) is not None]
    stacked = [_stack_rows([getattr(g, name) for g in groups], n,
                           np.inf if name == "stddev" else None) for name in names]
    return eqx.tree_at(lambda g: [getattr(g, name) for name in names], first, stacked)


def _padded_ties(problem: BundleProblem, shapes: Parameters) -> tuple:
    """`problem.ties` as positions of the padded Parameters shaped like `shapes`."""
    padded = positions_of(shapes).cameras
    return tuple((int(padded[model][row, column]), int(padded[source][at, of]))
                 for (model, row, column), (source, at, of) in _tied_entries(problem))


@dataclasses.dataclass(frozen=True)
class BatchShape:
    """The padded shape of a batch, all that its compiled programs depend on: rows per
    camera model, images, points (the spare one included), rows per observation group, the
    length of the free-index vector and, per group of the linearisation plan, its live
    slots and (keys, rows per key) (None for a group that is not row-local); `mounts` the
    rows of the mounts block (None: no rigs)."""

    cameras: dict[str, int]
    images: int
    points: int
    rows: tuple[int, ...]
    free: int
    live: tuple[tuple[int, ...] | None, ...] | None = None
    keys: tuple[tuple[int, int] | None, ...] | None = None
    mounts: int | None = None


def _block_shape(problems: tuple[BundleProblem, ...], free: int | None = None) -> BatchShape:
    """The largest of every block and group, one spare point row; no plan yet. `free`: the
    length of the free-index vector, default the most free unknowns of any problem."""
    return BatchShape(
        cameras={m: max(p.initial.cameras[m].shape[0] for p in problems)
                 for m in problems[0].initial.cameras},
        images=max(p.initial.images.shape[0] for p in problems),
        points=max(p.initial.points.shape[0] for p in problems) + 1,
        rows=tuple(max(np.shape(p.groups[g].stddev)[0] for p in problems)
                   for g in range(len(problems[0].groups))),
        free=max(p.n_unknowns() for p in problems) if free is None else free,
        mounts=None if problems[0].initial.mounts is None
        else max(p.initial.mounts.shape[0] for p in problems),
    )


def _pad_each(problems, shape: BatchShape
              ) -> tuple[BundleProblem, np.ndarray, np.ndarray, list, list]:
    """Every problem padded to `shape`'s blocks and stacked (a BundleProblem of NumPy leaves
    with a leading batch axis), the (n,) counts of free unknowns, the (n, shape.free) padded
    free indices, the live slots of
    the plans (`shape.live`, or the union over these problems) and the padded problems'
    `_local_positions` where the live slots needed them (else Nones)."""
    shapes = Parameters(
        cameras={m: np.zeros((n, problems[0].initial.cameras[m].shape[1]))
                 for m, n in shape.cameras.items()},
        images=np.zeros((shape.images, 6)),
        points=np.zeros((shape.points, 3)),
        mounts=None if shape.mounts is None else np.zeros((shape.mounts, 6)),
    )
    ties = {_padded_ties(problem, shapes) for problem in problems}
    if len(ties) > 1:
        raise ValueError("the problems tie different camera parameters (BundleProblem.ties);"
                         " pad only problems with the same ties")
    first = problems[0]
    stacked = BundleProblem(
        jax.tree.map(lambda like, *leaves: _stack_rows(leaves, len(like)), shapes,
                     *(p.initial for p in problems)),
        jax.tree.map(lambda like, *leaves: _stack_rows(leaves, len(like), False), shapes,
                     *(p.free for p in problems)),
        tuple(_stack_groups([p.groups[g] for p in problems], n)
              for g, n in enumerate(shape.rows)),
        jax.tree.map(lambda *leaves: np.stack(leaves), *(p.refraction for p in problems)),
        None if first.robust is None
        else jax.tree.map(lambda *leaves: np.stack(leaves), *(p.robust for p in problems)),
        ties=next(iter(ties)),
    )
    flat_free = free_mask(stacked.free, (len(problems),))
    n_free = flat_free.sum(-1)
    if n_free.max() > shape.free:
        raise ValueError(f"pad_problems: {shape} cannot hold these problems (one has"
                         f" {n_free.max()} free unknowns)")
    # X of the spare (last) point; points are not the last block where there are mounts
    spare = int(unflatten(shapes, np.arange(flat_free.shape[1])).points[-1, 0])
    free_index = free_positions(flat_free, shape.free, spare)
    if shape.live is not None:
        return stacked, n_free, free_index, list(shape.live), [None] * len(problems)
    # One set of live slots for all: problems may free different IOPs.
    padded = [_take(stacked, k) for k in range(len(problems))]
    locals_ = [_local_positions(one) for one in padded]
    lives = zip(*(live_slots(one, index, local)
                  for one, index, local in zip(padded, free_index, locals_)))
    live = [None if slots[0] is None else tuple(sorted(set().union(*slots))) for slots in lives]
    return stacked, n_free, free_index, live, locals_


def _digests(stacked: BundleProblem, free_index: np.ndarray, live) -> list[bytes]:
    """Per problem of `stacked` (NumPy leaves with a leading batch axis; `free_index` (n,
    n_free)) a digest of all that `linearisation_plan(problem, free_index, live)` reads: the
    integer (index) arrays and observed entries of every group, the free index, the ties and
    the live slots. Padded problems of one kind and equal digests have equal plans."""
    digests = [hashlib.blake2b(repr((stacked.ties, live)).encode()) for _ in free_index]
    for digest, index in zip(digests, free_index):
        digest.update(np.ascontiguousarray(index).tobytes())
    for group in stacked.groups:
        for leaf in jax.tree.leaves(group):
            leaf = np.asarray(leaf)
            if leaf.dtype.kind in "biu":
                layout = repr(leaf.shape[1:]).encode()
                for digest, rows in zip(digests, leaf):
                    digest.update(layout)
                    digest.update(np.ascontiguousarray(rows).tobytes())
        for digest, observed in zip(digests, np.isfinite(np.asarray(group.stddev))):
            digest.update(observed.tobytes())
    return [digest.digest() for digest in digests]


def _structure(problem: BundleProblem) -> bytes:
    """`_digests` of one (unpadded) problem with its own free indices."""
    one = jax.tree.map(lambda leaf: np.asarray(leaf)[None], problem)
    return _digests(one, free_indices(problem)[None], None)[0]


# The plans of this process's padded problems by structure and padded shape: `batch_shape`
# finds them and the chunks padded to its shape (`pad_problems`) use them again.
_known_plans: dict[tuple, LinearisationPlan] = {}
KNOWN_PLANS = 4096  # structures kept at most (the oldest are dropped)


def _plans(stacked: BundleProblem, free_index, live, locals_) -> list[LinearisationPlan]:
    """`linearisation_plan` of every padded problem of `stacked`, computed once per distinct
    structure and padded shape in this process (a batch of calibrations of one target and
    one set of images has one); `locals_`: their `_local_positions`, or None where not
    known yet."""
    blocks = tuple(np.shape(leaf)[1:] for leaf in jax.tree.leaves(stacked.initial))
    plans = []
    for k, digest in enumerate(_digests(stacked, free_index, live)):
        key = (digest, blocks)
        plan = _known_plans.get(key)
        if plan is None:
            plan = linearisation_plan(_take(stacked, k), free_index[k], live, locals_[k])
            while len(_known_plans) >= KNOWN_PLANS:
                del _known_plans[next(iter(_known_plans))]
            _known_plans[key] = plan
        plans.append(plan)
    return plans


def _check_kind(problems) -> None:
    if any(problem.initial.warp is not None for problem in problems):
        raise ValueError("a board warp (Parameters.warp) is not adjusted in a padded batch:"
                         " adjust such a problem alone (jaxba.adjust; jaxba batch does)")
    reference = batch_kind(problems[0])
    for k, problem in enumerate(problems):
        if batch_kind(problem) != reference:
            raise ValueError(
                f"problem {k} has another structure than problem 0 (observation groups, camera"
                " models, refraction or robust loss); pad only problems of one kind"
            )


def batch_shape(problems) -> BatchShape:
    """The smallest shape that holds every one of `problems` (bundles of one kind), their
    plans included: chunks of them padded to it (`pad_problems(chunk, shape)`) share one
    compiled program. Pads one problem of each distinct structure (`_structure`) to find
    the plans' sizes."""
    problems = tuple(problems)
    _check_kind(problems)
    blocks = _block_shape(problems)
    distinct = {_structure(p): p for p in problems}
    stacked, _, free_index, live, locals_ = _pad_each(tuple(distinct.values()), blocks)
    plans = _plans(stacked, free_index, live, locals_)
    keys = tuple(None if slots is None else
                 tuple(max(plan.key_rows[g].shape[k] for plan in plans) for k in (0, 1))
                 for g, slots in enumerate(live))
    return dataclasses.replace(blocks, live=tuple(live), keys=keys)


def _holds(shape: BatchShape, own: BatchShape) -> bool:
    return (shape.cameras.keys() == own.cameras.keys()
            and all(shape.cameras[m] >= n for m, n in own.cameras.items())
            and shape.images >= own.images and shape.points >= own.points
            and (shape.mounts is None) == (own.mounts is None)
            and (shape.mounts or 0) >= (own.mounts or 0)
            and len(shape.rows) == len(own.rows)
            and all(a >= b for a, b in zip(shape.rows, own.rows)) and shape.free >= own.free)


def pad_problems(problems, shape: BatchShape | None = None) -> PaddedBatch:
    """Pad bundles of one kind (same observation groups in the same order, same camera
    models, refraction and robust loss) to a common shape and stack them.

    `shape`: the shape to pad to (`batch_shape` of these problems and maybe others: chunks
    of one larger batch padded alike share one compiled program); default the problems'
    own. Raises ValueError naming the first problem whose structure differs from the first
    one, or when `shape` cannot hold them.
    """
    problems = tuple(problems)
    if not problems:
        raise ValueError("pad_problems: no problems")
    with paused_gc():  # many small arrays and tuples, none in a cycle
        return _pad_problems(problems, shape)


def _pad_problems(problems: tuple[BundleProblem, ...], shape: BatchShape | None) -> PaddedBatch:
    _check_kind(problems)
    # Free unknowns counted once stacked (`_pad_each`), not read from each problem here.
    own = _block_shape(problems, None if shape is None else shape.free)
    shape = own if shape is None else shape
    if not _holds(shape, own):
        raise ValueError(f"pad_problems: {shape} cannot hold these problems ({own})")
    stacked, n_free, free_index, live, locals_ = _pad_each(problems, shape)
    plans = _plans(stacked, free_index, live, locals_)
    if all(plan is plans[0] for plan in plans):  # one structure: one plan, repeated
        one = pad_plans(plans[:1], shape.keys)
        plan = jax.tree.map(lambda leaf: np.repeat(np.asarray(leaf), len(plans), 0), one)
    else:
        plan = pad_plans(plans, shape.keys)
    device = jax.device_put((stacked, plan))  # padded and stacked in NumPy: one transfer
    return PaddedBatch(
        problem=device[0],
        plan=device[1],
        problems=problems,
        n_free=n_free,
        n_observations=observation_counts(stacked.groups, (len(problems),)),
        host=stacked,
    )


def broadcast_plan(plan: LinearisationPlan, n: int) -> LinearisationPlan:
    """`plan` repeated along a new leading batch axis of length `n`."""
    return jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (n, *jnp.shape(leaf))), plan)


def _take(tree, k: int):
    return jax.tree.map(lambda leaf: leaf[k], tree)


def _unpad_parameters(padded: Parameters, like: Parameters, k: int) -> Parameters:
    """Problem `k`'s rows of the padded batch's `padded`, as many as `like` has."""
    return jax.tree.map(lambda leaf, ref: leaf[k, : np.shape(ref)[0]], padded, like)
