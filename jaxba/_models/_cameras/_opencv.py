"""The OpenCV pinhole camera: distortion applied forward, image coordinates in pixels."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_PARAMETER_NAMES


class OpenCVCamera(AbstractCamera):
    """OpenCV's camera model with skew (Zhang's γ), computer-vision convention.

    With p_cv = diag(1, -1, -1) p_camera = (X_c, Y_c, Z_c), p_camera = M (X - X0):

        x' = X_c / Z_c,  y' = Y_c / Z_c,  r² = x'² + y'²,  s = 1 + k1 r² + k2 r⁴ + k3 r⁶
        x'' = x' s + 2 p1 x'y' + p2 (r² + 2x'²),  y'' = y' s + p1 (r² + 2y'²) + 2 p2 x'y'
        u = fx x'' + skew y'' + cx,  v = fy y'' + cy

    (u, v) = (col, row) in pixels, origin at the centre of the top-left pixel (OpenCV's
    `projectPoints`, plus skew). fx, fy, cx, cy, skew in pixels; k1, k2, k3, p1, p2
    dimensionless. Distortion acts on the ideal point, so `measured` and `refraction_k`
    are ignored: the model has no atmospheric refraction. Source: OpenCV calib3d docs;
    Zhang, PAMI 22(11), 2000.
    """

    fx: Scalar
    fy: Scalar
    cx: Scalar
    cy: Scalar
    skew: Scalar
    k1: Scalar
    k2: Scalar
    p1: Scalar
    p2: Scalar
    k3: Scalar
    parameter_names = CAMERA_PARAMETER_NAMES["opencv"]
    image_units = "pixel"

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        del measured, refraction_k
        x, y = normalised(p_camera)
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd, yd = decentered(x, y, r2, radial, self.p1, self.p2)
        return jnp.stack([self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy])


def normalised(p_camera: Vector3) -> tuple[Scalar, Scalar]:
    """OpenCV's normalised point (x', y') = (X_c, Y_c) / Z_c of p_camera = M (X - X0), with
    p_cv = diag(1, -1, -1) p_camera (OpenCV's camera frame: x right, y down, z forward)."""
    return p_camera[0] / -p_camera[2], p_camera[1] / p_camera[2]


def decentered(x: Scalar, y: Scalar, r2: Scalar, radial: Scalar, p1: Scalar,
               p2: Scalar) -> tuple[Scalar, Scalar]:
    """(x'', y''): the normalised point (x, y), r² = x² + y², scaled by the radial factor and
    shifted by OpenCV's tangential terms p1, p2."""
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
