"""The projection difference of two calibrations of one camera, and its χ² test.

For the grid pixels q (pixels of A's sensor), the ray p_A(q) of calibration A (at a distance
or a direction) is rotated by R and projected by calibration B:
Δ(q) = q_B(R p_A(q)) - q, with Σ_Δ = J_A Σ_A J_Aᵀ + J_B Σ_B J_Bᵀ its joint covariance over
all grid pixels (J = ∂Δ/∂θ by `jax.jacfwd`, Σ the covariance of each camera's parameters).
The pixels share the few unknowns, so Σ_Δ has a small rank: with Σ_Δ = C Cᵀ
(C = [J_A L_A, J_B L_B], Σ = L Lᵀ) and C = U S Vᵀ, the test keeps the r leading singular
directions, r at most the larger number of estimated parameters of the two (they describe
one lens: their patterns overlap, and the rest of the spectrum is the curvature between two
nearby linearisations, which whitening would blow up), and χ² = |h|², h = S_r⁻¹ U_rᵀ Δ, with
r degrees of freedom. With a fitted rotation, h loses its projection on the whitened
rotation patterns H = S_r⁻¹ U_rᵀ G (G = ∂Δ/∂ρ), the generalised least-squares fit, and the
degrees of freedom rank(H). The differences reported are aligned by the rotation that
minimises Σ_q Δ_qᵀ W_q Δ_q, W_q the inverse of pixel q's own 2 x 2 block of Σ_Δ
(Gauss-Newton on the rotation vector ρ): the generalised fit may turn about the optical axis
to absorb noise, which the per-pixel weights do not.
"""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models._cameras import PixelGrid
from ._projection import projected, sensor_grid, unproject

FITS = ("rotation", "none")
RANK_RTOL = 1e-8  # singular values of C below this fraction of the largest count as 0
_FIT_STEPS = 5  # Gauss-Newton steps of the rotation (3 unknowns, nearly linear)
_NEWTON_STEPS = 8  # projections by B from A's pixel: B's point is near, not at, the start


@dataclasses.dataclass(frozen=True)
class Calibration:
    """One camera's calibration: `model` (a `CAMERA_MODELS` key), its `parameters` (p,) in
    the model's order and units, their `covariance` (p, p) (fixed ones 0), the model's
    `constants` ((name, value) pairs), `sensor` (ncols, nrows) and, for a mm model, the
    `grid` that converts pixels; `camera` its ID, `name` says where it came from."""

    name: str
    camera: str
    model: str
    parameters: np.ndarray
    covariance: np.ndarray
    constants: tuple
    sensor: tuple[int, int]
    grid: PixelGrid | None = None


@dataclasses.dataclass(frozen=True)
class Comparison:
    """The outcome of `compare_calibrations`.

    - `pixels` (n, 2): the grid (pixels of A's sensor); `difference` (n, 2): Δ = (du, dv)
      in pixels, aligned; `chi2_pixels` (n,): each pixel's Δᵀ Σ_ii⁻¹ Δ (before alignment)
      with its own 2 x 2 block;
    - `rotation` (3,): the fitted rotation vector (radians, A's camera frame), 0 without a fit;
    - `chi2`, `dof`, `p_value`: the joint test; `rank` of Σ_Δ; `fit`, `distance`.
    """

    pixels: np.ndarray
    difference: np.ndarray
    chi2_pixels: np.ndarray
    rotation: np.ndarray
    chi2: float
    dof: int
    rank: int
    p_value: float
    fit: str
    distance: float

    @property
    def norm(self) -> np.ndarray:
        """(n,) |Δ| in pixels."""
        return np.linalg.norm(self.difference, axis=1)

    def rejected(self, alpha: float = 0.05) -> bool:
        """True when the test rejects "the same camera" at level `alpha`."""
        return self.p_value < alpha


def _to_model(grid: PixelGrid | None, pixels):
    return pixels if grid is None else grid.pixel_to_image(pixels)


def _to_pixels(grid: PixelGrid | None, image):
    return image if grid is None else grid.image_to_pixel(image)


def _static(calibration: Calibration) -> tuple:
    """What the compiled program takes of a calibration as static: model, constants, grid."""
    return calibration.model, calibration.constants, calibration.grid


def _rotation(rho):
    """exp([ρ]×) (3, 3), differentiable at 0."""
    skew = jnp.array([[0.0, -rho[2], rho[1]], [rho[2], 0.0, -rho[0]], [-rho[1], rho[0], 0.0]])
    return jax.scipy.linalg.expm(skew)


@eqx.filter_jit
def _differences(a: tuple, b: tuple, pixels, distance, theta_a, theta_b, rho):
    """Δ (n, 2) in pixels and its Jacobians (n, 2, p_a), (n, 2, p_b), (n, 2, 3); `a`, `b`
    the calibrations' `_static` parts."""
    (model_a, constants_a, grid_a), (model_b, constants_b, grid_b) = a, b

    def one(q):
        def delta(theta_a, theta_b, rho):
            ray = unproject(model_a, constants_a, theta_a, _to_model(grid_a, q))
            p = _rotation(rho) @ (ray * jnp.where(jnp.isfinite(distance), distance, 1.0))
            image = projected(model_b, constants_b, theta_b, p, _to_model(grid_b, q),
                              _NEWTON_STEPS)
            return _to_pixels(grid_b, image) - q

        return (delta(theta_a, theta_b, rho),
                *jax.jacfwd(delta, argnums=(0, 1, 2))(theta_a, theta_b, rho))

    return jax.vmap(one)(pixels)


def _per_pixel_chi2(factor: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n,) Δ_qᵀ Σ_qq⁺ Δ_q of every pixel with its own 2 x 2 block of Σ_Δ = factor factorᵀ."""
    blocks = factor.reshape(delta.shape[0], 2, -1)
    inverse = np.linalg.pinv(blocks @ np.swapaxes(blocks, 1, 2), hermitian=True)
    return np.einsum("ni,nij,nj->n", delta, inverse, delta)


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """The (2n, 2n) block-diagonal matrix of `blocks` (n, 2, 2)."""
    n = blocks.shape[0]
    out = np.zeros((n, 2, n, 2))
    out[np.arange(n), :, np.arange(n), :] = blocks
    return out.reshape(2 * n, 2 * n)


def _square_root(covariance: np.ndarray) -> np.ndarray:
    """L with L Lᵀ = `covariance` (symmetric, positive semi-definite; negative rounding
    clipped)."""
    values, vectors = np.linalg.eigh((covariance + covariance.T) / 2)
    return vectors * np.sqrt(np.clip(values, 0, None))


def compare_calibrations(
    a: Calibration,
    b: Calibration,
    *,
    distance: float = math.inf,
    fit: str = "rotation",
    pixels: np.ndarray | None = None,
) -> Comparison:
    """The projection difference of `b` against `a` and its χ² test (module docstring).

    `distance`: object units along A's rays (inf, default: directions); `fit`: "rotation"
    (default) or "none"; `pixels` (n, 2): the grid, default `sensor_grid(a.sensor, 24)`.
    """
    if fit not in FITS:
        raise ValueError(f"fit {fit!r}: one of {FITS}")
    if not distance > 0:
        raise ValueError(f"distance {distance}: must be > 0 (inf for directions)")
    if tuple(a.sensor) != tuple(b.sensor):
        raise ValueError(f"{a.name} and {b.name}: different sensors {tuple(a.sensor)} and"
                         f" {tuple(b.sensor)}; a comparison needs one image size")
    pixels = sensor_grid(a.sensor, 24) if pixels is None else np.asarray(pixels, dtype=float)
    theta_a, theta_b = (jax.device_put(np.asarray(c.parameters, dtype=float)) for c in (a, b))
    args = (_static(a), _static(b), jax.device_put(pixels), float(distance), theta_a, theta_b)
    rho = np.zeros(3)
    delta, j_a, j_b, j_rho = (np.asarray(x) for x in _differences(*args, jax.device_put(rho)))
    if not np.all(np.isfinite(delta)):
        raise ValueError(f"{a.name} -> {b.name}: a grid pixel does not map (a ray that the"
                         " other calibration cannot project)")
    n = pixels.shape[0]
    factor = np.concatenate([j_a.reshape(2 * n, -1) @ _square_root(a.covariance),
                             j_b.reshape(2 * n, -1) @ _square_root(b.covariance)], axis=1)
    u, s, _ = np.linalg.svd(factor, full_matrices=False)
    estimated = max(int(np.sum(np.diag(c.covariance) > 0)) for c in (a, b))
    rank = min(int(np.sum(s > RANK_RTOL * s[0])), estimated)
    whiten = u[:, :rank].T / s[:rank, None]  # (r, 2n)
    tested = whiten @ delta.ravel()
    dof = rank
    if fit == "rotation":
        # min over ρ of |whiten (Δ(0) + G ρ)|²: the whitened Δ(0) less its projection on
        # the whitened rotation patterns H, which take rank(H) degrees of freedom.
        h = whiten @ j_rho.reshape(2 * n, 3)
        basis, singular, _ = np.linalg.svd(h, full_matrices=False)
        basis = basis[:, singular > RANK_RTOL * max(singular[0], 1e-300)]
        tested = tested - basis @ (basis.T @ tested)
        dof -= basis.shape[1]
    chi2 = float(tested @ tested)
    per_pixel = _per_pixel_chi2(factor, delta)
    blocks = factor.reshape(n, 2, -1)
    weights = np.linalg.pinv(blocks @ np.swapaxes(blocks, 1, 2), hermitian=True)  # (n, 2, 2)
    for _ in range(_FIT_STEPS if fit == "rotation" else 0):  # the aligned Δ shown
        g = j_rho.reshape(2 * n, 3)
        weighted = _block_diagonal(weights) @ g
        rho = rho - np.linalg.solve(g.T @ weighted, weighted.T @ delta.ravel())
        delta, _, _, j_rho = (np.asarray(x) for x in _differences(*args, jax.device_put(rho)))
    import scipy.special  # here: loaded only by a comparison (its χ² survival function)

    return Comparison(pixels, delta, per_pixel, rho, chi2, dof, rank,
                      float(scipy.special.chdtrc(dof, chi2)) if dof > 0 else math.nan,
                      fit, float(distance))


def calibration_of(result, camera, sensor: tuple[int, int], *, grid: PixelGrid | None = None,
                   name: str | None = None) -> Calibration:
    """The `Calibration` of camera `camera` (its ID) of the adjustment `result` (an
    `Adjustment`) with its image size `sensor` (ncols, nrows) and, for a mm model, `grid`."""
    from ._derived import camera_covariance
    from ._projection import camera_ref

    ref = camera_ref(result, camera)
    return Calibration(
        name=str(camera) if name is None else name, camera=str(camera), model=ref.model,
        parameters=np.asarray(result.parameters.cameras[ref.model][ref.row], dtype=float),
        covariance=camera_covariance(result, ref.model, ref.row), constants=ref.constants,
        sensor=tuple(int(v) for v in sensor), grid=grid)
