"""OpenCV's camera with all its distortion terms: rational radial (k1-k6) and thin prism
(s1-s4), image coordinates in pixels."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_PARAMETER_NAMES
from ._opencv import decentered, normalised


class OpenCVFullCamera(AbstractCamera):
    """OpenCV's camera with the rational and thin-prism terms (calibrateCamera's
    CALIB_RATIONAL_MODEL | CALIB_THIN_PRISM_MODEL), plus skew; COLMAP's FULL_OPENCV is this
    model with s1..s4 = 0 and skew = 0.

    With p_cv = diag(1, -1, -1) p_camera = (X_c, Y_c, Z_c), p_camera = M (X - X0):

        x' = X_c / Z_c,  y' = Y_c / Z_c,  r² = x'² + y'²
        s = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
        x'' = x' s + 2 p1 x'y' + p2 (r² + 2x'²) + s1 r² + s2 r⁴
        y'' = y' s + p1 (r² + 2y'²) + 2 p2 x'y' + s3 r² + s4 r⁴
        u = fx x'' + skew y'' + cx,  v = fy y'' + cy

    (u, v) = (col, row) in pixels, origin at the centre of the top-left pixel, as
    `OpenCVCamera` (which is this model with k4..k6 and s1..s4 = 0). fx, fy, cx, cy, skew in
    pixels; k1..k6, p1, p2, s1..s4 dimensionless (OpenCV's distCoeffs order k1 k2 p1 p2 k3 k4
    k5 k6 s1 s2 s3 s4). Distortion acts forward on the ideal point, so `measured` and
    `refraction_k` are ignored. Source: OpenCV calib3d docs, "Camera Calibration and 3D
    Reconstruction"; Claus and Fitzgibbon (rational), Weng et al., PAMI 14(10), 1992 (thin
    prism).
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
    k4: Scalar
    k5: Scalar
    k6: Scalar
    s1: Scalar
    s2: Scalar
    s3: Scalar
    s4: Scalar
    parameter_names = CAMERA_PARAMETER_NAMES["opencv_full"]
    image_units = "pixel"

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        del measured, refraction_k
        x, y = normalised(p_camera)
        r2 = x * x + y * y
        radial = ((1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3)))
                  / (1 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6))))
        xd, yd = decentered(x, y, r2, radial, self.p1, self.p2)
        xd = xd + r2 * (self.s1 + r2 * self.s2)
        yd = yd + r2 * (self.s3 + r2 * self.s4)
        return jnp.stack([self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy])
