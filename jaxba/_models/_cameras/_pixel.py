"""Pixel <-> photogrammetric image coordinates (docs/conventions.md "Frames and units")."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class PixelGrid(eqx.Module):
    """A sensor of `sensor = (ncols, nrows)` pixels of size `pixel_size = (ps_x, ps_y)` mm.

    Pixel (col, row) has its origin at the centre of the top-left pixel, row down; image
    (x, y) its origin at the sensor centre, y up, in mm:
    x = (col - (ncols - 1)/2) ps_x, y = ((nrows - 1)/2 - row) ps_y.
    """

    pixel_size: tuple[float, float]
    sensor: tuple[int, int]

    def _centre(self) -> Float[Array, "2"]:
        return (jnp.asarray(self.sensor, dtype=float) - 1) / 2

    def pixel_to_image(self, pixel: Float[Array, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """(col, row) -> (x, y) mm."""
        offset = jnp.asarray(pixel) - self._centre()
        return offset * jnp.array([1.0, -1.0]) * jnp.asarray(self.pixel_size)

    def image_to_pixel(self, image: Float[Array, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """(x, y) mm -> (col, row)."""
        offset = jnp.asarray(image) / jnp.asarray(self.pixel_size) * jnp.array([1.0, -1.0])
        return offset + self._centre()
