"""The photogrammetric frame camera: collinearity + SMAC distortion, affine, refraction."""

from typing import Self

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._affine import Affine
from ._decentering import DecenteringSmac
from ._names import CAMERA_PARAMETER_NAMES
from ._radial import RadialSmac


class SmacCamera(AbstractCamera):
    """Extended collinearity equations with interior orientation (xp, yp, c), mm.

        x = xp - c U / W + dist_x(x̄, ȳ),   y = yp - c V / W + dist_y(x̄, ȳ)

    with (U, V, W) = M (X - X0) and dist evaluated at the *measured* reduced coordinates
    x̄ = x - xp, ȳ = y - yp (photogrammetric convention, as BASC/SMAC and DBAT):
    radial + decentering + affine, plus atmospheric refraction k x̄ (1 + r²/c²).
    """

    xp: Scalar
    yp: Scalar
    c: Scalar
    radial: RadialSmac
    decentering: DecenteringSmac
    affine: Affine
    parameter_names = CAMERA_PARAMETER_NAMES["smac"]
    image_units = "mm"

    @classmethod
    def from_parameters(cls, values: Float[Array, " 12"]) -> Self:
        return cls(
            values[0], values[1], values[2],
            RadialSmac.from_parameters(values[3:7]),
            DecenteringSmac.from_parameters(values[7:10]),
            Affine.from_parameters(values[10:12]),
        )

    def parameters(self) -> Float[Array, " 12"]:
        return jnp.concatenate([
            jnp.stack([self.xp, self.yp, self.c]),
            self.radial.parameters(), self.decentering.parameters(), self.affine.parameters(),
        ])

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        principal_point = jnp.stack([self.xp, self.yp])
        reduced = measured - principal_point
        r2 = jnp.sum(reduced**2)
        distortion = (
            self.radial.correction(reduced)
            + self.decentering.correction(reduced)
            + self.affine.correction(reduced)
            + refraction_k * reduced * (1 + r2 / self.c**2)
        )
        return principal_point - self.c * p_camera[:2] / p_camera[2] + distortion
