"""The adjusted bundle as a differentiable function of its data.

`adjusted(problem)` returns the least-squares solution x̂(θ) of a BundleProblem as a jax
function of every array in the problem θ: image measurements, control coordinates, prior
values, σ. Derivatives come from the implicit function theorem at the optimum,
g(x̂, θ) = ∇ₓ ½‖e(x, θ)‖² = 0  ⇒  dx̂/dθ = -H⁻¹ ∂g/∂θ,  H = ∂g/∂x (the full Hessian, not
only JᵀJ): no differentiation through the iterations. Two backends, chosen as `adjust`
chooses (`use_schur`; `backend=`):

- dense (calibrations, batches; vmappable): `optx.least_squares` with
  `adjoint=optx.ImplicitAdjoint()`, the linear solver dense QR on the (n_free, n_free)
  Hessian of the Jacobi-scaled unknowns. The Jacobi column scale of the solver is held
  constant (`stop_gradient`): the optimum does not depend on it, so its derivative would
  only cancel.
- Schur (blocks): the Schur backend's Levenberg-Marquardt forward, and H v = w solved by
  conjugate gradients on the matrix-free Hessian (Hessian-vector products), preconditioned
  by the Gauss-Newton matrix JᵀJ at x̂ through the Schur split (`jaxba._solvers._schur._adjoint`):
  no n x n matrix and no Jacobian, the largest arrays those of the Schur solve (the reduced
  camera matrix). Not vmappable (its split is NumPy).

Only gauge-invariant outputs are meaningful: with a datum defect the solution is not a
function of θ. With a fixed datum (control, fixed coordinates) all unknowns are. The
network-design functions (`covariance`, `iop_trace_gradient`) stay dense.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, Int

from .._models._cameras import CAMERA_MODELS
from .._problem._bundle import BundleProblem, free_indices, params_from_free
from .._problem._linearisation import LinearisationPlan, linearisation_plan
from .._problem._parameters import Parameters, flatten, unflatten
from .._solvers._dense import Dense, cofactors
from .._solvers._schur._adjoint import schur_adjusted
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import BundleStructure, bundle_structure
from .._solvers._solve import choose_backend, solve


def adjusted(
    problem: BundleProblem,
    plan: LinearisationPlan | None = None,
    *,
    max_steps: int = 100,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    backend: str = "auto",
    structure: BundleStructure | None = None,
) -> Parameters:
    """The adjusted Parameters x̂(θ), differentiable w.r.t. every array of `problem`.

    Levenberg-Marquardt as in `solve`, with an implicit adjoint. Tolerances default
    tighter than `solve`'s, since a derivative is only as good as the optimality of x̂.
    `backend`: "dense" (dense QR on the Hessian of the scaled unknowns; vmappable),
    "schur" (the Schur backend's solve, CG preconditioned through the Schur split:
    `jaxba._solvers._schur._adjoint`) or "auto" (`choose_backend`: as `adjust` chooses
    where the problem's values are known, outside `jax.jit` / `jax.vmap`, `jax.grad` and
    friends included; "dense" under a transformation that traces them). `plan` =
    `linearisation_plan(problem)` (static structure as arrays, so it can vmap) for the dense
    path, `structure` = `bundle_structure(problem)` for the Schur path (not vmappable);
    each computed here when not given.
    """
    if isinstance(choose_backend(problem, backend), Schur):
        structure = bundle_structure(problem) if structure is None else structure
        return schur_adjusted(problem, structure, max_steps=max_steps, rtol=rtol, atol=atol)[0]
    if plan is None:
        plan = linearisation_plan(problem)
    return _adjusted(problem, plan, max_steps=max_steps, rtol=rtol, atol=atol)


@eqx.filter_jit
def _adjusted(problem, plan, *, max_steps, rtol, atol) -> Parameters:
    adjoint = optx.ImplicitAdjoint(linear_solver=lx.QR())
    return solve(problem, Dense(plan), max_steps=max_steps, rtol=rtol, atol=atol,
                 adjoint=adjoint).parameters


def covariance(
    problem: BundleProblem,
    params: Parameters,
    free_index: Int[Array, " n_free"],
    *,
    sigma0: float | Float[Array, ""] = 1.0,
) -> Float[Array, "n_free n_free"]:
    """Predicted covariance σ0² (JᵀJ)⁻¹ of the free unknowns at `params`, as a jax function.

    J is the whitened Jacobian at `params`: for network design, `params` holds the planned
    (true) geometry and σ0 the a priori variance factor; for a posteriori precision pass
    σ̂0. Differentiable w.r.t. `params` (second derivatives of the model) and the σ in
    `problem`. Dense Cholesky on the column-equilibrated normal matrix (`cofactors`).
    """
    at = eqx.tree_at(lambda p: p.initial, problem, params)

    def whitened(x_free):
        values = params_from_free(at, x_free, free_index)
        return jnp.concatenate([jnp.ravel(e) for e in problem.whitened(values)])

    x_free = ravel_pytree(params)[0][free_index]
    jacobian = jax.jacfwd(whitened)(x_free)
    return sigma0**2 * cofactors(jacobian.T @ jacobian)


def camera_positions(problem: BundleProblem, model: str, row: int = 0):
    """Positions within the free vector (`free_indices` order) of the free IOPs of camera
    `row` of `model`, and their parameter names."""
    index = free_indices(problem)
    marker = jax.tree.map(lambda leaf: np.zeros(np.shape(leaf)), problem.initial)
    camera = np.zeros(np.shape(problem.initial.cameras[model]))
    camera[row] = 1 + np.arange(camera.shape[1])
    marker = unflatten(problem.initial, flatten(eqx.tree_at(
        lambda p: p.cameras[model], marker, camera)))
    flat = flatten(marker)[index]
    positions = np.flatnonzero(flat > 0)
    names = [CAMERA_MODELS[model].parameter_names[int(flat[p]) - 1] for p in positions]
    return positions, names


def sensitivity(
    problem: BundleProblem,
    *,
    group: int = 0,
    model: str | None = None,
    row: int = 0,
    backend: str = "auto",
    **solver_options,
) -> tuple[Float[Array, "n_iop n_obs 2"], list[str]]:
    """d(adjusted IOPs)/d(image coordinates) of the ImagePoints group `group`.

    Returns (S, names): S[i, k, j] = ∂ IOP_i / ∂ measured[k, j] for the free IOPs of camera
    `row` of `model` (default: the group's model), units IOP unit per image unit. External
    reliability: a blunder ∇ in observation (k, j) moves IOP i by S[i, k, j] ∇ (to first
    order); S ∇ with ∇ the MDB gives the IOPs' external reliability. One reverse pass per
    IOP through the implicit adjoint (jax.jacrev); `backend` and `solver_options` as for
    `adjusted` (on a block "auto" takes the Schur backend).
    """
    model = model if model is not None else problem.groups[group].model
    schur = isinstance(choose_backend(problem, backend), Schur)
    backend = "schur" if schur else "dense"
    split = ({"structure": bundle_structure(problem)} if schur
             else {"plan": linearisation_plan(problem)})

    def iops(measured):
        moved = eqx.tree_at(lambda p: p.groups[group].measured, problem, measured)
        return adjusted(moved, backend=backend, **split, **solver_options).cameras[model][row]

    _, names = camera_positions(problem, model, row)
    keep = jnp.asarray([CAMERA_MODELS[model].parameter_names.index(n) for n in names])
    return jax.jacrev(iops)(problem.groups[group].measured)[keep], names


def iop_trace_gradient(
    problem: BundleProblem,
    params: Parameters,
    *,
    model: str | None = None,
    row: int = 0,
    sigma0: float = 1.0,
    weights: Float[Array, " n_iop"] | None = None,
) -> tuple[Float[Array, ""], Float[Array, "n_images 3"]]:
    """Network design: trace(W C_IOP) and its gradient w.r.t. the camera-station positions.

    C_IOP is the block of `covariance(problem, params)` of the free IOPs of camera `row`
    (the planned geometry `params`, a priori σ0); `weights` (one per free IOP, default 1)
    weigh it, e.g. 1/c² for relative precision. The gradient (n_images, 3) says how to
    move every station X0, Y0, Z0 to make the IOPs more precise (descent: minus it).
    """
    model = model if model is not None else sorted(problem.initial.cameras)[0]
    index = jnp.asarray(free_indices(problem))
    positions, _ = camera_positions(problem, model, row)
    positions = jnp.asarray(positions)
    w = jnp.ones(positions.shape[0]) if weights is None else jnp.asarray(weights)
    return _trace_and_gradient(problem, params, index, positions, w, jnp.asarray(sigma0))


@eqx.filter_jit  # once per problem structure (eagerly, every call took seconds)
def _trace_and_gradient(problem, params, index, positions, w, sigma0):
    def objective(stations):
        images = jnp.asarray(params.images).at[:, :3].set(stations)
        moved = eqx.tree_at(lambda p: p.images, params, images)
        c = covariance(problem, moved, index, sigma0=sigma0)
        return jnp.sum(w * jnp.diag(c)[positions])

    return jax.value_and_grad(objective)(params.images[:, :3])


__all__ = ["adjusted", "camera_positions", "covariance", "iop_trace_gradient", "sensitivity"]
