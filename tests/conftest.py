"""Test configuration: float64 everywhere (the library never flips it at import)."""

import jax

jax.config.update("jax_enable_x64", True)
