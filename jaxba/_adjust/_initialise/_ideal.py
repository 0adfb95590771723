"""Ideal (distortion-free) image rays of measured image points, for any jaxba camera model.

A camera model maps a camera-frame point p = M (X - X0) to computed image coordinates,
`image_point(p, measured, k)` (docs/conventions.md; photogrammetric models evaluate their
corrections at the measured point, forward models such as OpenCV, fisheye and BAL distort the
ideal point, some work in pixels). The ray of a measured point m is the direction p = (a, b, -1)
(the camera looks along -z) that the model maps onto m:

    image_point((a, b, -1), m, 0) = m.

(a, b) are the *normalised* ideal coordinates: the reduced, distortion-free coordinates of an
ideal camera with c = 1 and the principal point at 0, so that the approximation tools take
them with `c=1.0`. They are found by Newton's method with the model's Jacobian (jax autodiff),
vmapped over the points: one step for the photogrammetric models (linear in (a, b) at fixed
m), a few for the forward models; each step is backtracked (halved up to three times) when it
does not reduce the misfit. Atmospheric refraction is left out (k = 0).
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._float64 import require_float64
from ..._models._cameras import AbstractCamera
from ..._models._rotation import opk_to_matrix

NEWTON_STEPS = 30
"""Newton iterations of `ideal_coordinates` (the photogrammetric models need one)."""

CONVERGED_RTOL = 1e-9
"""A point converged when its misfit |image_point - m| is below this fraction of
1 + the local scale (image units per unit of normalised coordinate) times 1e-3."""

_BACKTRACK = (1.0, 0.5, 0.25, 0.125)


@dataclasses.dataclass(frozen=True)
class IdealCoordinates:
    """Rays of measured image points by `ideal_coordinates`.

    - `normalised` (n, 2): (a, b) with the ray (a, b, -1) ∝ M (X - X0) in jaxba's camera frame
      (dimensionless: the reduced ideal coordinates of a camera with c = 1);
    - `scale` (n,): image units (mm or pixels, the camera's) per unit of normalised
      coordinate at each point, sqrt|det ∂image_point/∂(a, b)| (the principal distance or
      focal length, locally): multiply a normalised residual by it for image units;
    - `misfit` (n,): |image_point((a, b, -1), m, 0) - m| left (image units);
    - `converged` (n,): misfit small (NaN input or a ray the model cannot represent: False).
    """

    normalised: np.ndarray
    scale: np.ndarray
    misfit: np.ndarray
    converged: np.ndarray


def _residual(camera, q, measured):
    p = jnp.stack([q[0], q[1], -jnp.ones_like(q[0])])
    return camera.image_point(p, measured, jnp.zeros_like(q[0])) - measured


@eqx.filter_jit
def _solve(camera, measured):
    def one(m):
        f = lambda q: _residual(camera, q, m)  # noqa: E731
        jac = jax.jacfwd(f)
        q0 = jnp.zeros(2, dtype=m.dtype)
        # The first step from q = 0 is the inverse of the linearised (pinhole) camera.
        q = q0 - jnp.linalg.solve(jac(q0), f(q0))

        def step(_, q):
            value, j = f(q), jac(q)
            delta = -jnp.linalg.solve(j, value)
            candidates = jnp.stack([q + t * delta for t in _BACKTRACK])
            norms = jax.vmap(lambda c: jnp.sum(f(c) ** 2))(candidates)
            norms = jnp.where(jnp.isfinite(norms), norms, jnp.inf)
            best = jnp.argmin(norms)
            better = norms[best] < jnp.sum(value**2)
            return jnp.where(better, candidates[best], q)

        q = jax.lax.fori_loop(0, NEWTON_STEPS, step, q)
        scale = jnp.sqrt(jnp.abs(jnp.linalg.det(jac(q))))
        return q, scale, jnp.linalg.norm(f(q))

    return jax.vmap(one)(measured)


def ideal_coordinates(camera: AbstractCamera, measured) -> IdealCoordinates:
    """The normalised ideal coordinates (rays) of measured image points of one camera.

    Arguments:
    - `camera`: a jaxba camera model instance (`jaxba.CAMERA_MODELS`, e.g. `jaxba.SmacCamera`)
      with its (approximate) parameters;
    - `measured` (n, 2): measured image coordinates in the camera's image units (mm in jaxba's
      image frame for the photogrammetric models, pixels (col, row) for OpenCV and fisheye,
      BAL's centred pixels for BAL).

    Returns `IdealCoordinates`: (a, b) with the ray (a, b, -1) in the camera frame, so that
    the approximation tools take them with c = 1 and principal point 0 (module docstring).
    Needs jax in float64.
    """
    require_float64("ideal_coordinates")
    measured = np.asarray(measured, dtype=np.float64).reshape(-1, 2)
    if len(measured) == 0:
        empty = np.zeros((0, 2))
        return IdealCoordinates(empty, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool))
    camera = jax.tree.map(lambda leaf: jnp.asarray(leaf, dtype=jnp.float64), camera)
    q, scale, misfit = (np.asarray(a) for a in _solve(camera, jnp.asarray(measured)))
    converged = (np.all(np.isfinite(q), axis=1) & np.isfinite(scale) & (scale > 0)
                 & (misfit <= CONVERGED_RTOL * (1.0 + 1e-3 * np.where(np.isfinite(scale),
                                                                        scale, 0.0))))
    return IdealCoordinates(normalised=q, scale=scale, misfit=misfit, converged=converged)


@eqx.filter_jit
def _residuals(camera, eops, points, measured):
    def one(eop, point, m):
        p = opk_to_matrix(eop[3:]) @ (point - eop[:3])
        return m - camera.image_point(p, m, jnp.zeros_like(m[0]))

    return jax.vmap(one)(eops, points, measured)


def image_residuals(camera: AbstractCamera, eops, points, measured) -> np.ndarray:
    """v = measured - computed (n, 2) in the camera's image units (refraction left out), of
    measured points (n, 2) of `camera` in images `eops` (n, 6) (X0, Y0, Z0, omega, phi, kappa,
    radians) of points (n, 3)."""
    measured = np.asarray(measured, dtype=np.float64).reshape(-1, 2)
    if len(measured) == 0:
        return np.zeros((0, 2))
    camera = jax.tree.map(lambda leaf: jnp.asarray(leaf, dtype=jnp.float64), camera)
    return np.asarray(_residuals(camera, jnp.asarray(eops, dtype=jnp.float64),
                                 jnp.asarray(points, dtype=jnp.float64), jnp.asarray(measured)))
