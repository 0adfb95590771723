"""Many bundles in one call: pad problems to a common shape, solve them vmapped, then the
statistics of each, also vmapped.

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

The solver is `solve`'s (Levenberg-Marquardt on the Jacobi-scaled unknowns, dense QR) run
without the per-step host callback: under `jax.vmap` a `jax.debug.callback` is unrolled
once per batch element, which would make compile time grow with the batch size.
"""

import dataclasses
import hashlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .._models._cameras import CAMERA_MODELS
from .._problem._bundle import (
    BundleProblem,
    free_indices,
    observation_mask,
    observed_minus_computed,
)
from .._problem._linearisation import (
    LinearisationPlan,
    _row_blocks,
    _whole_group_jacobian,
    linearisation_plan,
    live_slots,
    normal_equations,
    pad_plans,
)
from .._problem._observations import AbstractObservationGroup
from .._problem._parameters import Parameters, flatten, parameter_labels, unflatten
from .._programs import call_stored
from .._solvers._dense import Dense, cofactors, equilibrated
from .._solvers._progress import Iteration
from .._solvers._solution import Solution
from .._solvers._solve import solve
from .._statistics._adjustment import Adjustment
from .._statistics._covariance import precision_from_covariance
from .._statistics._datum import DatumError, check_columns, check_datum
from .._statistics._reliability import reliability_from_redundancy


@dataclasses.dataclass(frozen=True)
class PaddedBatch:
    """Problems padded to one shape and stacked along a leading batch axis.

    - `problem`: a BundleProblem whose every array leaf has a leading axis of `n_batch`;
    - `plan`: the stacked `LinearisationPlan`s of the padded problems; `plan.free_index`
      (n_batch, n_free_max) the free positions in `flatten` order, padded;
    - `problems`: the original (unpadded) problems;
    - `n_free`, `n_observations`: per problem, real unknowns and observations.
    """

    problem: BundleProblem
    plan: LinearisationPlan
    problems: tuple[BundleProblem, ...]
    n_free: np.ndarray
    n_observations: np.ndarray

    @property
    def n_batch(self) -> int:
        return len(self.problems)

    @property
    def free_index(self) -> Int[Array, "n_batch n_free_max"]:
        return self.plan.free_index


def _signature(problem: BundleProblem) -> tuple:
    """What must agree between problems for them to share a padded shape."""
    groups = tuple(
        (type(g).__name__, getattr(g, "model", None), getattr(g, "block", None),
         tuple(np.shape(g.stddev)[1:]), getattr(g, "mount", None) is None)
        for g in problem.groups
    )
    cameras = tuple((m, np.shape(b)[1]) for m, b in sorted(problem.initial.cameras.items()))
    return groups, cameras, problem.initial.mounts is None, problem.refraction, problem.robust


def _pad_rows(array, n: int, fill=None):
    """Pad the leading axis of `array` to `n` rows by repeating row 0 (or with `fill`)."""
    array = np.asarray(array)
    extra = n - array.shape[0]
    if extra == 0:
        return array
    if fill is None:
        rows = np.repeat(array[:1], extra, axis=0)
    else:
        rows = np.full((extra, *array.shape[1:]), fill, dtype=array.dtype)
    return np.concatenate([array, rows])


def _pad_group(group: AbstractObservationGroup, n: int, name: str) -> AbstractObservationGroup:
    """Rows repeated from row 0 up to `n`, σ = inf on the added rows; `name` unified."""
    n_real = np.shape(group.stddev)[0]
    leaves = {
        field.name: getattr(group, field.name)
        for field in dataclasses.fields(group)
        if not field.metadata.get("static", False) and field.name != "stddev"
        and getattr(group, field.name) is not None
    }
    padded = {key: _pad_rows(value, n) for key, value in leaves.items()}
    stddev = np.array(_pad_rows(group.stddev, n, fill=np.inf))
    stddev[n_real:] = np.inf
    padded["stddev"] = stddev
    group = eqx.tree_at(lambda g: [getattr(g, k) for k in padded], group, list(padded.values()))
    return dataclasses.replace(group, name=name) if hasattr(group, "name") else group


def _pad_parameters(params: Parameters, shapes: Parameters, fill_free: bool | None) -> Parameters:
    def pad(leaf, like):
        n = np.shape(like)[0]
        if fill_free is None:
            return _pad_rows(leaf, n)
        return _pad_rows(leaf, n, fill=fill_free)

    return jax.tree.map(pad, params, shapes)


def _padded_ties(problem: BundleProblem, shapes: Parameters) -> tuple:
    """`problem.ties` as positions of the padded Parameters shaped like `shapes`."""
    own = unflatten(problem.initial, np.arange(flatten(problem.initial).size)).cameras
    padded = unflatten(shapes, np.arange(flatten(shapes).size)).cameras
    position = np.zeros(flatten(problem.initial).size, dtype=int)
    for model, block in own.items():
        position[np.ravel(block)] = np.ravel(padded[model][: block.shape[0]])
    return tuple((int(position[d]), int(position[s])) for d, s in problem.ties)


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


def _block_shape(problems: tuple[BundleProblem, ...]) -> BatchShape:
    """The largest of every block and group, one spare point row; no plan yet."""
    return BatchShape(
        cameras={m: max(p.initial.cameras[m].shape[0] for p in problems)
                 for m in problems[0].initial.cameras},
        images=max(p.initial.images.shape[0] for p in problems),
        points=max(p.initial.points.shape[0] for p in problems) + 1,
        rows=tuple(max(np.shape(p.groups[g].stddev)[0] for p in problems)
                   for g in range(len(problems[0].groups))),
        free=max(p.n_unknowns() for p in problems),
        mounts=None if problems[0].initial.mounts is None
        else max(p.initial.mounts.shape[0] for p in problems),
    )


def _pad_each(problems, shape: BatchShape) -> tuple[list[BundleProblem], np.ndarray, list]:
    """Every problem padded to `shape`'s blocks, the (n, shape.free) padded free indices
    and the live slots of the plans (`shape.live`, or the union over these problems)."""
    shapes = Parameters(
        cameras={m: np.zeros((n, problems[0].initial.cameras[m].shape[1]))
                 for m, n in shape.cameras.items()},
        images=np.zeros((shape.images, 6)),
        points=np.zeros((shape.points, 3)),
        mounts=None if shape.mounts is None else np.zeros((shape.mounts, 6)),
    )
    names = [g.name for g in problems[0].groups]
    padded, indices = [], []
    ties = {_padded_ties(problem, shapes) for problem in problems}
    if len(ties) > 1:
        raise ValueError("the problems tie different camera parameters (BundleProblem.ties);"
                         " pad only problems with the same ties")
    for problem in problems:
        initial = _pad_parameters(problem.initial, shapes, None)
        free = _pad_parameters(problem.free, shapes, False)
        groups = tuple(_pad_group(g, n, name)
                       for g, n, name in zip(problem.groups, shape.rows, names))
        one = BundleProblem(initial, free, groups, problem.refraction, problem.robust,
                            ties=next(iter(ties)))
        padded.append(one)
        indices.append(free_indices(one))
    size = flatten(padded[0].initial).size
    spare = int(np.asarray(unflatten(padded[0].initial, np.arange(size)).points)[-1, 0])
    # X of the spare (last) point; points are not the last block where there are mounts
    free_index = np.full((len(problems), shape.free), spare)
    for k, index in enumerate(indices):
        free_index[k, : len(index)] = index
    if shape.live is not None:
        return padded, free_index, list(shape.live)
    # One set of live slots for all: problems may free different IOPs.
    lives = zip(*(live_slots(one, index) for one, index in zip(padded, free_index)))
    live = [None if slots[0] is None else tuple(sorted(set().union(*slots))) for slots in lives]
    return padded, free_index, live


def _structure(problem: BundleProblem, free_index: np.ndarray, live) -> bytes:
    """A digest of all that `linearisation_plan(problem, free_index, live)` reads: the
    integer (index) arrays and observed entries of every group, the free index, the ties and
    the live slots. Padded problems of one kind and equal digests have equal plans."""
    digest = hashlib.blake2b(repr((problem.ties, live)).encode())
    digest.update(np.asarray(free_index).tobytes())
    for group in problem.groups:
        for leaf in jax.tree.leaves(group):
            leaf = np.asarray(leaf)
            if leaf.dtype.kind in "biu":
                digest.update(repr(leaf.shape).encode())
                digest.update(leaf.tobytes())
        digest.update(np.isfinite(np.asarray(group.stddev)).tobytes())
    return digest.digest()


def _plans(padded, free_index, live) -> list[LinearisationPlan]:
    """`linearisation_plan` of every padded problem, computed once per distinct structure
    (a batch of calibrations of one target and one set of images has one)."""
    known, plans = {}, []
    for one, index in zip(padded, free_index):
        key = _structure(one, index, live)
        if key not in known:
            known[key] = linearisation_plan(one, index, live)
        plans.append(known[key])
    return plans


def _check_kind(problems) -> None:
    if any(problem.initial.warp is not None for problem in problems):
        raise ValueError("a board warp (Parameters.warp) is not adjusted in a padded batch:"
                         " adjust such a problem alone (jaxba.adjust; jaxba batch does)")
    reference = _signature(problems[0])
    for k, problem in enumerate(problems):
        if _signature(problem) != reference:
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
    distinct = {_structure(p, free_indices(p), None): p for p in problems}
    padded, free_index, live = _pad_each(tuple(distinct.values()), blocks)
    plans = _plans(padded, free_index, live)
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
    _check_kind(problems)
    own = _block_shape(problems)
    shape = own if shape is None else shape
    if not _holds(shape, own):
        raise ValueError(f"pad_problems: {shape} cannot hold these problems ({own})")
    padded, free_index, live = _pad_each(problems, shape)
    plans = _plans(padded, free_index, live)
    # Padded in NumPy, stacked in NumPy, one transfer per leaf.
    stacked = jax.tree.map(lambda *leaves: jax.device_put(np.stack(leaves)), *padded)
    if all(plan is plans[0] for plan in plans):  # one structure: one plan, repeated
        one = pad_plans(plans[:1], shape.keys)
        plan = jax.tree.map(lambda leaf: jax.device_put(np.repeat(leaf, len(plans), 0)), one)
    else:
        plan = pad_plans(plans, shape.keys)
    return PaddedBatch(
        problem=stacked,
        plan=plan,
        problems=problems,
        n_free=np.array([p.n_unknowns() for p in problems]),
        n_observations=np.array([p.n_observations() for p in problems]),
    )


@eqx.filter_jit
def solve_batch(
    problem: BundleProblem,
    plan: LinearisationPlan,
    *,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    chunk_size: int | None = None,
) -> Solution:
    """`solve` vmapped over a leading batch axis of `problem` and `plan` (`pad_plans`, or
    one plan broadcast with `broadcast_plan` for problems of one structure): one
    compilation per padded shape. Returns a Solution with a leading batch axis.

    `chunk_size`: solve `chunk_size` problems at a time (vmapped), the chunks one after the
    other (`jax.lax.map`), in one compiled call. A vmapped solve runs every problem until
    the slowest of its chunk has converged, and its per-row arrays outgrow the CPU caches:
    for Zhang-size calibrations (1280 rows) chunks of 10 ran ~1.3x faster than one chunk
    of 250 (benchmarks/README.md). None: all at once.
    """
    return _solve_batch(problem, plan, max_steps, rtol, atol, chunk_size)


@eqx.filter_jit
def _solve_batch(problem, plan, max_steps, rtol, atol, chunk_size) -> Solution:
    arrays, static = eqx.partition((problem, plan), eqx.is_array)

    def one(arrays):
        problem, plan = eqx.combine(arrays, static)
        return solve(problem, Dense(plan), max_steps=max_steps, rtol=rtol, atol=atol)

    if chunk_size is None:
        return jax.vmap(one)(arrays)
    return jax.lax.map(one, arrays, batch_size=chunk_size)


def broadcast_plan(plan: LinearisationPlan, n: int) -> LinearisationPlan:
    """`plan` repeated along a new leading batch axis of length `n`."""
    return jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (n, *jnp.shape(leaf))), plan)


class BatchStatistics(eqx.Module):
    """Per problem (leading batch axis): cost ½eᵀe at the start and the solution, the
    cofactor matrix (JᵀJ)⁻¹ of the (padded) free unknowns, the leverages diag(J(JᵀJ)⁻¹Jᵀ)
    of every residual entry, the whitened residuals e and `suspect`, the datum screen at
    the approximations (`_datum_suspect`)."""

    initial_cost: Float[Array, " n_batch"]
    cofactor: Float[Array, "n_batch n_free n_free"]
    leverage: Float[Array, "n_batch n_residuals"]
    whitened: Float[Array, "n_batch n_residuals"]
    suspect: Bool[Array, " n_batch"]


def _datum_suspect(problem: BundleProblem, plan: LinearisationPlan, n_free, rtol: float):
    """False where the datum is surely defined at the approximations: N = JᵀJ finite, every
    real column observed, and the equilibrated N's eigenvalues λ = s² (s the singular values
    of the equilibrated J) with λ_min/λ_max above 4·rtol² + 1e-12: a defect, s_min/s_max <
    rtol, lies below it even with N's rounding (~1e-16 λ_max). True: `check_datum` decides
    (the exact test, from J itself, and the message)."""
    normal = normal_equations(problem, problem.initial, plan)[0]
    real = jnp.arange(plan.n_free) < n_free
    finite = jnp.all(jnp.isfinite(normal))
    observed = jnp.all(jnp.where(real, jnp.diag(normal) > 0, True))
    scaled = equilibrated(jnp.where(finite, normal, 1.0), real)[0]
    eigenvalues = jnp.linalg.eigvalsh(jnp.where(finite, scaled, jnp.eye(plan.n_free)))
    regular = eigenvalues[0] > (4 * rtol**2 + 1e-12) * eigenvalues[-1]
    return ~(finite & observed & regular)


def _leverages(problem: BundleProblem, params: Parameters, plan: LinearisationPlan, cofactor):
    """diag(J Q Jᵀ) of every residual entry (flat, in `problem.whitened`'s order), Q the
    cofactor matrix (n_free, n_free): per key of the plan from the rows' Jacobian blocks and
    Q's block of the key's columns (no dense Jacobian); whole groups from their Jacobian."""
    n = plan.n_free
    padded = jnp.zeros((n + 1, n + 1), cofactor.dtype).at[:n, :n].set(cofactor)
    parts = []
    for group, rows, columns, slots in zip(
        problem.groups, plan.key_rows, plan.key_columns, plan.live
    ):
        n_rows, k = jnp.shape(group.stddev)
        if slots is None:
            jacobian, _ = _whole_group_jacobian(problem, params, plan.free_index, [group])
            parts.append(jnp.einsum("ei,ij,ej->e", jacobian, cofactor, jacobian))
            continue
        if not slots:
            parts.append(jnp.zeros(n_rows * k, cofactor.dtype))
            continue
        blocks = _row_blocks(problem, group, params)[1][:, :, list(slots)]
        blocks = jnp.concatenate([blocks, jnp.zeros_like(blocks[:1])])[rows]
        block_q = padded[columns[:, :, None], columns[:, None, :]]
        leverage = jnp.einsum("kmci,kij,kmcj->kmc", blocks, block_q, blocks)
        target = jnp.where(rows >= 0, rows, n_rows)  # key padding: a dropped extra row
        parts.append(jnp.zeros((n_rows + 1, k), cofactor.dtype).at[target].set(leverage)
                     [:n_rows].ravel())
    return jnp.concatenate(parts)


def _statistics_one(problem: BundleProblem, plan: LinearisationPlan, params: Parameters,
                    n_free, datum_rtol: float) -> BatchStatistics:
    real = jnp.arange(plan.n_free) < n_free
    cofactor = cofactors(normal_equations(problem, params, plan)[0], real)
    whitened = jnp.concatenate([jnp.ravel(e) for e in problem.whitened(params)])
    initial = 0.5 * sum(jnp.sum(e**2) for e in problem.whitened(problem.initial))
    return BatchStatistics(initial, cofactor, _leverages(problem, params, plan, cofactor),
                           whitened, _datum_suspect(problem, plan, n_free, datum_rtol))


def _each(function, problem, plan, n_free, chunk_size):
    """`function(problem, plan, n_free)` of every problem of a padded batch: vmapped, or
    `chunk_size` at a time (vmapped) one chunk after the other (`jax.lax.map`)."""
    arrays, static = eqx.partition((problem, plan), eqx.is_array)

    def one(args):
        arrays, n = args
        return function(*eqx.combine(arrays, static), n)

    if chunk_size is None:
        return jax.vmap(one)((arrays, n_free))
    return jax.lax.map(one, (arrays, n_free), batch_size=chunk_size)


@eqx.filter_jit
def batch_statistics(
    problem: BundleProblem, plan: LinearisationPlan, parameters: Parameters, n_free, *,
    datum_rtol: float = 1e-9,
) -> BatchStatistics:
    """Dense statistics of every problem of a padded batch at `parameters`, vmapped."""
    return jax.vmap(lambda problem, plan, params, n: _statistics_one(
        problem, plan, params, n, datum_rtol))(problem, plan, parameters, n_free)


@eqx.filter_jit
def _adjust_program(problem, plan, n_free, max_steps, rtol, atol, datum_rtol, chunk_size):
    """Solve and statistics of every problem of a padded batch: one compiled program."""

    def one(problem, plan, n):
        solution = solve(problem, Dense(plan), max_steps=max_steps, rtol=rtol, atol=atol)
        return solution, _statistics_one(problem, plan, solution.parameters, n, datum_rtol)

    return _each(one, problem, plan, n_free, chunk_size)


def _adjust_outline(problem, plan, n_free) -> tuple[Solution, BatchStatistics]:
    """The structure of `_adjust_program`'s output (leaves of no meaning), without tracing."""
    zero = np.zeros(())
    return (Solution(problem.initial, zero, zero, zero, zero, optx.RESULTS.successful),
            BatchStatistics(zero, zero, zero, zero, zero))


@eqx.filter_jit
def _screen_program(problem, plan, n_free, datum_rtol):
    return _each(lambda problem, plan, n: _datum_suspect(problem, plan, n, datum_rtol),
                 problem, plan, n_free, None)


def _datum_error(problem, suspect: bool, labels, rtol: float) -> DatumError | None:
    """`check_datum`'s error of one problem, or None: the exact check where the batched
    screen found it `suspect`; otherwise the structural checks only (redundancy, separable
    camera parameters: `check_columns`, its finite and observed columns screened)."""
    try:
        if suspect:
            check_datum(problem, labels=labels, rtol=rtol)
        else:
            n = problem.n_unknowns()
            check_columns(problem, np.ones(n, bool), np.ones(n),
                          labels or parameter_labels(problem.initial))
    except DatumError as error:
        return error
    return None


def check_datum_batch(
    problems, *, labels: list | None = None, rtol: float = 1e-9, shape: BatchShape | None = None
) -> list[DatumError | None]:
    """`check_datum` of every problem, screened in one vmapped program (one compilation):
    per problem None, or the `DatumError` that `check_datum` would raise. `shape`: as
    `pad_problems`'."""
    batch = pad_problems(problems, shape)
    suspect = np.asarray(_screen_program(batch.problem, batch.plan, jax.device_put(batch.n_free),
                                         rtol))
    labels = labels if labels is not None else [None] * batch.n_batch
    return [_datum_error(problem, bool(flag), names, rtol)
            for problem, flag, names in zip(batch.problems, suspect, labels)]


def adjust_batch(
    problems,
    *,
    sigma0: float | list[float] = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    alpha: float | list[float] | None = None,
    familywise: bool | list[bool] = False,
    shape: BatchShape | None = None,
) -> list[Adjustment]:
    """Adjust bundles of one kind in one padded, jitted, vmapped program: the solve and
    the statistics of each.

    Each returned `Adjustment` equals `adjust(problem)` of that problem alone (to rounding):
    parameters, σ̂0² = σ0² eᵀe / r, Cxx = σ̂0² (σ0² JᵀJ)⁻¹, residuals. Its `iterations`
    hold only the start and the solution (no per-step report inside a batch). With `alpha`
    (one per problem or one for all) `reliability` is filled in as `reliability(result,
    alpha=..., familywise=...)` would. No datum check: call `check_datum` first, or
    `adjust_padded(..., check=True)` (the CLI's `run_batch` does). `shape`: the padded
    shape (`pad_problems`).
    """
    return adjust_padded(pad_problems(problems, shape), sigma0=sigma0, max_steps=max_steps,
                         rtol=rtol, atol=atol, alpha=alpha, familywise=familywise)


def adjust_padded(
    batch: PaddedBatch,
    *,
    sigma0: float | list[float] = 1.0,
    max_steps: int = 50,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    alpha: float | list[float] | None = None,
    familywise: bool | list[bool] = False,
    check: bool = False,
    labels: list | None = None,
    datum_rtol: float = 1e-9,
    chunk_size: int | None = None,
) -> list[Adjustment | DatumError]:
    """`adjust_batch` of a padded batch (`pad_problems`). With `check`, the datum of every
    problem is checked in the same program (`check_datum_batch`'s screen; `labels`: one
    list per problem, or None): a problem whose datum is not defined gets its `DatumError`
    in place of an Adjustment. `chunk_size`: as `solve_batch`'s."""
    n = batch.n_batch
    sigma0s = [sigma0] * n if np.ndim(sigma0) == 0 else list(sigma0)
    alphas = [alpha] * n if alpha is None or np.ndim(alpha) == 0 else list(alpha)
    familywises = [familywise] * n if np.ndim(familywise) == 0 else list(familywise)
    labels = labels if labels is not None else [None] * n
    # Called through a stored export where one exists: a later process skips the trace.
    solution, stats = jax.device_get(call_stored(
        "batch_adjust", _adjust_program,
        (batch.problem, batch.plan, jax.device_put(batch.n_free)),
        (max_steps, rtol, atol, datum_rtol, chunk_size), _adjust_outline,
        code=tuple(CAMERA_MODELS[model] for model in batch.problem.initial.cameras)))
    layout = [np.shape(group.stddev)[1:] for group in batch.problem.groups]
    results = []
    for k, problem in enumerate(batch.problems):
        if check:
            error = _datum_error(problem, bool(stats.suspect[k]), labels[k], datum_rtol)
            if error is not None:
                results.append(error)
                continue
        results.append(_adjustment(
            problem, layout, _take(solution, k), _take(stats, k), int(batch.n_free[k]),
            sigma0s[k], alphas[k], familywises[k],
        ))
    return results


def _take(tree, k: int):
    return jax.tree.map(lambda leaf: leaf[k], tree)


def _unpad_parameters(padded: Parameters, like: Parameters) -> Parameters:
    return jax.tree.map(lambda leaf, ref: leaf[: np.shape(ref)[0]], padded, like)


def _unpad_residuals(layout: list[tuple], problem: BundleProblem, flat) -> list:
    """Split a flat padded residual vector (groups of (rows, k) as `layout`) into the real
    rows of each group of `problem`."""
    parts, start = [], 0
    for shape, group in zip(layout, problem.groups):
        size = int(np.prod(shape))
        parts.append(flat[start:start + size].reshape(shape)[: np.shape(group.stddev)[0]])
        start += size
    return parts


def _adjustment(problem, layout, solution, stats, n_free, sigma0, alpha, familywise):
    params = _unpad_parameters(solution.parameters, problem.initial)
    mask = observation_mask(problem)
    n_obs = int(mask.sum())
    redundancy = n_obs - n_free
    whitened = _unpad_residuals(layout, problem, stats.whitened)
    final_cost = 0.5 * float(sum(np.sum(e**2) for e in whitened))
    sigma0_squared = sigma0**2 * 2 * final_cost / redundancy
    covariance = (sigma0_squared / sigma0**2) * stats.cofactor[:n_free, :n_free]
    prec = precision_from_covariance(problem, params, covariance, sigma0_squared, redundancy,
                                     n_obs)
    residuals = observed_minus_computed(problem, whitened)
    iterations = [
        Iteration(0, float(stats.initial_cost),
                  sigma0**2 * 2 * float(stats.initial_cost) / max(redundancy, 1)),
        Iteration(1, final_cost, sigma0_squared),
    ]
    converged = bool(solution.converged)
    result = Adjustment(
        problem=problem,
        parameters=params,
        precision=prec,
        residuals=residuals,
        iterations=iterations,
        converged=converged,
        message="converged" if converged else str(optx.RESULTS[solution.result]),
        steps=int(solution.steps),
        sigma0_prior=float(sigma0),
    )
    if alpha is None:
        return result
    leverage = np.concatenate([np.ravel(x) for x in _unpad_residuals(layout, problem,
                                                                      stats.leverage)])
    flat_e = np.concatenate([np.ravel(e) for e in whitened])
    r, e = 1.0 - leverage[mask], flat_e[mask]
    return dataclasses.replace(result, reliability=reliability_from_redundancy(
        problem, r, e, alpha=alpha, familywise=familywise
    ))


__all__ = [
    "BatchShape", "PaddedBatch", "adjust_batch", "adjust_padded", "batch_shape", "batch_statistics",
    "check_datum_batch", "pad_problems", "solve_batch",
]
