"""Robust losses as residual transformations, so optimistix still sees least squares.

For a whitened residual e, the transformed residual ẽ = sign(e) sqrt(2 ρ(e)) gives
½ ẽ² = ρ(e), so minimising ½ Σ ẽ² minimises Σ ρ(e). Both losses equal ½ e² near 0.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

ROBUST_LOSSES = ("huber", "cauchy")


class RobustLoss(eqx.Module):
    """ρ with scale k (in σ): Huber ρ = ½e² for |e| <= k, k|e| - ½k² beyond;
    Cauchy ρ = ½k² log(1 + e²/k²)."""

    kind: str = eqx.field(static=True)
    scale: float = 3.0

    def __check_init__(self):
        if self.kind not in ROBUST_LOSSES:
            raise ValueError(f"robust loss must be one of {ROBUST_LOSSES}, got {self.kind!r}")
        if not self.scale > 0:
            raise ValueError(f"robust loss scale must be > 0, got {self.scale}")

    def __call__(self, e: Float[Array, "..."]) -> Float[Array, "..."]:
        k = self.scale
        if self.kind == "huber":
            magnitude = jnp.abs(e)
            outside = magnitude > k
            safe = jnp.where(outside, magnitude, k)
            return jnp.where(outside, jnp.sign(e) * jnp.sqrt(2 * k * safe - k**2), e)
        # Cauchy: ẽ = e sqrt(log1p(t) / t), t = e²/k²; the ratio → 1 - t/2 as t → 0.
        t = (e / k) ** 2
        small = t < 1e-8
        safe_t = jnp.where(small, 1.0, t)
        ratio = jnp.where(small, 1.0 - t / 2, jnp.log1p(safe_t) / safe_t)
        return e * jnp.sqrt(ratio)

    def weight(self, e: Float[Array, "..."]) -> Float[Array, "..."]:
        """IRLS weight ρ'(e)/e of each residual (1 inside Huber's k)."""
        if self.kind == "huber":
            return jnp.minimum(1.0, self.scale / jnp.maximum(jnp.abs(e), 1e-300))
        return 1.0 / (1.0 + (e / self.scale) ** 2)
