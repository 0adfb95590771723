"""The Kannala-Brandt fisheye camera of OpenCV's cv::fisheye module, in pixels."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_PARAMETER_NAMES

# Below this r² = a² + b², θ/r = atan(r)/r is taken from its Taylor series 1 - r²/3 + r⁴/5
# (error < r⁶ ~ 1e-24): keeps the value and the derivatives finite and exact at r = 0.
_SMALL_R2 = 1e-8


class FisheyeCamera(AbstractCamera):
    """Kannala-Brandt (equidistant) fisheye, exactly as OpenCV's `cv::fisheye::projectPoints`.

    With p_cv = diag(1, -1, -1) p_camera = (X_c, Y_c, Z_c), p_camera = M (X - X0) (the OpenCV
    camera frame: x right, y down, looking along +z; as `OpenCVCamera`):

        a = X_c / Z_c,  b = Y_c / Z_c,  r = √(a² + b²),  θ = atan(r)
        θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
        x' = (θd / r) a,  y' = (θd / r) b
        u = fx x' + cx,  v = fy y' + cy

    (u, v) = (col, row) in pixels, origin at the centre of the top-left pixel (OpenCV's
    convention). fx, fy, cx, cy in pixels; k1..k4 dimensionless. OpenCV's skew `alpha` is not
    a parameter (it is 0). Distortion acts forward on the ideal point, so `measured` and
    `refraction_k` are ignored. Source: J. Kannala and S. Brandt, "A generic camera model and
    calibration method for conventional, wide-angle, and fish-eye lenses", PAMI 28(8), 2006;
    OpenCV docs, "Fisheye camera model" (calib3d/fisheye.hpp). COLMAP's OPENCV_FISHEYE is the
    same model (with its own pixel origin; see `jaxba._io._colmap`).
    """

    fx: Scalar
    fy: Scalar
    cx: Scalar
    cy: Scalar
    k1: Scalar
    k2: Scalar
    k3: Scalar
    k4: Scalar
    parameter_names = CAMERA_PARAMETER_NAMES["fisheye"]
    image_units = "pixel"

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        del measured, refraction_k
        # OpenCV camera frame (x right, y down, z forward): p_cv = (p[0], -p[1], -p[2]).
        a, b = p_camera[0] / -p_camera[2], p_camera[1] / p_camera[2]
        r2 = a * a + b * b
        small = r2 < _SMALL_R2
        r = jnp.sqrt(jnp.where(small, 1.0, r2))
        theta_over_r = jnp.where(small, 1 - r2 / 3 + r2 * r2 / 5, jnp.arctan(r) / r)
        theta2 = theta_over_r * theta_over_r * r2
        poly = 1 + theta2 * (self.k1 + theta2 * (self.k2 + theta2 * (self.k3 + theta2 * self.k4)))
        scale = theta_over_r * poly  # θd / r
        return jnp.stack([self.fx * scale * a + self.cx, self.fy * scale * b + self.cy])
