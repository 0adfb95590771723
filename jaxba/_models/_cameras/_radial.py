"""SMAC radial lens distortion (USGS SMAC; BASC lab, docs/conventions.md)."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2
from ._abstract import AbstractDistortion
from ._names import RADIAL_SMAC


class RadialSmac(AbstractDistortion):
    """Δx = x̄ (K0 + K1 r² + K2 r⁴ + K3 r⁶), Δy = ȳ (same); r² = x̄² + ȳ² in mm².

    Units: K0 dimensionless, K1 mm⁻², K2 mm⁻⁴, K3 mm⁻⁶.
    """

    K0: Scalar
    K1: Scalar
    K2: Scalar
    K3: Scalar
    parameter_names = RADIAL_SMAC

    def correction(self, reduced: Vector2) -> Vector2:
        r2 = jnp.sum(reduced**2)
        return reduced * (self.K0 + r2 * (self.K1 + r2 * (self.K2 + r2 * self.K3)))
