"""What a solver returns."""

import equinox as eqx
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
