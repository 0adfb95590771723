"""Between the Schur split's columns and a `Parameters` tree: reduced vectors, free masks,
flat positions, every row's reduced columns, and sums and gathers at the image
observations' reduced columns."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..._problem._bundle import BundleProblem
from ..._problem._observations import AbstractObservationGroup
from ..._problem._parameters import Parameters, positions_of
from ._structure import BundleStructure


def reduced_vector(
    structure: BundleStructure, params: Parameters, xp=jnp
) -> Float[Array, " n_r"]:
    """The reduced-side entries of a Parameters tree (values, masks) as one vector; `xp`
    numpy for a tree of NumPy arrays (no program compiled)."""
    parts = [xp.ravel(params.cameras[model]) for model in structure.models]
    parts += [xp.ravel(params.images)]
    parts += [] if params.mounts is None else [xp.ravel(params.mounts)]
    parts += [xp.ravel(params.points[structure.reduced_points])]
    return xp.concatenate(parts).astype(params.images.dtype)


def to_parameters(
    structure: BundleStructure, like: Parameters, reduced: Array, eliminated: Array
) -> Parameters:
    """Inverse of the split: reduced (n_r,) and eliminated (n_e, 3) into a Parameters tree."""
    cameras = {}
    for model, offset in zip(structure.models, structure.camera_offsets):
        shape = like.cameras[model].shape
        cameras[model] = reduced[offset : offset + int(np.prod(shape))].reshape(shape)
    n_images = like.images.shape[0]
    images = reduced[structure.image_offset : structure.image_offset + 6 * n_images]
    mounts = None
    if like.mounts is not None:
        mounts = reduced[structure.mount_offset:structure.mount_offset + like.mounts.size]
        mounts = mounts.reshape(like.mounts.shape)
    points = jnp.zeros_like(like.points)
    points = points.at[structure.eliminated_points].set(eliminated)
    start = structure.mount_offset + (0 if like.mounts is None else like.mounts.size)
    points = points.at[structure.reduced_points].set(reduced[start:].reshape(-1, 3))
    return Parameters(cameras=cameras, images=images.reshape(n_images, 6), points=points,
                      mounts=mounts)


def free_masks(problem: BundleProblem, structure: BundleStructure, dtype) -> tuple[Array, Array]:
    """1.0 on free unknowns: reduced columns (n_r + 1,) and eliminated points (n_e + 1, 3),
    each with a padding entry 0."""
    free_r = jnp.append(reduced_vector(structure, problem.free), 0.0).astype(dtype)
    free_e = problem.free.points.astype(dtype)[structure.eliminated_points]
    return free_r, jnp.concatenate([free_e, jnp.zeros((1, 3), dtype)])

def row_columns(structure: BundleStructure, group: AbstractObservationGroup) -> Int[Array, "n w"]:
    """(n, width) the reduced column of every unknown a row of `group` depends on (its
    `row_blocks`, in `local_values` order): a tied IOP's source's column; n_r (padding) at
    an eliminated point's coordinates. For the groups other than image points, whose
    blocks are summed into U one row at a time."""
    parts = []
    for block, index in group.row_blocks():
        index = jnp.asarray(index)[:, None]
        if block == "points":
            column = structure.point_column[index]
            parts.append(jnp.where(column >= 0, column + jnp.arange(3), structure.n_reduced))
        elif block in ("images", "mounts"):
            start = structure.image_offset if block == "images" else structure.mount_offset
            parts.append(start + index * 6 + jnp.arange(6))
        else:
            model = structure.models.index(block.removeprefix("cameras/"))
            width = structure.camera_widths[model]
            parts.append(structure.camera_column[
                structure.camera_offsets[model] + index * width + jnp.arange(width)])
    return jnp.concatenate(parts, axis=1)


def row_points(structure: BundleStructure, group: AbstractObservationGroup) -> Array | None:
    """(n,) the eliminated point (row of V; n_e for a reduced point) of every row of a group
    whose rows each depend on one point alone (control), or None: a row that couples a
    point with other unknowns has it on the reduced side (`bundle_structure`)."""
    blocks = group.row_blocks()
    if len(blocks) != 1 or blocks[0][0] != "points":
        return None
    return structure.eliminated_index[jnp.asarray(blocks[0][1])]


def reduced_positions(problem: BundleProblem, structure: BundleStructure) -> np.ndarray:
    """(n_r,) `flatten` positions of the reduced columns."""
    positions = positions_of(problem.initial)
    return reduced_vector(structure, positions, np).astype(int)


def add_at_columns(
    structure: BundleStructure, per_observation: Float[Array, "n_obs1 w"]
) -> Float[Array, " n_r1"]:
    """Σ_i per_observation_i added at observation i's first w reduced columns, (n_r + 1,)
    (last: padding): summed per key first (observations of one key share their columns),
    then n_keys rows scattered, not n_obs (a scatter-add of every observation's entries
    into a short vector runs serially on the CPU)."""
    width = per_observation.shape[1]
    per_key = jax.ops.segment_sum(per_observation, structure.key, structure.key_columns.shape[0])
    zero = jnp.zeros(structure.n_reduced + 1, per_observation.dtype)
    return zero.at[structure.key_columns[:, :width]].add(per_key)


def at_columns(structure: BundleStructure, x_padded: Float[Array, " n_r1"]) -> Array:
    """(n_obs1, m) the entries of `x_padded` (n_r + 1,) at every image observation's
    reduced columns, gathered per key, then a row per observation."""
    return x_padded[structure.key_columns][structure.key]

