"""The PhotoModeler-compatible backward lens model of DBAT, with its aspect and skew terms."""

import jax.numpy as jnp

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_PARAMETER_NAMES


class PhotoModelerCamera(AbstractCamera):
    """DBAT's "backward (photogrammetry) model 3": measured points are corrected, in mm.

    In jaxba's image frame (x right, y up, mm; docs/conventions.md), with (U, V, W) = M (X - X0),
    the measured point (x, y) is first reduced and scaled, then corrected for lens distortion:

        x̄ = x - xp,  ȳ = y - yp                              (measured, reduced)
        a = ((1 + aspect) x̄ + skew ȳ,  ȳ),  r² = a_x² + a_y²   (affine, before distortion)
        l = a (1 + K1 r² + K2 r⁴ + K3 r⁶)
            + (P1 (r² + 2a_x²) + 2 P2 a_x a_y,  2 P1 a_x a_y + P2 (r² + 2a_y²))
            - k a (1 + r²/c²)                                 (atmospheric refraction, k = 0 off)

    and the collinearity condition is l = -c (U, V) / W. The residual is formed there, in the
    corrected frame: v = l - (-c (U, V) / W), mm. `image_point` returns the point whose
    difference from the measurement is that residual,

        x_computed = (x, y) - l + (-c U / W, -c V / W),

    so that `measured - image_point(...)` = v, as the observation groups expect.

    Compared with `SmacCamera` (x̄ - Δ(x̄) = -c U/W, the correction subtracted and evaluated
    at the raw reduced point, the residual in the measured frame): the distortion here is
    *added* (K1..K3, P1, P2 have the opposite sign of SMAC's for the same lens), it is
    evaluated at the aspect-scaled point, and `aspect` scales x only, whereas SMAC's A1 scales
    x by (1 + A1) and y by (1 - A1). The residual lives in the corrected frame, so σ̂0 and the
    weights are those of DBAT, whose image σ (pixels times the pixel size) applies to l.

    Parameters: xp, yp, c in mm; K1 mm⁻², K2 mm⁻⁴, K3 mm⁻⁶; P1, P2 mm⁻¹; aspect ("as", the
    off-unit aspect parameter, dimensionless: DBAT's camera file writes 1 - aspect) and skew
    (dimensionless). K1..K3, P1, P2, aspect and skew take DBAT's (and PhotoModeler's) values
    unchanged; DBAT's principal point is measured from the top-left image corner, y down:
    see docs/dbat.md for the mapping onto (xp, yp).

    Source: N. Börlin and P. Grussenmeyer, DBAT (github.com/niclasborlin/dbat), residual
    function `res_euler_brown_1` (lens distortion model 3: affine transform, then Brown
    (1971) distortion); verified against DBAT's own residuals of the camera-calibration demo
    (tests/test_dbat.py).
    """

    xp: Scalar
    yp: Scalar
    c: Scalar
    K1: Scalar
    K2: Scalar
    K3: Scalar
    P1: Scalar
    P2: Scalar
    aspect: Scalar
    skew: Scalar
    parameter_names = CAMERA_PARAMETER_NAMES["photomodeler"]
    image_units = "mm"

    def corrected(self, measured: Vector2, refraction_k: Scalar) -> Vector2:
        """l: the measured point (mm) reduced, scaled and corrected for distortion, mm."""
        x, y = measured[0] - self.xp, measured[1] - self.yp
        ax, ay = (1 + self.aspect) * x + self.skew * y, y
        a = jnp.stack([ax, ay])
        r2 = ax * ax + ay * ay
        radial = a * (1 + r2 * (self.K1 + r2 * (self.K2 + r2 * self.K3)))
        decentering = jnp.stack([
            self.P1 * (r2 + 2 * ax * ax) + 2 * self.P2 * ax * ay,
            2 * self.P1 * ax * ay + self.P2 * (r2 + 2 * ay * ay),
        ])
        refraction = refraction_k * a * (1 + r2 / self.c**2)
        return radial + decentering - refraction

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        projected = -self.c * p_camera[:2] / p_camera[2]
        return measured - self.corrected(measured, refraction_k) + projected
