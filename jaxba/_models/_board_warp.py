"""A calibration board's warp: mrcal's two-parameter deformation of a nominally flat board.

A board point at (X, Y) of the board's plane moves along the board's normal (+Z of its frame) by

    dZ = kx (1 - x²) + ky (1 - y²),   x = (X - X_c) / h_x,   y = (Y - Y_c) / h_y,

x, y its coordinates normalised to [-1, 1] over the board's extent (centre X_c, Y_c, half
widths h_x, h_y): 0 along the edges, kx + ky at the centre; kx, ky in the board's length
units. mrcal's `calobject_warp` (docs "board deformation"; `ref_calibration_object` writes
4 x_r (1 - x_r), x_r = column / (W - 1), which is 1 - x² with x = 2 x_r - 1).
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._custom_types import Vector3


def warp_shape(xy: Float[np.ndarray, "n 2"], extent: Float[np.ndarray, " 4"]
               ) -> Float[np.ndarray, "n 2"]:
    """(1 - x², 1 - y²) of board points `xy` (board frame, length units), normalised over
    `extent` (X_min, X_max, Y_min, Y_max): the derivatives of dZ by kx and ky."""
    xy = np.asarray(xy, dtype=float)
    low, high = np.asarray(extent, dtype=float)[[0, 2]], np.asarray(extent, dtype=float)[[1, 3]]
    normalised = (xy - (low + high) / 2) / ((high - low) / 2)
    return 1.0 - normalised ** 2


def board_extent(xy: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, " 4"]:
    """(X_min, X_max, Y_min, Y_max) of a board's points `xy`; `ValueError` where they span
    no rectangle (one row or one column of points: no x or no y to normalise)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    low, high = xy.min(axis=0, initial=np.inf), xy.max(axis=0, initial=-np.inf)
    if not np.all(high > low):
        raise ValueError("a warped board's points must span a rectangle in X and Y")
    return np.array([low[0], high[0], low[1], high[1]])


def warped_point(point: Vector3, warp: Float[Array, " 2"], shape: Float[Array, " 2"]
                 ) -> Vector3:
    """`point` (board frame) moved along +Z by kx shape_x + ky shape_y (`warp` = (kx, ky),
    `shape` its row of `warp_shape`)."""
    return point + jnp.zeros(3, point.dtype).at[2].set(jnp.dot(warp, shape))
