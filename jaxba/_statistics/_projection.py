"""Projection uncertainty of a camera: the 2 x 2 covariance of the image point of a ray.

For an image point q (in the camera model's image units) the ray p(q) through it is found
with the adjusted parameters (`unproject`), at a distance d along it or as a direction
(d = ∞). q⁺ is the projection of that ray with perturbed unknowns; Σ_q = J Σ_z Jᵀ, J = ∂q⁺/∂z
by `jax.jacfwd`, z a handful of quantities whose covariance Σ_z comes from the adjustment's
Cxx = σ̂0² N⁻¹ (with the variance components where they were estimated):

- frame "camera": the ray fixed in the camera frame, z = the camera's parameters;
- frame "object" (default): the ray fixed in the world the camera observed. A perturbed
  solution sees the world from a camera frame moved by a small rigid motion T = (ρ, τ)
  (rotation vector, translation), which is fitted, as mrcal's cross-reprojection does, by
  weighted least squares over the camera's own observations: T ∘ p_ij ≈ p⁺_ij compared
  through the camera's projection, p_ij = M_i (X_j - X0_i) the original camera-frame points,
  p⁺_ij the perturbed solution's. To first order T = K Δθ, K = (AᵀWA)⁻¹ AᵀW [B_pose, B_point]
  (A = ∂u/∂T, B = ∂u/∂(pose, point) of the image points u, W = 1/σ²); a change of datum
  moves poses and points together and leaves T at 0, so the arbitrary object frame drops out.
  z = (the camera's parameters, T), q⁺ = project(iop⁺, T ∘ p(q)).

The Jacobians are small (one row pair per pixel, one per observation of the camera); no n x n
matrix is formed beyond what the adjustment's `Precision` holds.
"""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._models._cameras import CAMERA_MODELS, PixelGrid
from .._models._poses import POSE_MODELS, ComposedPose
from .._problem._observations import ImagePoints
from .._problem._parameters import positions_of

FRAMES = ("object", "camera")
_NEWTON_STEPS = 30  # unprojection from the principal ray; a few suffice for usual lenses


@dataclasses.dataclass(frozen=True)
class ProjectionUncertainty:
    """Σ_q of every image point `pixels` (n, 2) at `distance` (n,) (object units, inf for a
    direction): `covariance` (n, 2, 2) in the units of `pixels` squared (pixels where a pixel
    grid converted them); `frame` "object" or "camera" (module docstring)."""

    pixels: np.ndarray
    distance: np.ndarray
    covariance: np.ndarray
    frame: str

    @property
    def sigma_worst(self) -> np.ndarray:
        """(n,) σ in the worst direction: sqrt of Σ_q's largest eigenvalue."""
        return np.sqrt(np.clip(np.linalg.eigvalsh(self.covariance)[:, -1], 0, None))

    @property
    def sigma_rms(self) -> np.ndarray:
        """(n,) RMS σ over both directions: sqrt(trace(Σ_q) / 2)."""
        return np.sqrt(np.clip(np.trace(self.covariance, axis1=1, axis2=2) / 2, 0, None))


@dataclasses.dataclass(frozen=True)
class CameraRef:
    """Where camera `camera_id` lives in an adjustment: its model, row of
    `cameras[model]`, the model's constants and its image groups' indices."""

    camera_id: object
    model: str
    row: int
    constants: tuple
    groups: tuple[int, ...]


def camera_ref(result, camera_id) -> CameraRef:
    """The `CameraRef` of `camera_id` (an ID of `result.cameras`, `result` an `Adjustment`:
    not imported here, whose method this module serves); `KeyError` naming the cameras
    there is when it is none of them."""
    for model, ids in result._ids.cameras.items():
        if camera_id in ids:
            row = list(ids).index(camera_id)
            groups = tuple(k for k, g in enumerate(result.problem.groups)
                           if g.kind() == "image_points" and g.model == model)
            constants = result.problem.groups[groups[0]].constants if groups else ()
            return CameraRef(camera_id, model, row, constants, groups)
    known = [i for ids in result._ids.cameras.values() for i in ids]
    raise KeyError(f"camera {camera_id!r}: not a camera of this adjustment (cameras: {known})")


def _camera(model: str, constants: tuple, iop):
    return CAMERA_MODELS[model].from_parameters(iop, **dict(constants))


def _moved(p: Float[Array, "3"], motion: Float[Array, "6"], finite) -> Float[Array, "3"]:
    """T ∘ p to first order, p + ρ × p + τ, motion = (ρ, τ); τ only for a finite point."""
    return p + jnp.cross(motion[:3], p) + jnp.where(finite, 1.0, 0.0) * motion[3:]


def projected(model: str, constants: tuple, iop, p: Float[Array, "3"],
              start: Float[Array, "2"], steps: int = 3) -> Float[Array, "2"]:
    """The image point of the camera-frame point `p`: the q with q = image_point(p, q) (a
    model of the photogrammetric convention evaluates its corrections at the point itself),
    by Newton steps from `start`; exact in value and first derivative when `start` is the
    solution at the unperturbed parameters."""
    camera = _camera(model, constants, iop)

    def image(q):
        return camera.image_point(p, q, 0.0)

    q = start
    for _ in range(steps):
        step = jnp.linalg.solve(jnp.eye(2) - jax.jacfwd(image)(q), q - image(q))
        q = q - step
    return q


def unproject(model: str, constants: tuple, iop, q: Float[Array, "2"]) -> Float[Array, "3"]:
    """The unit camera-frame direction (x, y, -1)/norm whose image point is `q` (Newton on
    (x, y) from the principal ray); NaN where it does not converge."""
    camera = _camera(model, constants, iop)

    def image(xy):
        return camera.image_point(jnp.array([xy[0], xy[1], -1.0]), q, 0.0)

    def step(_, xy):
        return xy - jnp.linalg.solve(jax.jacfwd(image)(xy), image(xy) - q)

    xy = jax.lax.fori_loop(0, _NEWTON_STEPS, step, jnp.zeros(2))
    scale = jnp.maximum(jnp.max(jnp.abs(q)), 1.0)
    good = jnp.all(jnp.abs(image(xy) - q) <= 1e-9 * scale)
    ray = jnp.array([xy[0], xy[1], -1.0])
    return jnp.where(good, ray / jnp.linalg.norm(ray), jnp.nan)


@eqx.filter_jit
def _pixel_jacobians(model, constants, iop, pixels, distance):
    """∂q⁺/∂(iop, T) (n, 2, n_iop + 6) of every image point `pixels` (n, 2) at `distance`
    (n,) (inf: a direction), in the model's image units."""

    def one(q, d):
        finite = jnp.isfinite(d)
        p = unproject(model, constants, iop, q) * jnp.where(finite, d, 1.0)

        def q_plus(iop_plus, motion):
            return projected(model, constants, iop_plus, _moved(p, motion, finite), q)

        return jnp.concatenate(jax.jacfwd(q_plus, argnums=(0, 1))(iop, jnp.zeros(6)), axis=1)

    return jax.vmap(one)(pixels, distance)


def camera_frame(pose: str, eop: Float[Array, " k"]):
    """A camera's frame (`to_camera`, `station`) from its row of pose parameters (the pose
    model `pose`): (6,) an image's pose, or (12,) a mounted camera's frame pose then its
    pose in the rig or on the platform (`ComposedPose`)."""
    poses = POSE_MODELS[pose]
    if eop.shape[0] == 12:
        return ComposedPose(poses.from_parameters(eop[:6]), poses.from_parameters(eop[6:]))
    return poses.from_parameters(eop)


def camera_rows(params, group: ImagePoints, rows: np.ndarray) -> np.ndarray:
    """(n, 6) or (n, 12): the pose parameters of each of `rows` of `group` (`camera_frame`):
    its image's, then its mount's where the group has mounts."""
    eops = np.asarray(params.images)[np.asarray(group.image)[rows]]
    if group.mount is None:
        return eops
    return np.concatenate([eops, np.asarray(params.mounts)[np.asarray(group.mount)[rows]]],
                          axis=1)


@eqx.filter_jit
def _frame_fit_blocks(model, constants, pose, iop, eops, points, measured, sigma):
    """Per observation of the camera: AᵀWA (6, 6), AᵀW B_pose (6, k), AᵀW B_point (6, 3)
    of the image point u = image_point(T ∘ p, measured), p the point in the camera frame
    (module docstring). `eops` (n, k): each row's image pose (k = 6), or a mounted camera's
    frame pose then mount (k = 12: its camera frame is the frame's followed by the mount's,
    `ComposedPose`)."""
    camera = _camera(model, constants, iop)

    def one(eop, point, m, s):
        def u(motion, eop_, point_):
            p = camera_frame(pose, eop_).to_camera(point_)
            return camera.image_point(_moved(p, motion, True), m, 0.0)

        a, b_pose, b_point = jax.jacfwd(u, argnums=(0, 1, 2))(jnp.zeros(6), eop, point)
        aw = a.T / s**2
        return aw @ a, aw @ b_pose, aw @ b_point

    return jax.vmap(one)(eops, points, measured, sigma)


def _frame_map(result, ref: CameraRef, positions) -> tuple[np.ndarray, np.ndarray]:
    """(L, cols): z = (Δiop, T) = L Δθ over the unknowns at `flatten` positions `cols`
    (the camera's parameters, its images' poses (a mounted camera's: its frames' and its
    mount's), the points they observe; points left out where the adjustment eliminated them
    and holds no cross-covariances)."""
    params, problem = result.parameters, result.problem
    iop = np.asarray(params.cameras[ref.model][ref.row])
    normal, by_pose, by_mount, by_point = np.zeros((6, 6)), {}, {}, {}
    for k in ref.groups:
        group = problem.groups[k]
        rows = np.flatnonzero((np.asarray(group.camera) == ref.row)
                              & np.all(np.asarray(group.mask()), axis=1))
        if rows.size == 0:
            continue
        images, points = np.asarray(group.image)[rows], np.asarray(group.point)[rows]
        eops = camera_rows(params, group, rows)
        mounts = None if group.mount is None else np.asarray(group.mount)[rows]
        a, b_pose, b_point = (np.asarray(x) for x in _frame_fit_blocks(
            ref.model, ref.constants, group.pose, jax.device_put(iop), jax.device_put(eops),
            jax.device_put(np.asarray(params.points)[points]),
            np.asarray(group.measured)[rows], np.asarray(group.stddev)[rows]))
        normal += a.sum(axis=0)
        parts = [(images, b_pose[:, :, :6], by_pose), (points, b_point, by_point)]
        if mounts is not None:
            parts.append((mounts, b_pose[:, :, 6:], by_mount))
        for index, blocks, store in parts:
            for j in np.unique(index):
                store[j] = store.get(j, 0.0) + blocks[index == j].sum(axis=0)
    if not by_pose:
        raise ValueError(f"camera {ref.camera_id!r}: no image points, so no frame to carry"
                         " (use frame='camera')")
    with_points = result.precision.covariance is not None
    pieces = [(np.asarray(positions.images[j]), m) for j, m in sorted(by_pose.items())]
    pieces += [(np.asarray(positions.mounts[j]), m) for j, m in sorted(by_mount.items())]
    if with_points:
        pieces += [(np.asarray(positions.points[j]), m) for j, m in sorted(by_point.items())]
    cols = np.concatenate([np.asarray(positions.cameras[ref.model][ref.row])]
                          + [c for c, _ in pieces])
    gain = np.linalg.solve(normal, np.concatenate([m for _, m in pieces], axis=1))
    n_iop = iop.size
    mapping = np.zeros((n_iop + 6, cols.size))
    mapping[:n_iop, :n_iop] = np.eye(n_iop)
    mapping[n_iop:, n_iop:] = gain
    return mapping, cols


def projection_uncertainty(
    result,
    camera,
    pixels: Float[np.ndarray, "n 2"],
    distance: float | Float[np.ndarray, " n"] = math.inf,
    *,
    frame: str = "object",
    grid: PixelGrid | None = None,
) -> ProjectionUncertainty:
    """Σ_q of the image points `pixels` of camera `camera` (its ID) at `distance` (module
    docstring).

    `pixels` (n, 2) are in the camera model's image units (pixels for a pixel model, mm
    for a photogrammetric one), or pixels (col, row) when the mm model's `grid` is given,
    and Σ_q is then in pixels². `distance`: object units along the ray from the
    perspective centre, one for all or one per point; inf (default) for a direction.
    `frame`: "object" (default) or "camera" (intrinsics only).
    """
    if frame not in FRAMES:
        raise ValueError(f"frame {frame!r}: one of {FRAMES}")
    ref = camera_ref(result, camera)
    pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
    distance = np.broadcast_to(np.asarray(distance, dtype=float), pixels.shape[:1]).copy()
    if np.any(distance <= 0):
        raise ValueError("distance: must be > 0 (inf for a direction)")
    image = pixels if grid is None else np.asarray(grid.pixel_to_image(pixels))
    iop = np.asarray(result.parameters.cameras[ref.model][ref.row])
    jacobians = np.asarray(_pixel_jacobians(ref.model, ref.constants, jax.device_put(iop),
                                            jax.device_put(image), jax.device_put(distance)))
    positions = positions_of(result.parameters)
    if frame == "camera":
        jacobians = jacobians[:, :, :iop.size]
        covariance = result.precision.covariance_of(
            np.asarray(positions.cameras[ref.model][ref.row]))
    else:
        mapping, cols = _frame_map(result, ref, positions)
        covariance = mapping @ result.precision.covariance_of(cols) @ mapping.T
    sigma_q = np.einsum("nij,jk,nlk->nil", jacobians, covariance, jacobians)
    if grid is not None:
        scale = np.array([1.0, -1.0]) / np.asarray(grid.pixel_size)
        sigma_q = sigma_q * scale[:, None] * scale[None, :]
    return ProjectionUncertainty(pixels, distance, sigma_q, frame)


def sensor_grid(sensor: tuple[int, int], n_columns: int = 40) -> Float[np.ndarray, "n 2"]:
    """Pixel centres (col, row) of an evenly spaced grid over a sensor (ncols, nrows), about
    `n_columns` across, rows in proportion; the corners' pixels included."""
    width, height = int(sensor[0]), int(sensor[1])
    n_rows = max(2, round(n_columns * height / width))
    cols, rows = np.linspace(0, width - 1, n_columns), np.linspace(0, height - 1, n_rows)
    return np.stack(np.meshgrid(cols, rows), axis=-1).reshape(-1, 2)
