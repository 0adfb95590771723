"""SMAC decentering lens distortion (Brown-Conrady; BASC lab, docs/conventions.md)."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2
from ._abstract import AbstractDistortion
from ._names import DECENTERING_SMAC


class DecenteringSmac(AbstractDistortion):
    """Δx = (1 + P3 r²)(P1 (r² + 2x̄²) + 2 P2 x̄ȳ), Δy = (1 + P3 r²)(2 P1 x̄ȳ + P2 (r² + 2ȳ²)).

    Units: P1, P2 mm⁻¹, P3 mm⁻².
    """

    P1: Scalar
    P2: Scalar
    P3: Scalar
    parameter_names = DECENTERING_SMAC

    def correction(self, reduced: Vector2) -> Vector2:
        x, y = reduced
        r2 = x * x + y * y
        dx = self.P1 * (r2 + 2 * x * x) + 2 * self.P2 * x * y
        dy = 2 * self.P1 * x * y + self.P2 * (r2 + 2 * y * y)
        return (1 + self.P3 * r2) * jnp.stack([dx, dy])
