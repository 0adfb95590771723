"""The BAL (Snavely / Bundler) camera: one focal length and two radial terms, in pixels."""

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_PARAMETER_NAMES


class BalCamera(AbstractCamera):
    """Snavely's Bundler camera as used by the BAL data sets (f, k1, k2).

    BAL's camera frame is x right, y up, looking along -z: the photogrammetric camera frame of
    docs/conventions.md. So p_camera = M (X - X0) is BAL's P = R X + t (with R = M, t = -M X0), and

        p = -P[:2] / P[2],   x = f (1 + k1 |p|² + k2 |p|⁴) p.

    x is in pixels, in BAL's image frame: origin at the image centre (the principal point, which
    the model does not estimate), x right, **y up**. It is *not* OpenCV's (col, row): for an image
    of W x H pixels, col = x_0 + x and row = y_0 - y with (x_0, y_0) the centre, e.g.
    ((W - 1)/2, (H - 1)/2) in jaxba's pixel convention. Observations of a `"bal"` camera are
    therefore written in BAL's frame, as BAL's files give them (image_units = "pixel").

    f in pixels, k1 and k2 dimensionless. Distortion acts forward on the ideal point, so
    `measured` and `refraction_k` are ignored. Source: N. Snavely, Bundler user's manual;
    Agarwal et al., "Bundle adjustment in the large", ECCV 2010 (grail.cs.washington.edu/
    projects/bal). With the "rodrigues" pose this is the model `jaxba bal` solves.
    """

    f: Scalar
    k1: Scalar
    k2: Scalar
    parameter_names = CAMERA_PARAMETER_NAMES["bal"]
    image_units = "pixel"

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        del measured, refraction_k
        p = -p_camera[:2] / p_camera[2]
        r2 = p[0] * p[0] + p[1] * p[1]
        return self.f * (1 + r2 * (self.k1 + r2 * self.k2)) * p
