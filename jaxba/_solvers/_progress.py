"""Accepted iterations of an adjustment, as the solver's steps report them."""

import dataclasses
from collections.abc import Callable

from ._steps import StepInfo


@dataclasses.dataclass
class Iteration:
    """An accepted iterate: its number (0 = the approximations), cost ½Σe² and σ̂0²."""

    iteration: int
    cost: float
    sigma0_squared: float


@dataclasses.dataclass
class StepRecorder:
    """An `on_step` listener that keeps the accepted iterations (step 0 evaluates and accepts
    the approximations) and passes each to `on_iteration`. σ̂0² = σ0² · 2 cost / redundancy."""

    redundancy: int
    sigma0_prior: float = 1.0
    on_iteration: Callable[[Iteration], None] | None = None
    iterations: list[Iteration] = dataclasses.field(default_factory=list)

    def __call__(self, step: StepInfo) -> None:
        if not step.accepted:
            return
        sigma0_squared = self.sigma0_prior**2 * 2 * step.cost / max(self.redundancy, 1)
        iteration = Iteration(len(self.iterations), step.cost, float(sigma0_squared))
        self.iterations.append(iteration)
        if self.on_iteration is not None:
            self.on_iteration(iteration)
