"""Derived quantities of rigs: the baseline of a rig camera, and an image's pose composed from
its frame's and its camera's relative pose, each with its σ propagated from the covariance of
the unknowns it is computed from (σ_f² = ∇fᵀ C ∇f)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models._poses import POSE_MODELS, ComposedPose
from .._problem._parameters import Parameters, positions_of


def baseline(params: Parameters, precision, row: int) -> tuple[float, float]:
    """|X0_c| of mount `row` (the distance of the camera's perspective centre from its rig's
    reference camera's, object units) and its σ from the 3 x 3 covariance of X0_c
    (`Precision.covariance_of`): σ² = uᵀ C u, u = X0_c / |X0_c|. Needs an "opk"-like pose
    whose first three parameters are the centre (the projects' "opk")."""
    positions = positions_of(params).mounts[row, :3]
    centre = np.asarray(params.mounts, dtype=float)[row, :3]
    length = float(np.linalg.norm(centre))
    direction = centre / length if length > 0 else np.zeros(3)
    covariance = np.asarray(precision.covariance_of(np.asarray(positions)), dtype=float)
    return length, float(np.sqrt(max(direction @ covariance @ direction, 0.0)))


def composed_poses(params: Parameters, pose: str, frames: np.ndarray, mounts: np.ndarray
                   ) -> np.ndarray:
    """(n, 6) pose rows of the images taken in `frames` (n,) (rows of `images`) with the
    cameras `mounts` (n,) (rows of `mounts`): the frame's pose followed by the mount."""
    if len(frames) == 0:
        return np.zeros((0, 6))
    return np.asarray(_composed(jax.device_put(np.asarray(params.images)[frames]),
                                jax.device_put(np.asarray(params.mounts)[mounts]), pose))


def composed_pose_sigma(params: Parameters, precision, pose: str, frame: int, mount: int
                        ) -> np.ndarray:
    """(6,) σ of the composed pose of one image (`composed_poses`), propagated from the
    12 x 12 covariance of its frame's and its camera's relative pose."""
    positions = positions_of(params)
    index = np.concatenate([np.asarray(positions.images)[frame],
                            np.asarray(positions.mounts)[mount]])
    covariance = np.asarray(precision.covariance_of(index), dtype=float)
    values = np.concatenate([np.asarray(params.images)[frame], np.asarray(params.mounts)[mount]])
    jacobian = np.asarray(_composed_jacobian(jax.device_put(values), pose))
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jacobian, covariance, jacobian), 0.0))


def _compose(values, pose: str):
    model = POSE_MODELS[pose]
    composed = ComposedPose(model.from_parameters(values[:6]).frame(),
                            model.from_parameters(values[6:]).frame())
    return model.from_rotation(composed.rotation(), composed.station()).parameters()


@eqx.filter_jit
def _composed(frames, mounts, pose: str):
    return jax.vmap(lambda f, m: _compose(jnp.concatenate([f, m]), pose))(frames, mounts)


@eqx.filter_jit
def _composed_jacobian(values, pose: str):
    return jax.jacfwd(lambda v: _compose(v, pose))(values)
