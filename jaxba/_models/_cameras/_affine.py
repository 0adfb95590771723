"""Affine image deformation: non-uniform scale and non-orthogonality (docs/conventions.md)."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2
from ._abstract import AbstractDistortion
from ._names import AFFINE


class Affine(AbstractDistortion):
    """Δx = -A1 x̄ + A2 ȳ, Δy = A1 ȳ (A1, A2 dimensionless)."""

    A1: Scalar
    A2: Scalar
    parameter_names = AFFINE

    def correction(self, reduced: Vector2) -> Vector2:
        x, y = reduced
        return jnp.stack([-self.A1 * x + self.A2 * y, self.A1 * y])
