"""Observation groups: each is one per-observation residual function vmapped over the group.

Residuals are whitened, e = (observed - computed) / σ, so that the solver minimises
½ Σ e² = ½ vᵀ Σ⁻¹ v. Every group reports which residual entries are real observations
(`mask`), so that padding entries (a coordinate with no observation) count nowhere.
"""

from collections.abc import Hashable, Iterator, Mapping, Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._custom_types import Vector2, Vector3
from .._models._board_warp import warped_point
from .._models._cameras import CAMERA_MODELS, AbstractRefraction
from .._models._poses import (
    POSE_MODELS,
    AbstractPose,
    ComposedPose,
    image_frames,
    image_row_inputs,
)
from ._parameters import IMAGE_PARAMETER_NAMES, POINT_PARAMETER_NAMES, Parameters


class AbstractObservationGroup(eqx.Module):
    """A set of observations of one kind.

    `stddev` holds the a priori σ of every residual entry (units of the observation);
    σ = inf marks an entry that is not an observation (an unobserved coordinate, or a
    measurement removed as a blunder): it is whitened to 0 and counted nowhere.

    A row-local group (every group but the inner constraints) says which parameter
    blocks each row depends on (`row_blocks`; `local_values` gathers their values) and
    computes one row from them (`row_residual`); `residuals` vmaps that row function and
    `row_jacobians` differentiates it (reverse mode: k outputs, few inputs). `ImagePoints`
    overrides both, to make each image's pose frame once rather than once per row. A
    group that is not row-local overrides `residuals` and has no `row_blocks`.
    """

    name: eqx.AbstractVar[str]
    stddev: eqx.AbstractVar[Float[Array, "n k"]]
    # True for rows that fix a datum (inner constraints): counted as constraints, not
    # as observations, by the covariance.
    constraint: ClassVar[bool] = False
    # True where a blunder in one entry of a row removes the whole row (data snooping):
    # an image point's x and y are one measurement.
    removed_whole: ClassVar[bool] = False

    def prior_positions(self, positions: Parameters) -> np.ndarray:
        """The `flatten` positions of the unknowns this group observes directly (priors:
        control, GNSS/INS, IOP priors), given a Parameters of positions; none here."""
        del positions
        return np.zeros(0, dtype=int)

    def row_blocks(self) -> tuple[tuple[str, Int[Array, " n"]], ...]:
        """The parameter blocks every row depends on, as (block, index) pairs: row i reads
        row index[i] (index (n,)) of the block ("cameras/<model>", "images", "mounts" or
        "points"), in the order of `local_values`' columns; () where rows may depend on any
        unknown (not row-local). This is how a group contributes to the normal equations:
        the dense backend places its rows' Jacobian blocks at these blocks' positions
        (`local_values` of flat positions); the Schur split eliminates the point of an
        image point's row and keeps on the reduced side a point that a row of another
        group couples with further unknowns (a distance's two points)."""
        return ()

    def local_values(self, params: Parameters) -> Array | None:
        """(n, width): the values of the unknowns row i depends on (`row_blocks`' rows, side
        by side), taken from `params` by indexing only (so a Parameters of flat positions
        gives their positions: `local_positions`). None: rows may depend on any unknown."""
        return _row_values(self.row_blocks(), params, jnp)

    def row_residual(self, values: Array, row: Array, refraction: AbstractRefraction) -> Array:
        """Whitened residual (k,) of row `row` from its unknowns `values` (width,)."""
        raise NotImplementedError(f"{type(self).__name__} has no row function")

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Array:
        """Whitened residuals (observed - computed) / σ, shape (n, k)."""
        values = self.local_values(params)
        rows = jnp.arange(values.shape[0])
        return jax.vmap(lambda v, i: self.row_residual(v, i, refraction))(values, rows)

    def row_jacobians(
        self, params: Parameters, refraction: AbstractRefraction
    ) -> tuple[Float[Array, "n k"], Float[Array, "n k width"]]:
        """The residuals (as `residuals`, unmasked) and d residual row / d its unknowns,
        for every row (row-local groups only): one forward and k backward passes a row."""
        values = self.local_values(params)
        rows = jnp.arange(values.shape[0])

        def row(v, i):
            e = self.row_residual(v, i, refraction)
            return e, e

        jacobians, residuals = jax.vmap(jax.jacrev(row, has_aux=True))(values, rows)
        return residuals, jacobians

    def kind(self) -> str:
        """What the group measures, as reports and results.json name it: "image_points",
        "control", "gnss_ins", "camera_priors", "distances"; by default its name up to a
        colon."""
        return self.name.split(":")[0]

    def coordinate_names(self) -> tuple[str, ...]:
        """The names of a row's entries (its residual columns); () where a row is one
        quantity that its `row_references` name alone (a distance)."""
        return tuple(str(k) for k in range(self.stddev.shape[1]))

    def row_references(self) -> tuple[tuple[str, str, Int[Array, " n"]], ...]:
        """What each row refers to, as (label, block, index) triples: `index` (n,) rows of
        the block ("images", "points" or "cameras/<model>"), whose IDs name the row under
        `label` in reports; () where rows are known by their number only."""
        return ()

    def parts(
        self, camera_ids: Mapping[str, Sequence[Hashable]]
    ) -> tuple[tuple[str, ...], np.ndarray]:
        """The parts of the group that reports and variance components treat apart, as
        (names, index (n,) of every row's part in names); by default one part, the whole
        group under its name. `camera_ids`: {model: ID per row of `cameras[model]`}."""
        del camera_ids
        return (self.name,), np.zeros(np.shape(self.stddev)[0], dtype=int)

    def mask(self) -> Bool[Array, "n k"]:
        """True where the residual entry is an observation: traced inside a program, a NumPy
        array outside one (host bookkeeping, no jax op per call)."""
        if isinstance(self.stddev, jax.core.Tracer):
            return jnp.isfinite(self.stddev)
        return np.isfinite(np.asarray(self.stddev))

    def sigma(self) -> Float[Array, "n k"]:
        """A priori σ of every residual entry."""
        return self.stddev


def local_positions(group: AbstractObservationGroup, positions: Parameters
                    ) -> np.ndarray | None:
    """`group.local_values(positions)` in NumPy, on the host (no program): the `flatten`
    positions (n, width) of the unknowns each row depends on, `positions` a Parameters of
    positions (`positions_of`); None for a group that is not row-local."""
    return _row_values(host_query(group, "row_blocks"), positions, np)


def _row_values(blocks, params: Parameters, xp):
    """`local_values` of `row_blocks`' `blocks` from `params`, with the array module `xp`
    (jax.numpy in a trace, NumPy on the host)."""
    if not blocks:
        return None
    return xp.concatenate([xp.asarray(params.block(block))[xp.asarray(index)]
                           for block, index in blocks], axis=1)


def host_query(group: AbstractObservationGroup, method: str, *args):
    """`group.<method>(*args)` called through the group's class: an equinox Module's bound
    method is itself a Module, built (its arguments' leaves checked) on every access, ~0.1 ms;
    for the host-side queries (`kind`, `parts`, `row_references`, ...) of the reports."""
    return getattr(type(group), method)(group, *args)


def part_name(group: AbstractObservationGroup, camera_ids: Mapping[str, Sequence[Hashable]],
              row: int) -> str:
    """The name of the part (`parts`) that row `row` of `group` belongs to."""
    names, index = host_query(group, "parts", camera_ids)
    return names[int(index[row])]


def named_parts(group: AbstractObservationGroup, camera_ids: Mapping[str, Sequence[Hashable]]
                ) -> Iterator[tuple[str, np.ndarray]]:
    """(name, rows (m,)) of every part of `group` with rows, in the order of `parts`."""
    names, index = host_query(group, "parts", camera_ids)
    if len(names) == 1:  # one part: every row (no sort)
        if len(index):
            yield names[0], np.arange(len(index))
        return
    order = np.argsort(index, kind="stable")
    parts, starts = np.unique(index[order], return_index=True)
    for k, rows in zip(parts.tolist(), np.split(order, starts[1:])):
        yield names[k], rows


def collinearity_residual(
    model: str,
    iop: Float[Array, " n_iop"],
    eop: Float[Array, " 6"],
    point: Vector3,
    measured: Vector2,
    sigma: Vector2,
    refraction: AbstractRefraction,
    pose: str = "opk",
    constants: tuple[tuple[str, float], ...] = (),
) -> Vector2:
    """Whitened image residual (x_obs - x, y_obs - y) / σ of one measured image point; `eop`
    is the image's row of the pose model `pose` (`POSE_MODELS`); `constants` the camera
    model's constants as (name, value) pairs (`AbstractCamera.constant_names`)."""
    return _frame_collinearity_residual(
        model, iop, POSE_MODELS[pose].from_parameters(eop), point, measured, sigma, refraction,
        constants)


def _frame_collinearity_residual(
    model: str,
    iop: Float[Array, " n_iop"],
    frame,
    point: Vector3,
    measured: Vector2,
    sigma: Vector2,
    refraction: AbstractRefraction,
    constants: tuple[tuple[str, float], ...] = (),
) -> Vector2:
    """`collinearity_residual` with the image's pose given as a frame (a pose's `frame()`:
    `to_camera`, `station`)."""
    camera = CAMERA_MODELS[model].from_parameters(iop, **dict(constants))
    k = refraction.coefficient(frame.station(), point)
    return (measured - camera.image_point(frame.to_camera(point), measured, k)) / sigma


def row_pose(pose: type[AbstractPose], inputs, delta: Array, mounted: bool):
    """The frame of one image row moved by `delta`: the pose's `row_frame` (delta (6,)), or
    with `mounted` the frame's then the mount's (inputs a pair, delta (12,): the frame's
    6 then the mount's), composed (`ComposedPose`)."""
    if not mounted:
        return pose.row_frame(inputs, delta)
    return ComposedPose(pose.row_frame(inputs[0], delta[:6]),
                        pose.row_frame(inputs[1], delta[6:]))


class ImagePoints(AbstractObservationGroup):
    """Image coordinates of points, all taken with cameras of one model and images of one
    pose model.

    `camera`, `image`, `point` index the rows of `cameras[model]`, `images`, `points`;
    `measured` and `stddev` are (n, 2) in the camera model's image units. `pose` names the
    pose model (`POSE_MODELS`) that reads the `images` rows: "opk" (X0, omega, phi, kappa,
    jaxba's project files) or "rodrigues" (BAL's r, t). It lives here, beside `model`,
    because the group is what evaluates rows: every residual and Jacobian (the dense
    rows, the Schur backend's blocks) reads both models from the group, and a row never
    needs more than its group; consumers that hold only Parameters (the datum's similarity
    transform) ask the problem (`BundleProblem.pose`), which holds one pose model for all
    its image groups.

    `constants`: the values of the camera model's constants (`AbstractCamera.constant_names`,
    e.g. (("r0", 12.5),) for "metrology") as (name, value) pairs, shared by all the group's
    cameras (project files make one group per model and constants); () for models without
    constants.

    `per_camera`: the rows of each camera form a part of their own (`parts`), named
    "image_points:<camera ID>" (project files: reports, variance components and data
    snooping per camera, as many cameras as there are in one group and one program);
    False: the group is one part under its name.

    `mount`: None, or the row of `Parameters.mounts` of every row's camera in a rig: `image`
    then indexes the rig's frame (an `images` row) and the row's pose is the frame's pose
    followed by the mount (`ComposedPose`); a row outside a rig, or of a rig's reference
    camera, points to a fixed identity mount. `local_values` and the Jacobians then carry
    the mount's 6 parameters after the frame's.

    `board`: None, or the row of `Parameters.warp` of every row's board, and `warp_shape`
    (n, 2) the row's point's (1 - x², 1 - y²) over its board (`warp_shape`): the point is
    then moved along +Z of the object frame (the board's normal: a board's points in its
    own frame, as a calibration has them) by kx (1 - x²) + ky (1 - y²) before it is
    projected. `local_values` and the Jacobians then carry the board's kx, ky after the
    point. More boards take a row each; a board whose plane is not Z = 0 of the object
    frame would need its normal per row.
    """

    name: str = eqx.field(static=True)
    model: str = eqx.field(static=True)
    camera: Int[Array, " n"]
    image: Int[Array, " n"]
    point: Int[Array, " n"]
    measured: Float[Array, "n 2"]
    stddev: Float[Array, "n 2"]
    pose: str = eqx.field(static=True, default="opk")
    constants: tuple[tuple[str, float], ...] = eqx.field(static=True, default=())
    per_camera: bool = eqx.field(static=True, default=False)
    mount: Int[Array, " n"] | None = None
    board: Int[Array, " n"] | None = None
    warp_shape: Float[Array, "n 2"] | None = None
    removed_whole: ClassVar[bool] = True

    def __check_init__(self):
        if (self.board is None) != (self.warp_shape is None):
            raise ValueError("a warped board needs both `board` and `warp_shape`")

    def kind(self) -> str:
        return "image_points"

    def parts(
        self, camera_ids: Mapping[str, Sequence[Hashable]]
    ) -> tuple[tuple[str, ...], np.ndarray]:
        """One part per camera of the model ("image_points:<camera ID>"; cameras without
        rows here have none) where `per_camera`, else the whole group."""
        if not self.per_camera:
            return (self.name,), np.zeros(np.shape(self.stddev)[0], dtype=int)
        names = tuple(f"image_points:{cid}" for cid in camera_ids[self.model])
        return names, np.asarray(self.camera, dtype=int)

    def coordinate_names(self) -> tuple[str, ...]:
        return ("x", "y")

    def row_references(self) -> tuple[tuple[str, str, Int[Array, " n"]], ...]:
        if self.mount is not None:  # a frame and a camera name a rig's image
            return (("frame", "images", self.image),
                    ("camera", f"cameras/{self.model}", self.camera),
                    ("point", "points", self.point))
        return ("image", "images", self.image), ("point", "points", self.point)

    def row_blocks(self) -> tuple[tuple[str, Int[Array, " n"]], ...]:
        """The camera's IOPs, the image's (or frame's, then the mount's) pose parameters,
        the point's XYZ (then kx, ky of its board where the group has `board`)."""
        mount = () if self.mount is None else (("mounts", self.mount),)
        warp = () if self.board is None else (("warp", self.board),)
        return ((f"cameras/{self.model}", self.camera), ("images", self.image), *mount,
                ("points", self.point), *warp)

    def _points(self, params: Parameters) -> Float[Array, "n 3"]:
        """Every row's object point, moved by its board's warp where the group has one."""
        points = jnp.asarray(params.points)[self.point]
        if self.board is None:
            return points
        return jax.vmap(warped_point)(points, jnp.asarray(params.warp)[self.board],
                                      jnp.asarray(self.warp_shape))

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Float[Array, "n 2"]:
        """Whitened residuals (n, 2), each image's frame (`AbstractPose.frame`) made once
        (and each mount's)."""
        pose = POSE_MODELS[self.pose]
        frames = jax.tree.map(lambda x: x[self.image],
                              image_frames(pose, jnp.asarray(params.images)))
        if self.mount is not None:
            mounts = image_frames(pose, jnp.asarray(params.mounts))
            frames = ComposedPose(frames, jax.tree.map(lambda x: x[self.mount], mounts))
        return jax.vmap(self.frame_residual, in_axes=(0, 0, 0, 0, 0, None))(
            jnp.asarray(params.cameras[self.model])[self.camera], frames,
            self._points(params), self.measured, self.stddev, refraction)

    def row_jacobians(
        self, params: Parameters, refraction: AbstractRefraction
    ) -> tuple[Float[Array, "n 2"], Float[Array, "n 2 width"]]:
        """The residuals and d residual row / d `local_values` row, in reverse mode as the
        base class does, the image's pose through its model's `row_frame` (from
        `row_inputs`, made once per image)."""
        pose = POSE_MODELS[self.pose]
        inputs = jax.tree.map(lambda x: x[self.image],
                              image_row_inputs(pose, jnp.asarray(params.images)))
        if self.mount is not None:
            mounts = image_row_inputs(pose, jnp.asarray(params.mounts))
            inputs = (inputs, jax.tree.map(lambda x: x[self.mount], mounts))

        def row(iop, delta, point, warp, pose_inputs, measured, sigma, shape):
            frame = row_pose(pose, pose_inputs, delta, self.mount is not None)
            if shape is not None:
                point = warped_point(point, warp, shape)
            e = self.frame_residual(iop, frame, point, measured, sigma, refraction)
            return e, e

        warped = self.board is not None
        jacobian = jax.jacrev(row, argnums=(0, 1, 2, 3) if warped else (0, 1, 2), has_aux=True)
        n = self.image.shape[0]
        width = 6 if self.mount is None else 12
        warp = jnp.asarray(params.warp)[self.board] if warped else None
        shape = jnp.asarray(self.warp_shape) if warped else None
        blocks, residuals = jax.vmap(jacobian)(
            jnp.asarray(params.cameras[self.model])[self.camera],
            jnp.zeros((n, width), jnp.asarray(params.images).dtype),
            jnp.asarray(params.points)[self.point], warp, inputs, self.measured, self.stddev,
            shape)
        return residuals, jnp.concatenate(blocks, axis=2)

    def frame_residual(self, iop, frame, point, measured, sigma, refraction) -> Vector2:
        """Whitened residual (2,) of one row from its camera's IOPs, its image's frame
        (`AbstractPose.frame`, or a `ComposedPose`), its point, measurement and σ."""
        return _frame_collinearity_residual(
            self.model, iop, frame, point, measured, sigma, refraction, self.constants)


class ParameterObservations(AbstractObservationGroup):
    """Direct observations of parameters: control coordinates, GNSS/INS EOPs, IOP priors,
    priors on rig cameras' relative poses.

    `rows` index the block `block` ("points", "images", "mounts" or "cameras/<model>"); `observed`
    and `stddev` have the block's width, with σ = inf where an entry is not observed.
    """

    name: str = eqx.field(static=True)
    block: str = eqx.field(static=True)
    rows: Int[Array, " n"]
    observed: Float[Array, "n k"]
    stddev: Float[Array, "n k"]

    def kind(self) -> str:
        kinds = {"points": "control", "images": "gnss_ins", "mounts": "mount_priors"}
        return kinds.get(self.block, "camera_priors")

    def coordinate_names(self) -> tuple[str, ...]:
        if self.block == "points":
            return POINT_PARAMETER_NAMES
        if self.block in ("images", "mounts"):
            return IMAGE_PARAMETER_NAMES
        return CAMERA_MODELS[self.block.removeprefix("cameras/")].parameter_names

    def row_references(self) -> tuple[tuple[str, str, Int[Array, " n"]], ...]:
        label = {"points": "point", "images": "image", "mounts": "mount"}.get(
            self.block, "camera")
        return ((label, self.block, self.rows),)

    def row_blocks(self) -> tuple[tuple[str, Int[Array, " n"]], ...]:
        """The observed row of the block."""
        return ((self.block, self.rows),)

    def row_residual(self, values, row, refraction) -> Float[Array, " k"]:
        del refraction
        return (self.observed[row] - values) / self.stddev[row]

    def prior_positions(self, positions: Parameters) -> np.ndarray:
        """The positions of the observed entries (finite σ)."""
        observed = np.isfinite(np.asarray(self.stddev))
        return np.asarray(positions.block(self.block))[np.asarray(self.rows)][observed]


class Distances(AbstractObservationGroup):
    """Measured distances between object points `a` and `b` (object units)."""

    name: str = eqx.field(static=True)
    a: Int[Array, " n"]
    b: Int[Array, " n"]
    observed: Float[Array, "n 1"]
    stddev: Float[Array, "n 1"]

    def kind(self) -> str:
        return "distances"

    def coordinate_names(self) -> tuple[str, ...]:
        return ()

    def row_references(self) -> tuple[tuple[str, str, Int[Array, " n"]], ...]:
        return ("point_a", "points", self.a), ("point_b", "points", self.b)

    def row_blocks(self) -> tuple[tuple[str, Int[Array, " n"]], ...]:
        """Both end points."""
        return ("points", self.a), ("points", self.b)

    def row_residual(self, values, row, refraction) -> Float[Array, " 1"]:
        del refraction
        computed = jnp.sqrt(jnp.sum((values[:3] - values[3:]) ** 2, keepdims=True))
        return (self.observed[row] - computed) / self.stddev[row]
