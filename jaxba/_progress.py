"""Per-step reporting from inside the jitted optimistix loop to Python listeners.

optimistix's Gauss-Newton solvers call `verbose(**info)` on every step with the loss of
the point evaluated in that step and the number of accepted steps so far. `report_step`
forwards these to the host with `jax.debug.callback`; `listening` routes them to the
`StepRecorder` of the adjustment currently running. The function passed to the solver
is the same object on every call, so it never causes a recompilation.
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
    """Turns the solver's step reports into accepted iterations.

    A step report carries the loss of the point evaluated in that step and the number
    of steps accepted *before* it, so step s reveals whether step s-1 was accepted.
    σ̂0² = σ0² · 2 cost / redundancy.
    """

    redundancy: int
    sigma0_prior: float = 1.0
    on_iteration: Callable[[Iteration], None] | None = None
    iterations: list[Iteration] = dataclasses.field(default_factory=list)
    _accepted: int = 0
    _last_loss: float = np.nan

    def record(self, accepted_before: int, loss_this_step: float) -> None:
        if not self.iterations:  # step 0 evaluates (and accepts) the approximations
            self._add(loss_this_step)
        elif accepted_before > max(self._accepted, 1):
            self._add(self._last_loss)
        self._accepted = max(self._accepted, accepted_before)
        self._last_loss = loss_this_step

    def finish(self, final_cost: float) -> None:
        """Add the final iterate if the last step was accepted and not yet reported."""
        if not np.isclose(self.iterations[-1].cost, final_cost, rtol=1e-14, atol=0):
            self._add(final_cost)

    def _add(self, cost: float) -> None:
        sigma0_squared = self.sigma0_prior**2 * 2 * cost / max(self.redundancy, 1)
        iteration = Iteration(len(self.iterations), float(cost), float(sigma0_squared))
        self.iterations.append(iteration)
        if self.on_iteration is not None:
            self.on_iteration(iteration)


def _dispatch(accepted_before, loss_this_step) -> None:
    if _listeners and np.ndim(loss_this_step) == 0:
        _listeners[-1].record(int(accepted_before), float(loss_this_step))


def report_step(**info: tuple[str, jax.Array]) -> None:
    """The `verbose` callable handed to optimistix."""
    jax.debug.callback(_dispatch, info["accepted_steps"][1], info["loss_this_step"][1])


@contextlib.contextmanager
def listening(recorder: StepRecorder) -> Iterator[StepRecorder]:
    """Route step reports to `recorder` while the block runs."""
    _listeners.append(recorder)
    try:
        yield recorder
    finally:
        _listeners.remove(recorder)
