"""The close-range metrology camera: distortion applied forward, at the computed image point,
with a balanced radial term that crosses zero at a constant radius r0; and its conversion to
and from the SMAC model.

The model (docs/conventions.md, "Camera models"), in mm, with (U, V, W) = M (X - X0):

    x' = -c U/W,  y' = -c V/W,  r² = x'² + y'²
    D  = A1 (r² - r0²) + A2 (r⁴ - r0⁴) + A3 (r⁶ - r0⁶)
    x  = xh + x' + x' D + B1 (r² + 2x'²) + 2 B2 x'y' + C1 x' + C2 y'
    y  = yh + y' + y' D + B2 (r² + 2y'²) + 2 B1 x'y'

plus, with refraction on, the atmospheric term k (x', y') (1 + r²/c²) at the same computed
point (`SmacCamera` adds it at the measured point). Units: xh, yh, c, r0 mm; A1 mm⁻², A2 mm⁻⁴,
A3 mm⁻⁶; B1, B2 mm⁻¹; C1 (affinity, x scaled by 1 + C1) and C2 (shear) dimensionless. r0 is
a constant of the camera (`cameras.toml` key `r0`), not an unknown.

Relation to SMAC. SMAC corrects the *measured* reduced point x̄ = x - xp: x̄ - Δ(x̄) = -c_s U/W.
The two describe the same lens with different values:

- exactly: xp = xh, yp = yh (both map the axis U = V = 0 to the principal point);
- exactly, within this model: the balance is a change of scale, i.e. of c. A1 (r² - r0²) =
  A1 r² - A1 r0², and -A1 r0² x' (with -A2 r0⁴ x', -A3 r0⁶ x') scales the image as c does:
  with D0 = -(A1 r0² + A2 r0⁴ + A3 r0⁶) and s = 1 + D0, the camera (c, Ak, B, C, r0) is the
  camera (s c, Ak / s^(2k+1), B / s², C / s, r0 = 0), point for point;
- exactly, for the linear terms alone (A = B = 0): c_s = 2 a c / (1 + a) with a = 1 + C1,
  SMAC A1 = -C1 / (2 + C1), SMAC A2 = 2 C2 / (2 + C1), K0 = 0;
- to first order, from the r0 = 0 form: K1 ≈ A1, K2 ≈ A2, K3 ≈ A3, P1 ≈ B1, P2 ≈ B2 and
  c_s ≈ c (1 + D0 + C1/2). A polynomial evaluated at the measured point is not one at the
  computed point, so beyond first order the equivalence is approximate.

`metrology_to_smac` and `smac_to_metrology` therefore fit the other model's values by linear
least squares over a grid of the image format (the principal point copied exactly): the fit
reproduces the exact relations where they hold (its residual is then zero) and minimises the
image residuals of the other model's points where they do not. They are pure NumPy.
"""

from collections.abc import Mapping
from typing import Self

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera
from ._names import CAMERA_CONSTANT_NAMES, CAMERA_PARAMETER_NAMES


class MetrologyCamera(AbstractCamera):
    """Close-range metrology model: forward distortion at the computed point, balanced radial
    term zero at the constant radius `r0` (mm; a static field). See the module docstring.

    `measured` is not used (the distortion is that of the computed point); `refraction_k`
    adds k (x', y') (1 + r²/c²). Build it with `from_parameters(values, r0=...)`.
    """

    xh: Scalar
    yh: Scalar
    c: Scalar
    A1: Scalar
    A2: Scalar
    A3: Scalar
    B1: Scalar
    B2: Scalar
    C1: Scalar
    C2: Scalar
    r0: float = eqx.field(static=True)
    parameter_names = CAMERA_PARAMETER_NAMES["metrology"]
    constant_names = CAMERA_CONSTANT_NAMES["metrology"]
    image_units = "mm"

    @classmethod
    def from_parameters(cls, values: Float[Array, " 10"], **constants: float) -> Self:
        if set(constants) != {"r0"}:
            raise TypeError(
                "the metrology camera model needs its constant r0 (mm) and no other: "
                f"from_parameters(values, r0=...), got {sorted(constants)} (an ImagePoints "
                'group passes its constants, e.g. constants=(("r0", 12.5),))'
            )
        return super().from_parameters(values, r0=float(constants["r0"]))

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        del measured
        x, y = -self.c * p_camera[0] / p_camera[2], -self.c * p_camera[1] / p_camera[2]
        r2, r02 = x * x + y * y, self.r0**2
        d = (self.A1 * (r2 - r02) + self.A2 * (r2**2 - r02**2) + self.A3 * (r2**3 - r02**3)
             + refraction_k * (1 + r2 / self.c**2))
        dx = x * d + self.B1 * (r2 + 2 * x * x) + 2 * self.B2 * x * y + self.C1 * x + self.C2 * y
        dy = y * d + self.B2 * (r2 + 2 * y * y) + 2 * self.B1 * x * y
        return jnp.stack([self.xh + x + dx, self.yh + y + dy])


# --- conversion to and from SMAC (NumPy) ----------------------------------------------------

SMAC_NAMES = CAMERA_PARAMETER_NAMES["smac"]
METROLOGY_NAMES = CAMERA_PARAMETER_NAMES["metrology"]


def metrology_image(values: Mapping[str, float], r0: float, ideal: np.ndarray) -> np.ndarray:
    """Reduced image points (x - xh, y - yh) (n, 2) mm of the metrology model at the reduced
    ideal points `ideal` = (x', y') = -c (U, V)/W (n, 2) mm; NumPy, no refraction."""
    v = values
    x, y = ideal[:, 0], ideal[:, 1]
    r2, r02 = x * x + y * y, r0**2
    d = v["A1"] * (r2 - r02) + v["A2"] * (r2**2 - r02**2) + v["A3"] * (r2**3 - r02**3)
    dx = x * d + v["B1"] * (r2 + 2 * x * x) + 2 * v["B2"] * x * y + v["C1"] * x + v["C2"] * y
    dy = y * d + v["B2"] * (r2 + 2 * y * y) + 2 * v["B1"] * x * y
    return np.stack([x + dx, y + dy], axis=-1)


def smac_correction(values: Mapping[str, float], reduced: np.ndarray) -> np.ndarray:
    """SMAC's correction Δ (n, 2) mm at the reduced measured points `reduced` (n, 2) mm
    (radial, decentering and affine terms of `SmacCamera`; no refraction); NumPy."""
    v = values
    x, y = reduced[:, 0], reduced[:, 1]
    r2 = x * x + y * y
    radial = v["K0"] + r2 * (v["K1"] + r2 * (v["K2"] + r2 * v["K3"]))
    profile = 1 + v["P3"] * r2
    dx = (x * radial + profile * (v["P1"] * (r2 + 2 * x * x) + 2 * v["P2"] * x * y)
          - v["A1"] * x + v["A2"] * y)
    dy = (y * radial + profile * (2 * v["P1"] * x * y + v["P2"] * (r2 + 2 * y * y))
          + v["A1"] * y)
    return np.stack([dx, dy], axis=-1)


def _as_values(camera, names: tuple[str, ...], model: str) -> dict[str, float]:
    """`camera` (a camera instance of `model`, or a mapping of its parameter names; missing
    ones are 0) as a dict of floats."""
    if isinstance(camera, Mapping):
        unknown = sorted(set(camera) - set(names))
        if unknown:
            raise ValueError(f"unknown {model} parameters {unknown}; allowed: {' '.join(names)}")
        return {name: float(camera.get(name, 0.0)) for name in names}
    if tuple(camera.parameter_names) != names:
        raise ValueError(f"expected a {model} camera or a mapping of its parameters, "
                         f"got {type(camera).__name__}")
    return dict(zip(names, np.asarray(camera.parameters(), dtype=float).tolist()))


def _format_grid(format_mm: tuple[float, float], n: int) -> np.ndarray:
    """(n², 2) points of an n x n grid over the image format (width, height) mm, centred on
    the image origin (the sensor centre)."""
    width, height = (float(v) for v in format_mm)
    if not (width > 0 and height > 0 and n >= 5):
        raise ValueError(f"format_mm must be two sizes > 0 and n >= 5, got {format_mm}, {n}")
    xs, ys = np.meshgrid(np.linspace(-width / 2, width / 2, n),
                         np.linspace(-height / 2, height / 2, n))
    return np.stack([xs.ravel(), ys.ravel()], axis=-1)


def _least_squares(columns: list[np.ndarray], target: np.ndarray) -> np.ndarray:
    """Coefficients of `columns` (each (n, 2)) that best fit `target` (n, 2), both image
    coordinates of every point stacked; columns equilibrated first."""
    design = np.stack([column.ravel() for column in columns], axis=-1)
    scale = np.linalg.norm(design, axis=0)
    scale[scale == 0] = 1.0
    solution, *_ = np.linalg.lstsq(design / scale, target.ravel(), rcond=None)
    return solution / scale


def metrology_to_smac(
    camera, *, format_mm: tuple[float, float], r0: float | None = None, n: int = 25
) -> dict[str, float]:
    """SMAC values (`SmacCamera.parameter_names`, K0 = P3 = 0) of a metrology camera.

    `camera`: a `MetrologyCamera` or a mapping of its parameter names (then `r0`, mm, is
    needed). `format_mm` = (width, height) of the image format in mm, centred on the image
    origin. xp, yp = xh, yh exactly; c, K1..K3, P1, P2, A1, A2 by linear least squares:
    the image points of an n x n grid of ideal points over the format are computed with the
    metrology model, and SMAC's residuals of them (x̄ - Δ(x̄) + c_s U/W) are minimised. Where
    the relation is exact (the linear terms: scale from r0 and c, C1, C2) it is recovered
    exactly; see the module docstring for the first-order relations.
    """
    values = _as_values(camera, METROLOGY_NAMES, "metrology")
    r0 = _constant_r0(camera, r0)
    principal = np.array([values["xh"], values["yh"]])
    ideal = _format_grid(format_mm, n) - principal
    measured = metrology_image(values, r0, ideal)
    x, y = measured[:, 0], measured[:, 1]
    r2 = x * x + y * y
    zero = np.zeros_like(x)
    columns = [
        ideal / values["c"],  # c_s: the SMAC condition is x̄ - Δ(x̄) = c_s (x'/c)
        measured * r2[:, None], measured * r2[:, None] ** 2, measured * r2[:, None] ** 3,
        np.stack([r2 + 2 * x * x, 2 * x * y], axis=-1),  # P1
        np.stack([2 * x * y, r2 + 2 * y * y], axis=-1),  # P2
        np.stack([-x, y], axis=-1),  # A1 (SMAC's affinity)
        np.stack([y, zero], axis=-1),  # A2 (SMAC's shear)
    ]
    c, k1, k2, k3, p1, p2, a1, a2 = _least_squares(columns, measured)
    smac = dict(xp=values["xh"], yp=values["yh"], c=c, K0=0.0, K1=k1, K2=k2, K3=k3,
                P1=p1, P2=p2, P3=0.0, A1=a1, A2=a2)
    return {name: float(smac[name]) for name in SMAC_NAMES}


def smac_to_metrology(
    camera, r0: float, *, format_mm: tuple[float, float], n: int = 25
) -> dict[str, float]:
    """Metrology values (`MetrologyCamera.parameter_names`) with constant `r0` (mm) of a SMAC
    camera (a `SmacCamera` or a mapping of its parameter names; P3 and K0 may be nonzero).

    xh, yh = xp, yp exactly; the rest by linear least squares over an n x n grid of measured
    points over the format (`format_mm` = (width, height) mm, centred on the image origin):
    SMAC gives each its ray exactly, u = (x̄ - Δ(x̄)) / c_s = -(U, V)/W, and the metrology
    model written as x̄ = β0 u + β1 u |u|² + β2 u |u|⁴ + β3 u |u|⁶ + (decentering, affinity
    in u) is linear in β0 = c (1 - A1 r0² - A2 r0⁴ - A3 r0⁶), β1 = A1 c³, β2 = A2 c⁵,
    β3 = A3 c⁷, B c², C c; c then solves c - Σ βk r0^2k / c^2k = β0 (Newton).
    """
    values = _as_values(camera, SMAC_NAMES, "smac")
    r0 = float(r0)
    principal = np.array([values["xp"], values["yp"]])
    measured = _format_grid(format_mm, n) - principal
    u = (measured - smac_correction(values, measured)) / values["c"]
    ux, uy = u[:, 0], u[:, 1]
    rho2 = (ux * ux + uy * uy)[:, None]
    zero = np.zeros_like(ux)
    columns = [
        u, u * rho2, u * rho2**2, u * rho2**3,
        np.stack([rho2[:, 0] + 2 * ux * ux, 2 * ux * uy], axis=-1),  # B1 c²
        np.stack([2 * ux * uy, rho2[:, 0] + 2 * uy * uy], axis=-1),  # B2 c²
        np.stack([ux, zero], axis=-1),  # C1 c
        np.stack([uy, zero], axis=-1),  # C2 c
    ]
    beta0, beta1, beta2, beta3, gamma1, gamma2, delta1, delta2 = _least_squares(columns, measured)
    betas = (beta1, beta2, beta3)
    c = beta0
    for _ in range(100):
        g = c - beta0 - sum(b * r0 ** (2 * k) / c ** (2 * k) for k, b in enumerate(betas, 1))
        slope = 1 + sum(2 * k * b * r0 ** (2 * k) / c ** (2 * k + 1)
                        for k, b in enumerate(betas, 1))
        step = g / slope
        c -= step
        if abs(step) <= 1e-15 * abs(c):
            break
    else:
        raise ValueError(f"smac_to_metrology: no principal distance for r0 = {r0} mm")
    metrology = dict(xh=values["xp"], yh=values["yp"], c=c, A1=beta1 / c**3, A2=beta2 / c**5,
                     A3=beta3 / c**7, B1=gamma1 / c**2, B2=gamma2 / c**2, C1=delta1 / c,
                     C2=delta2 / c)
    return {name: float(metrology[name]) for name in METROLOGY_NAMES}


def _constant_r0(camera, r0: float | None) -> float:
    """r0 of a `MetrologyCamera`, or the `r0` given with a mapping of values."""
    if isinstance(camera, MetrologyCamera):
        if r0 is not None and float(r0) != camera.r0:
            raise ValueError(f"r0 = {r0} given for a camera with r0 = {camera.r0}")
        return camera.r0
    if r0 is None:
        raise ValueError("metrology_to_smac: r0 (mm) is needed with a mapping of values")
    return float(r0)
