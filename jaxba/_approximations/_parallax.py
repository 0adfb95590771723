"""Parallax relations of a vertical stereo pair (the stereo lecture, "Parallax equations").

Two truly vertical images taken from the same flying height H above the datum, the air base B
apart, with flight-line image coordinates (x along the flight line, origin at each image's
principal point): the parallax of a point is p = x - x' (x on the left image, x' on the
right), and similar triangles give f / (H - h) = p / B, so

    H - h = B f / p,   X = B x / p,   Y = B y / p

with X, Y ground coordinates along and across the flight line, origin below the left image's
perspective centre. f is the principal distance c. Units: x, y, p, c image units (mm); B,
H, h, X, Y ground units (m); all functions broadcast over NumPy arrays and need no jax.
"""

import numpy as np


def _parallax(parallax, what: str) -> np.ndarray:
    p = np.asarray(parallax, dtype=np.float64)
    if np.any(p == 0):
        raise ValueError(f"{what}: zero parallax (a point at infinity): H - h = B c / p is "
                         "undefined")
    return p


def stereo_parallax(x_left, x_right) -> np.ndarray:
    """p = x - x': a point's parallax from its flight-line x coordinates on the left and the
    right image (image units)."""
    return np.asarray(x_left, dtype=np.float64) - np.asarray(x_right, dtype=np.float64)


def elevation_from_parallax(parallax, base, c, flying_height) -> np.ndarray:
    """h = H - B c / p: elevation (ground units) of a point of parallax p (image units), air
    base B, principal distance c (image units), flying height H above the datum."""
    p = _parallax(parallax, "elevation_from_parallax")
    return np.asarray(flying_height, dtype=np.float64) - np.asarray(base) * np.asarray(c) / p


def flying_height_from_parallax(parallax, base, c, elevation) -> np.ndarray:
    """H = h + B c / p: flying height above the datum (ground units) from a point of known
    elevation h and parallax p (image units), air base B, principal distance c."""
    p = _parallax(parallax, "flying_height_from_parallax")
    return np.asarray(elevation, dtype=np.float64) + np.asarray(base) * np.asarray(c) / p


def air_base_from_parallax(parallax, c, flying_height, elevation) -> np.ndarray:
    """B = (H - h) p / c: the air base (ground units) from a point of elevation h and
    parallax p (image units), flying height H, principal distance c."""
    return (np.asarray(flying_height, dtype=np.float64) - np.asarray(elevation)) * np.asarray(
        parallax) / np.asarray(c)


def ground_from_parallax(x, y, parallax, base, c, flying_height) -> np.ndarray:
    """Ground coordinates (X, Y, h) (..., 3) of a point from its left-image flight-line
    coordinates x, y and parallax p (image units): X = B x / p, Y = B y / p, h = H - B c / p
    (X, Y from the nadir of the left image, along and across the flight line)."""
    p = _parallax(parallax, "ground_from_parallax")
    base = np.asarray(base, dtype=np.float64)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    h = np.asarray(flying_height, dtype=np.float64) - base * np.asarray(c) / p
    return np.stack(np.broadcast_arrays(base * x / p, base * y / p, h), axis=-1)


def elevation_from_parallax_difference(
    parallax, reference_parallax, reference_elevation, flying_height
) -> np.ndarray:
    """h = h_r + Δp (H - h_r) / p, Δp = p - p_r: elevation (ground units) of a point of
    parallax p from a reference point of parallax p_r and elevation h_r, flying height H; needs
    neither B nor c (exact: both points obey H - h = B c / p). With the foot of an object as
    reference, h - h_r is the object's height from the parallax difference."""
    p = _parallax(parallax, "elevation_from_parallax_difference")
    reference = np.asarray(reference_elevation, dtype=np.float64)
    difference = p - np.asarray(reference_parallax, dtype=np.float64)
    return reference + difference * (np.asarray(flying_height) - reference) / p
