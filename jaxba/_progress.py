"""Per-step reporting from inside the jitted optimistix loop to Python listeners.

jaxba's Levenberg-Marquardt (`_trust_region.LevenbergMarquardt`) calls `verbose(**info)`
on every step with the cost of the point evaluated in that step and whether it was
accepted. `report_step` forwards these to the host with `jax.debug.callback`;
`listening` routes them to the `StepRecorder` of the adjustment currently running. The
function passed to the solver is the same object on every call, so it never causes a
recompilation.
"""

import contextlib
import dataclasses
from collections.abc import Callable, Iterator

import jax
import numpy as np

_listeners: list["StepRecorder"] = []


@dataclasses.dataclass
class Iteration:
    """An accepted iterate: its number (0 = the approximations), cost ½Σe² and σ̂0²."""

    iteration: int
    cost: float
    sigma0_squared: float


@dataclasses.dataclass
class StepRecorder:
    """Turns the solver's step reports into accepted iterations (step 0 evaluates and
    accepts the approximations). σ̂0² = σ0² · 2 cost / redundancy."""

    redundancy: int
    sigma0_prior: float = 1.0
    on_iteration: Callable[[Iteration], None] | None = None
    iterations: list[Iteration] = dataclasses.field(default_factory=list)

    def record(self, accepted: bool, cost: float) -> None:
        if not accepted:
            return
        sigma0_squared = self.sigma0_prior**2 * 2 * cost / max(self.redundancy, 1)
        iteration = Iteration(len(self.iterations), float(cost), float(sigma0_squared))
        self.iterations.append(iteration)
        if self.on_iteration is not None:
            self.on_iteration(iteration)


def _dispatch(accepted, cost) -> None:
    if _listeners and np.ndim(cost) == 0:
        _listeners[-1].record(bool(accepted), float(cost))


def report_step(**info: jax.Array) -> None:
    """The `verbose` callable handed to `_trust_region.LevenbergMarquardt`."""
    jax.debug.callback(_dispatch, info["accepted"], info["cost"])


@contextlib.contextmanager
def listening(recorder: StepRecorder) -> Iterator[StepRecorder]:
    """Route step reports to `recorder` while the block runs."""
    _listeners.append(recorder)
    try:
        yield recorder
    finally:
        _listeners.remove(recorder)
