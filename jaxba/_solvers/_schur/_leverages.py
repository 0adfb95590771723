"""The leverages of a bundle's observations from the Schur split, without a dense Jacobian or
N⁻¹, and the programs that form them with the cofactors (`_cofactors.py`).

The leverage of a whitened residual entry with Jacobian row j is j N⁻¹ jᵀ (its redundancy
number r = 1 - j N⁻¹ jᵀ).
A row depends on few unknowns, so j N⁻¹ jᵀ needs only the cofactor blocks among them: for an
image observation with blocks a (its reduced columns: IOPs, EOPs, a reduced point) and b (its
eliminated point p),

    j N⁻¹ jᵀ = a Q_rr aᵀ - 2 a G_p bᵀ + b Q_pp bᵀ,

Q_rr = S⁻¹ on the observation's reduced columns (one block per key: the same for all
observations of an image), G_p = S⁻¹ Y_p V_p⁻¹ (so that Q_rp = -G_p) and Q_pp the point's
3 x 3 cofactor block; a needs only G_p's rows at its own columns, which, as Q_pp, are sums
over the pairs of observations of the point (`_cofactors.observation_cofactors`). The rows
of the other groups need the cofactor block among their own unknowns (`row_blocks`): one
point's 3 x 3 block for control, S⁻¹ at a few reduced columns otherwise (GNSS/INS and IOP
priors, a distance's two reduced points).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._problem._bundle import BundleProblem, observation_mask
from ..._problem._parameters import Parameters
from ..._programs import stored
from .._backend import Cofactors, Leverages
from .._compiled import solver_jit
from ._assembly import compiled_normal_equations
from ._cofactors import (
    nan_where_singular,
    observation_cofactors,
    point_cofactors,
    reduced_cofactor,
)
from ._columns import free_masks, reduced_positions, row_columns, row_points
from ._jacobians import row_jacobians
from ._structure import BundleStructure


def schur_leverages(problem: BundleProblem, structure: BundleStructure, params: Parameters
                    ) -> Leverages:
    """The real observations' leverages at `params` (`structure`: the problem's
    `bundle_structure`)."""
    leverages, residuals, _ = _leverages(
        problem, structure, params, *compiled_normal_equations(problem, structure, params))
    return _real(problem, leverages, residuals)


def schur_cofactors(problem: BundleProblem, structure: BundleStructure, params: Parameters
                    ) -> Cofactors:
    """S⁻¹, every point's 3 x 3 block, the leverages and the whitened residuals at `params`,
    all from one compiled program, which forms S⁻¹ and the pair-wise cofactor blocks once
    (two programs did all that twice: block A 0.3 s and, cold, one compilation of ~3 s more;
    the residuals, a program of their own, cost 0.2 s to load in every process), from the
    normal equations of `compiled_normal_equations` (the datum check's program: compiled
    once for both)."""
    leverages, residuals, cofactor, points, squares, whitened = _cofactors_program(
        problem, structure, params, *compiled_normal_equations(problem, structure, params))
    return Cofactors(squares=float(squares),
                     reduced_positions=reduced_positions(problem, structure),
                     reduced=np.asarray(cofactor), points=np.asarray(points),
                     leverages=_real(problem, leverages, residuals), whitened=whitened)


def schur_cofactors_ahead(problem: BundleProblem, structure: BundleStructure) -> None:
    """Start compiling `schur_cofactors`' program for `problem` at parameters shaped as its
    approximations on a worker thread (`jaxba._programs.compile_ahead`), where the normal
    equations' program is ready in this process (the datum check's: its output shapes are
    read from it); else nothing."""
    normal = compiled_normal_equations.output_shapes(problem, structure, problem.initial)
    if normal is not None:
        _cofactors_program.ahead(problem, structure, problem.initial, *normal)


def _real(problem, leverages, residuals) -> Leverages:
    """`Leverages` of the real observations from the leverages and residuals per group."""
    leverage = np.concatenate([np.ravel(np.asarray(h)) for h in leverages])
    whitened = np.concatenate([np.ravel(np.asarray(e)) for e in residuals])
    real = observation_mask(problem)
    return Leverages(leverage[real], whitened[real])


@stored("schur_cofactors")
@solver_jit
def _cofactors_program(problem, structure, params, normal, reduced, point_inverse, blocks):
    """`_leverages`, eᵀe and the whitened residuals in one program."""
    leverages, residuals, (cofactor, points) = _leverages(problem, structure, params, normal,
                                                          reduced, point_inverse, blocks)
    squares = sum(jnp.sum(r**2) for r in residuals)
    # Without a robust loss the solver's residuals are the whitened ones (params are the
    # solution's, `with_free` already): not traced a second time.
    whitened = residuals if problem.robust is None else problem.whitened(params)
    return leverages, residuals, cofactor, points, squares, whitened


@eqx.filter_jit
def _leverages(problem, structure, params, normal, reduced, point_inverse, blocks):
    """Per observation group, j N⁻¹ jᵀ of every residual entry (n, k); the residuals; and
    S⁻¹ with every point's 3 x 3 cofactor block (`Cofactors.reduced`, `.points`);
    `normal`, `reduced` S, `point_inverse` V⁻¹ and `blocks`, the image observations'
    Jacobian blocks (J_r, J_e), at `params`: `compiled_normal_equations`'s."""
    dtype = normal.reduced_gradient.dtype
    cofactor, inverse = reduced_cofactor(problem, structure, normal, reduced, point_inverse)
    free_r, free_e = free_masks(problem, structure, dtype)
    jr, je = blocks
    image, eliminated = _image_leverages(structure, normal, cofactor, inverse, jr, je)
    image = jnp.zeros_like(image).at[structure.image_order].set(image)  # the groups' order
    points = point_cofactors(problem, structure, cofactor,
                             nan_where_singular(normal, eliminated))

    residuals = problem.residuals(problem.with_free(params))
    padded = jnp.pad(cofactor, ((0, 1), (0, 1)))
    eliminated_cofactors = jnp.concatenate([points[structure.eliminated_points],
                                            jnp.zeros((1, 3, 3), dtype)])
    leverages, start = [], 0
    for group in problem.groups:
        if group.kind() == "image_points":
            stop = start + group.point.shape[0]
            leverages.append(image[start:stop])
            start = stop
            continue
        # A row over a few unknowns: j Q jᵀ with Q the cofactor block among them.
        jacobian, _ = row_jacobians(problem, group, params)
        columns = row_columns(structure, group)
        reduced = jacobian * free_r[columns][:, None, :]
        block = padded[columns[:, :, None], columns[:, None, :]]
        leverage = jnp.einsum("nka,nab,nkb->nk", reduced, block, reduced)
        point = row_points(structure, group)
        if point is not None:  # on one eliminated point: its 3 x 3 block
            eliminated = jacobian * free_e[point][:, None, :]
            leverage = leverage + jnp.einsum("nka,nab,nkb->nk", eliminated,
                                             eliminated_cofactors[point], eliminated)
        leverages.append(leverage)
    return leverages, residuals, (cofactor, points)


def _image_leverages(structure, normal, cofactor, inverse, jr, je) -> tuple[Array, Array]:
    """j N⁻¹ jᵀ (n_image_obs, 2) of the image observations (see the module docstring), and
    the eliminated points' 3 x 3 cofactor blocks (n_e + 1, 3, 3) that it needs on the way."""
    padded = jnp.pad(cofactor, ((0, 1), (0, 1)))
    per_key = padded[structure.key_columns[:, :, None], structure.key_columns[:, None, :]]

    def reduced_part(jr_i, key_i):
        return jnp.einsum("ka,ab,kb->k", jr_i, per_key[key_i], jr_i)

    # One observation's m x m block at a time, vmapped over batches: never all at once.
    leverage = jax.lax.map(lambda x: reduced_part(*x), (jr, structure.key),
                           batch_size=structure.jacobian_batch)
    g, point_blocks = observation_cofactors(structure, normal, cofactor, inverse)
    k = g.shape[-1]
    # a G_p[c_i] bᵀ per residual entry: (a g_i) is (2, 3), dotted with b row by row.
    a_g = sum(jr[:, :, a, None] * g[:, None, :, a] for a in range(k))
    b_q = sum(je[:, :, c, None] * point_blocks[structure.image_point][:, None, c, :]
              for c in range(3))
    leverage = leverage + jnp.sum((b_q - 2.0 * a_g) * je, axis=2)
    return leverage[:-1], point_blocks
