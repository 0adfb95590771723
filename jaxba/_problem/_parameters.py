"""The unknowns of a bundle: camera (IOP), image (EOP), object-point, rig-mount and board-warp
blocks."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._models._cameras import CAMERA_MODELS
from .._models._poses import OpkPose

IMAGE_PARAMETER_NAMES = OpkPose.parameter_names  # the images columns of project files
POINT_PARAMETER_NAMES = ("X", "Y", "Z")
MOUNT_PARAMETER_NAMES = IMAGE_PARAMETER_NAMES  # a camera's pose in its rig's frame
WARP_PARAMETER_NAMES = ("kx", "ky")  # a board's warp (`jaxba._models._board_warp`)
ANGLE_NAMES = ("omega", "phi", "kappa")


class Parameters(eqx.Module):
    """One value per scalar unknown; the same structure also holds masks and σ.

    - `cameras`: camera model name -> (n_cameras_of_model, n_model_parameters), the
      model's `parameter_names` order, mm-based units.
    - `images`: (n_images, 6): the pose model's parameters (`BundleProblem.pose`): X0, Y0,
      Z0 (object units), omega, phi, kappa (radians) for "opk", r, t for "rodrigues".
    - `points`: (n_points, 3): X, Y, Z (object units).
    - `mounts`: (n_mounts, 6) or None (no rigs): the poses of rig cameras in their rig's
      frame, rows of the same pose model as `images` (for "opk": X0, Y0, Z0 the perspective
      centre in the rig frame, omega, phi, kappa the rotation rig -> camera). A rig image's
      pose is its frame's `images` row followed by its camera's mount (`ComposedPose`).
      None keeps a bundle without rigs free of any trace of them.
    - `warp`: (n_boards, 2) or None (flat targets): kx, ky of every board (object units),
      its points moved along its normal by kx (1 - x²) + ky (1 - y²) (`board_warp`) in the
      rows of the image-point groups that carry `board`. None: no board is warped.
    """

    cameras: dict[str, Float[Array, "n_cameras n_iop"]]
    images: Float[Array, "n_images 6"]
    points: Float[Array, "n_points 3"]
    mounts: Float[Array, "n_mounts 6"] | None = None
    warp: Float[Array, "n_boards 2"] | None = None

    def block(self, name: str) -> Array:
        """The block called "images", "points", "mounts", "warp" or "cameras/<model>"."""
        if name.startswith("cameras/"):
            return self.cameras[name.removeprefix("cameras/")]
        return getattr(self, name)


def where_free(free: Parameters, values: Parameters, fixed: Parameters) -> Parameters:
    """`values` where `free` is True, else `fixed` (elementwise over the blocks)."""
    return jax.tree.map(jnp.where, free, values, fixed)


def flatten(tree: Parameters) -> np.ndarray:
    """All entries of a Parameters tree as one NumPy vector (jax.tree leaf order)."""
    return np.concatenate([np.ravel(np.asarray(leaf)) for leaf in jax.tree.leaves(tree)])


def unflatten(like: Parameters, vector) -> Parameters:
    """Inverse of `flatten`, shaped like `like`: NumPy leaves from a NumPy `vector` (no jax
    operations, nothing to compile), jax arrays from a jax one (also under tracing)."""
    numpy = isinstance(vector, np.ndarray)
    leaves, treedef = jax.tree.flatten(like)
    out, start = [], 0
    for leaf in leaves:
        size = int(np.size(leaf))
        piece = vector[start:start + size]
        out.append(np.reshape(piece, np.shape(leaf)) if numpy
                   else jnp.reshape(jnp.asarray(piece), jnp.shape(leaf)))
        start += size
    return jax.tree.unflatten(treedef, out)


def positions_of(like: Parameters) -> Parameters:
    """A Parameters tree shaped like `like` holding each scalar's position in `flatten`
    order (NumPy leaves; `like`'s values are not read)."""
    size = sum(int(np.size(leaf)) for leaf in jax.tree.leaves(like))
    return unflatten(like, np.arange(size))


def parameter_labels(
    params: Parameters,
    camera_ids: dict[str, list[str]] | None = None,
    image_ids: list[str] | None = None,
    point_ids: list[str] | None = None,
    mount_ids: list[str] | None = None,
    board_ids: list[str] | None = None,
) -> list[str]:
    """A readable name for every scalar unknown, in `flatten` order.

    E.g. "camera C1 c", "image img03 omega", "point 12 Z", "mount stereo/right X0",
    "board board kx"; row numbers stand in for missing IDs.
    """
    def ids(given, n):
        return list(given) if given is not None else [str(i) for i in range(n)]

    def block(prefix: str, row_ids: list[str], names) -> list[str]:
        return [f"{prefix} {i} {n}" for i in row_ids for n in names]

    # The blocks in `flatten` order: cameras by sorted model name, images, points, mounts,
    # warp.
    labels = []
    for model in sorted(params.cameras):
        rows = ids((camera_ids or {}).get(model), params.cameras[model].shape[0])
        labels += block("camera", rows, CAMERA_MODELS[model].parameter_names)
    labels += block("image", ids(image_ids, params.images.shape[0]), IMAGE_PARAMETER_NAMES)
    labels += block("point", ids(point_ids, params.points.shape[0]), POINT_PARAMETER_NAMES)
    if params.mounts is not None:
        labels += block("mount", ids(mount_ids, params.mounts.shape[0]), MOUNT_PARAMETER_NAMES)
    if params.warp is not None:
        labels += block("board", ids(board_ids, params.warp.shape[0]), WARP_PARAMETER_NAMES)
    return labels
