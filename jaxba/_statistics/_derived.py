"""Derived precision: correlations, object-point ellipsoids, propagation to functions.

All work on an `Adjustment` through `precision.covariance_of` (Cxx among unknowns given by
their `flatten` positions; fixed unknowns have zero variance), so they serve bundles
adjusted densely and with their points eliminated alike (`full_covariance` excepted).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._models._cameras import CAMERA_MODELS
from .._problem._parameters import Parameters, flatten, positions_of, unflatten
from ._adjustment import Adjustment


def full_covariance(result: Adjustment) -> np.ndarray:
    """Cxx over *all* unknowns in `flatten` order, zero rows/columns for fixed ones (dense
    adjustments only: n x n)."""
    return result.precision.covariance_of(np.arange(flatten(result.parameters).size))


def correlation(covariance: np.ndarray) -> np.ndarray:
    """Correlation matrix ρ_ij = C_ij / (σ_i σ_j); 0 where a σ is 0."""
    std = np.sqrt(np.diag(covariance))
    scale = np.where(std > 0, 1.0 / np.where(std > 0, std, 1.0), 0.0)
    return covariance * scale[:, None] * scale[None, :]


def camera_covariance(result: Adjustment, model: str, row: int) -> np.ndarray:
    """Cxx (p, p) of all parameters of camera `row` of `model`, in the order of its
    `parameter_names`; rows and columns of fixed parameters 0."""
    positions = positions_of(result.parameters).cameras[model][row]
    return result.precision.covariance_of(np.asarray(positions))


def camera_correlation(result: Adjustment, model: str, row: int) -> tuple[list[str], np.ndarray]:
    """(names, ρ) of the estimated IOPs of camera `row` of `model`."""
    return correlation_of_free(result, model, row, camera_covariance(result, model, row))


def correlation_of_free(result: Adjustment, model: str, row: int,
                        covariance: np.ndarray) -> tuple[list[str], np.ndarray]:
    """`camera_correlation` from the camera's `camera_covariance` (p, p), already at hand."""
    names = CAMERA_MODELS[model].parameter_names
    free = np.asarray(result.problem.free.cameras[model])[row]  # no program to index it
    chosen = covariance[np.ix_(free, free)]
    return [n for n, f in zip(names, free) if f], correlation(chosen)


def point_covariances(result: Adjustment) -> Float[np.ndarray, "n_points 3 3"]:
    """3x3 covariance of every object point (object units²), zeros for fixed coordinates."""
    precision = result.precision
    if precision.schur is not None:
        return precision.schur.points
    positions = positions_of(result.parameters).points
    rows = precision.covariance_rows(np.asarray(positions))  # (n_points, 3)
    free = rows >= 0
    safe = np.where(free, rows, 0)
    blocks = precision.covariance[safe[:, :, None], safe[:, None, :]]
    return np.where(free[:, :, None] & free[:, None, :], blocks, 0.0)


def error_ellipsoids(
    covariances: Float[np.ndarray, "n 3 3"], *, scale: float = 1.0
) -> tuple[Float[np.ndarray, "n 3"], Float[np.ndarray, "n 3 3"]]:
    """Semi-axes (descending, object units) and axis directions (columns) of each ellipsoid.

    `scale` multiplies the standard (1σ) ellipsoid, e.g. 2.7955 for 95 % in 3D. A
    covariance with a non-finite entry (statistics unavailable) gives NaN axes and directions.
    """
    finite = np.all(np.isfinite(covariances), axis=(-2, -1))
    eigenvalues, eigenvectors = np.linalg.eigh(np.where(finite[:, None, None], covariances, 0.0))
    order = np.argsort(-eigenvalues, axis=-1)
    axes = scale * np.sqrt(np.clip(np.take_along_axis(eigenvalues, order, -1), 0, None))
    directions = np.take_along_axis(eigenvectors, order[:, None, :], -1)
    return (np.where(finite[:, None], axes, np.nan),
            np.where(finite[:, None, None], directions, np.nan))


def propagate(
    result: Adjustment, function: Callable[[Parameters], Float[Array, "..."]]
) -> tuple[np.ndarray, np.ndarray]:
    """Value and covariance of y = f(x) by linear propagation, C_yy = F Cxx Fᵀ.

    `function` maps the adjusted Parameters to an array (a distance, a projected point,
    a derived camera constant...); F = ∂y/∂x_free by `jax.jacfwd`; only the unknowns y
    depends on enter (after points-eliminated adjustments: reduced unknowns or one point).
    The covariance has the flattened shape (y.size, y.size).
    """
    index = np.asarray(result.precision.free_index)
    value, jacobian = (np.asarray(a) for a in _value_and_jacobian(
        function, result.parameters, flatten(result.parameters), index))
    used = np.flatnonzero(np.any(jacobian != 0, axis=0))
    covariance = result.precision.covariance_of(index[used])
    return value, jacobian[:, used] @ covariance @ jacobian[:, used].T


@eqx.filter_jit
def _value_and_jacobian(function, params: Parameters, base, index):
    """`function(params)` and F = ∂ ravel(function) / ∂x_free (y.size, index.size), `base`
    the flattened `params`, as one program (op by op, `jax.jacfwd` of a small function
    compiled ~100 small programs per call)."""

    def of_free(x_free):
        return jnp.ravel(function(unflatten(params, base.at[index].set(x_free))))

    return function(params), jax.jacfwd(of_free)(base[index])
