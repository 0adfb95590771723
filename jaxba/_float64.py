"""Float64 is the caller's choice: a check that it was made, never a switch."""

import jax


def require_float64(what: str) -> None:
    """Raise `ValueError` unless jax computes in float64 (`jax_enable_x64`).

    Adjustment and statistics need it (a 1e-8 relative change of c matters); library code
    never flips global configuration, so the caller turns it on (the CLI does).
    """
    if not jax.config.jax_enable_x64:
        raise ValueError(
            f"{what} needs float64, and jax computes in float32: call"
            " jax.config.update('jax_enable_x64', True) first"
        )
