"""Multimedia refraction through a flat port: the camera in air behind a plane glass window,
the object in a medium (water) beyond it (docs/models.md "Flat port")."""

import jax
import jax.numpy as jnp

from ..._custom_types import Scalar, Vector3
from ._abstract import AbstractRayRefraction
from ._names import RAY_REFRACTION_PARAMETER_NAMES

NEWTON_ITERATIONS = 30
"""Newton steps of the ray solve. From w = 0 they climb the concave residual monotonically
and quadratically near the root: 4 to 6 reach the rounding level for rays up to 70° off the
normal; the rest is margin for rays near the edge of what the port lets through."""
CONVERGED = 1e-10
"""|F(w)| (relative lateral miss) above which the solve has not converged: no ray reaches
the point (NaN)."""


class FlatPort(AbstractRayRefraction):
    """A plane-parallel port of glass between air (the camera's side) and a medium.

    Parameters: `distance` (perspective centre to the port's inner surface along the optical
    axis, object units), `thickness` (of the glass, along its normal, object units), the
    refractive indices `n_air`, `n_glass`, `n_medium`, and `normal_x`, `normal_y`: the unit
    normal of the port in the camera frame, n = (normal_x, normal_y, -√(1 - normal_x² -
    normal_y²)) (0, 0, -1 is the optical axis, towards the object).

    With a point P (camera frame), its depth beyond the centre along n, z = n·P, its lateral
    offset ρ = |P - z n|, and the layers' thicknesses along n, h = (distance n_z', thickness,
    z - distance n_z' - thickness) (n_z' = -n_z), the ray is in the plane of n and P and
    obeys Snell's law n_j sin θ_j = s at both surfaces. With n* = min n_j and the unknown w
    = tan θ* / ρ (θ* the ray's angle in the medium of index n*), tan θ_j = ρ w A_j and

        F(w) = w Σ_j h_j A_j - 1 = 0,   A_j = n* / √(n_j² + (n_j² - n*²) ρ² w²),

    concave and increasing in w: Newton from w = 0 climbs to the root monotonically. The
    returned point is z (n + w A_air (P - z n)), on the in-air ray at the depth of P.
    Derivatives are implicit (one Newton step at the converged w, differentiated).
    NaN where the port is invalid (an index ≤ 0, thickness or distance < 0, normal not
    towards the object), the point is not beyond the port, or no ray reaches it.
    """

    distance: Scalar
    thickness: Scalar
    n_air: Scalar
    n_glass: Scalar
    n_medium: Scalar
    normal_x: Scalar
    normal_y: Scalar
    parameter_names = RAY_REFRACTION_PARAMETER_NAMES["flat_port"]

    def ray(self, p_camera: Vector3) -> Vector3:
        tilt2 = self.normal_x**2 + self.normal_y**2
        axis = jnp.sqrt(jnp.where(tilt2 < 1, 1 - tilt2, 1.0))  # n · (0, 0, -1)
        normal = jnp.stack([self.normal_x, self.normal_y, -axis])
        depth = normal @ p_camera
        lateral = p_camera - depth * normal
        rho2 = jnp.sum(lateral**2)
        n_air_side = self.distance * axis
        heights = jnp.stack([n_air_side, self.thickness, depth - n_air_side - self.thickness])
        indices = jnp.stack([self.n_air, self.n_glass, self.n_medium])
        valid = ((tilt2 < 1) & jnp.all(indices > 0) & (self.distance >= 0)
                 & (self.thickness >= 0) & (heights[2] > 0))
        indices = jnp.where(valid, indices, 1.0)
        heights = jnp.where(valid, heights, 1.0)
        w_stop = _newton(*jax.lax.stop_gradient((heights, indices, rho2)))
        value, slope = _residual(w_stop, heights, indices, rho2)
        w = w_stop - value / slope  # = w_stop, with the implicit derivative dw = -dF / F'
        converged = jnp.abs(value) <= CONVERGED
        tan_air = w * _a(indices[0], jnp.min(indices), rho2 * w**2)  # tan θ_air / ρ
        point = depth * (normal + tan_air * lateral)
        return jnp.where(valid & converged, point, jnp.nan)


def _a(n_j: Scalar, n_min: Scalar, q: Scalar) -> Scalar:
    """A_j = n* / √(n_j² + (n_j² - n*²) q), q = ρ² w²: tan θ_j = ρ w A_j."""
    return n_min / jnp.sqrt(n_j**2 + (n_j**2 - n_min**2) * q)


def _residual(w, heights, indices, rho2) -> tuple[Scalar, Scalar]:
    """F(w) = w Σ h_j A_j - 1 and F'(w) = Σ h_j n* n_j² / (n_j² + (n_j² - n*²) ρ² w²)^(3/2);
    `heights` h (3,) object units, `indices` n (3,), `rho2` ρ² (object units²)."""
    n_min = jnp.min(indices)
    stretch = indices**2 + (indices**2 - n_min**2) * rho2 * w**2
    value = w * jnp.sum(heights * n_min / jnp.sqrt(stretch)) - 1
    slope = jnp.sum(heights * n_min * indices**2 / stretch**1.5)
    return value, slope


def _newton(heights, indices, rho2) -> Scalar:
    """`NEWTON_ITERATIONS` Newton steps on F(w) = 0 from w = 0 (call it on stopped inputs)."""

    def step(_, w):
        value, slope = _residual(w, heights, indices, rho2)
        return w - value / slope

    return jax.lax.fori_loop(0, NEWTON_ITERATIONS, step, jnp.zeros_like(rho2))
