"""What a solver returns."""

import equinox as eqx
import jax
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .._problem._parameters import Parameters


class Solution(eqx.Module):
    """What `solve` returns: adjusted `parameters`, `converged` flag, solver `steps` (trial
    steps and step 0, the evaluation of the start), `accepted_steps` (step 0 included), the
    final `cost` ½Σẽ² and optimistix's `result` code. A pytree, so it batches under vmap."""

    parameters: Parameters
    converged: Bool[Array, ""]
    steps: Int[Array, ""]
    accepted_steps: Int[Array, ""]
    cost: Float[Array, ""]
    result: optx.RESULTS


def stop_reason(result: optx.RESULTS, max_steps: int) -> str:
    """Why an unconverged solve stopped, in words: from a `Solution.result` (its value a
    device array or, from a batch moved to the host, a NumPy scalar)."""
    result = jax.tree.map(np.asarray, result)  # RESULTS[...] reads array values only
    if bool(result == optx.RESULTS.nonlinear_max_steps_reached):
        return f"the maximum number of steps ({max_steps}) was reached"
    return optx.RESULTS[result]
