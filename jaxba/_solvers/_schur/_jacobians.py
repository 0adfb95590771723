"""Jacobian blocks of a bundle's rows in the Schur split: image observations over their
reduced columns and their eliminated point, the rows of other groups over their unknowns;
products of per-observation blocks."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._models._poses import POSE_MODELS
from ..._problem._bundle import BundleProblem
from ..._problem._observations import AbstractObservationGroup, ImagePoints, row_pose
from ..._problem._parameters import Parameters
from ._structure import BundleStructure


def gram(a: Float[Array, "n k i"], b: Float[Array, "n k j"]) -> Float[Array, "n i j"]:
    """aᵀb per observation, the short sum over the residual entries k written out."""
    return sum(a[:, k, :, None] * b[:, k, None, :] for k in range(a.shape[1]))


def transposed_product(a: Float[Array, "n k i"], e: Float[Array, "n k"]) -> Float[Array, "n i"]:
    """aᵀe per observation (a Jacobian block times its residual: the gradient part)."""
    return jnp.sum(a * e[:, :, None], axis=1)


def image_blocks(
    problem: BundleProblem,
    structure: BundleStructure,
    params: Parameters,
    free_r: Array,
    free_e: Array,
) -> tuple[Float[Array, "n_obs1 2 m"], Float[Array, "n_obs1 2 3"], Float[Array, "n_obs1 2"]]:
    """jr, je and e (`_image_jacobian_blocks`) of all image observations in the structure's
    order, with a zero padding row last; `structure.jacobian_batch` observations are
    differentiated at a time (`jax.lax.scan`). Memory O(n_obs m), as W's."""
    params = problem.with_free(params)
    dtype = params.images.dtype
    free_keys = free_r[structure.key_columns]  # (n_keys, m): observations of a key share it
    parts, start = [], 0
    for group in problem.groups:
        if group.kind() != "image_points":
            continue
        stop = start + group.point.shape[0]

        def blocks(_, chunk, group=group):
            return None, _image_jacobian_blocks(
                problem, structure, group, params, free_keys, free_e, list(chunk))

        _, out = jax.lax.scan(blocks, None, _image_group_chunks(structure, group, start, stop))
        parts.append([x.reshape(-1, *x.shape[2:])[: stop - start] for x in out])
        start = stop
    padding = [jnp.zeros((1, 2, structure.m), dtype), jnp.zeros((1, 2, 3), dtype),
               jnp.zeros((1, 2), dtype)]
    return tuple(jnp.concatenate([*(p[i] for p in parts), padding[i]]) for i in range(3))


def _image_group_chunks(structure: BundleStructure, group: ImagePoints, start: int, stop: int):
    """One ImagePoints group's observations (camera, image, point, measured, σ, mask,
    eliminated-point row, key, and the mount where the group has one), rows
    `start`..`stop` of the structure (the group's observations in `image_order`), in chunks
    of `structure.jacobian_batch` (n_chunks, batch, ...); padding repeats the last
    observation, masked out, with out-of-range point row and key."""
    n = stop - start
    batch = max(1, min(structure.jacobian_batch, n))
    pad = -n % batch
    rows = structure.image_order[start:stop] - start

    def chunked(x, fill=None):
        widths = [(0, pad)] + [(0, 0)] * (x.ndim - 1)
        if fill is None:
            x = jnp.pad(x, widths, mode="edge")
        else:
            x = jnp.pad(x, widths, constant_values=fill)
        return x.reshape(-1, batch, *x.shape[1:])

    mount = () if group.mount is None else (chunked(group.mount[rows]),)
    return (
        chunked(group.camera[rows]),
        chunked(group.image[rows]),
        chunked(group.point[rows]),
        chunked(group.measured[rows]),
        chunked(group.stddev[rows]),
        chunked(group.mask()[rows], False),
        chunked(structure.image_point[start:stop], structure.eliminated_points.shape[0]),
        chunked(structure.key[start:stop], structure.key_columns.shape[0]),
        *mount,
    )


def _image_jacobian_blocks(
    problem: BundleProblem,
    structure: BundleStructure,
    group: ImagePoints,
    params: Parameters,
    free_keys: Array,
    free_e: Array,
    observations: list[Array],
) -> tuple[Float[Array, "n 2 m"], Float[Array, "n 2 3"], Float[Array, "n 2"]]:
    """Jacobian blocks of a batch of one group's observations (`_image_group_chunks`
    rows) at `params` (all values set): jr over the observation's reduced columns (a
    reduced point's columns included), je over its eliminated point (0 for a reduced
    one), both 0 in fixed columns (`free_keys`: 1.0 on the free columns of every key;
    `free_e` as `free_masks`'), and e. The residual differentiated is the one
    the solver minimises: whitened, masked, robustified (`BundleProblem.residuals`).
    Only the IOPs in `structure.iop_columns` are differentiated. The image's pose enters
    through its pose model's `row_frame` (from `row_inputs`, made once per image),
    differentiated by the parameter offset δ at δ = 0."""
    camera, image, point, measured, sigma, mask, point_row, key, *mount = observations
    iop_columns = np.asarray(structure.iop_columns[structure.models.index(group.model)], int)
    m, n_iop = structure.m, iop_columns.size
    all_iops = n_iop == params.cameras[group.model].shape[1]
    dtype = params.images.dtype
    pose = POSE_MODELS[group.pose]

    width = 12 if mount else 6

    def residual(free_iop, delta, point, iop, pose_inputs, data):
        iop = free_iop if all_iops else iop.at[iop_columns].set(free_iop)
        e = group.frame_residual(iop, row_pose(pose, pose_inputs, delta, bool(mount)), point,
                                 *data[:2], problem.refraction)
        e = jnp.where(data[2], e, 0.0)
        e = e if problem.robust is None else problem.robust(e)
        return e, e

    def one(iop, pose_inputs, point, *data):
        arguments = (iop[iop_columns], jnp.zeros(width, dtype), point, iop, pose_inputs, data)
        (j_iop, j_pose, j_point), e = jax.jacrev(residual, argnums=(0, 1, 2), has_aux=True)(
            *arguments)
        return jnp.concatenate([j_iop, j_pose], axis=1), j_point, e

    pose_inputs = jax.tree.map(lambda x: x.at[image].get(mode="clip"),
                               pose.row_inputs(params.images))
    if mount:
        mount_inputs = pose.row_inputs(params.mounts)
        pose_inputs = (pose_inputs,
                       jax.tree.map(lambda x: x.at[mount[0]].get(mode="clip"), mount_inputs))
    jc, jp, e = jax.vmap(one)(
        params.cameras[group.model].at[camera].get(mode="clip"),
        pose_inputs,
        params.points.at[point].get(mode="clip"),
        measured,
        sigma,
        mask,
    )
    mask = mask.astype(dtype)[:, :, None]
    jc, jp, e = jc * mask, jp * mask, e * mask[:, :, 0]
    reduced_point = (point_row == structure.eliminated_points.shape[0])[:, None, None]
    padding = jnp.zeros((*jc.shape[:2], m - structure.point_width - n_iop - width), dtype)
    point_part = [jnp.where(reduced_point, jp, 0.0)] if structure.point_width else []
    jr = jnp.concatenate([jc, padding, *point_part], axis=-1)
    jr = jr * free_keys.at[key].get(mode="fill", fill_value=0.0)[:, None, :]
    je = jnp.where(reduced_point, 0.0, jp) * free_e[point_row][:, None, :]
    return jr, je, e


def row_jacobians(
    problem: BundleProblem, group: AbstractObservationGroup, params: Parameters
) -> tuple[Float[Array, "n k w"], Float[Array, "n k"]]:
    """d e / d (a row's unknowns, `row_blocks` order) (n, k, w) and e (n, k) of every row of a
    group other than image points, by the group's own `row_jacobians`, 0 on the entries
    that are not observations; not robustified (`BundleProblem.residuals`)."""
    residuals, jacobians = group.row_jacobians(problem.with_free(params), problem.refraction)
    mask = group.mask()
    return jnp.where(mask[:, :, None], jacobians, 0.0), jnp.where(mask, residuals, 0.0)
