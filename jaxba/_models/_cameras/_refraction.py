"""Atmospheric refraction for near-vertical imagery (seed: chapter 8 notes, docs/conventions.md)."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector3
from ._abstract import AbstractRefraction


class NoRefraction(AbstractRefraction):
    """Close-range work: no refraction, k = 0."""

    def coefficient(self, station: Vector3, point: Vector3) -> Scalar:
        return jnp.zeros((), dtype=station.dtype)


class AtmosphericRefraction(AbstractRefraction):
    """k = 0.00241 [Z0 / (Z0² - 6 Z0 + 250) - Z² / (Z0 (Z² - 6 Z + 250))].

    Z0 (flying height) and Z (ground elevation) above sea level in km, taken from the
    station's and the point's Z coordinate: height_km = (Z + height_offset) * unit_km,
    with `unit_km` the object-space unit in km (0.001 for metres). The camera applies
    Δx = k x̄ (1 + r²/c²), Δy = k ȳ (1 + r²/c²).
    """

    unit_km: float = 0.001
    height_offset: float = 0.0

    def coefficient(self, station: Vector3, point: Vector3) -> Scalar:
        z0 = (station[2] + self.height_offset) * self.unit_km
        z = (point[2] + self.height_offset) * self.unit_km
        return 0.00241 * (z0 / (z0**2 - 6 * z0 + 250) - z**2 / (z0 * (z**2 - 6 * z + 250)))
