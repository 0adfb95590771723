"""The outcome of an adjustment: parameters, statistics, residuals and how the solve went."""

import dataclasses

import numpy as np

from .._problem._bundle import BundleProblem
from .._problem._parameters import Parameters
from .._solvers._progress import Iteration
from .._timing import Timings
from ._covariance import Precision


@dataclasses.dataclass(frozen=True)
class Adjustment:
    """The outcome of `adjust`.

    - `parameters`: adjusted unknowns (fixed ones at their given values);
    - `precision`: σ̂0², redundancy, covariance and σ of every unknown;
    - `residuals`: per observation group, v = observed - computed in the observation's
      units (masked entries 0), same shapes as the group's residuals;
    - `iterations`: every accepted iterate with its cost ½Σe² and σ̂0² (re-adjustments
      for variance components or data snooping continue the numbering);
    - `converged`, `message`, `steps` (solver steps, rejected ones included);
    - `backend`: the normal-equation backend that solved, "dense" or "schur";
    - `timings`: wall seconds per phase ("datum check", "solve", "statistics", ...) with
      the compilations inside each (`jaxba._timing.Timings`);
    - filled in by `adjust_project` as the project asks: `reliability` (a `Reliability`),
      `variance_components` ({group: VarianceComponent}) with `variance_iterations`, and
      `rejections` (data snooping, in order of removal).
    """

    problem: BundleProblem
    parameters: Parameters
    precision: Precision
    residuals: tuple[np.ndarray, ...]
    iterations: list[Iteration]
    converged: bool
    message: str
    steps: int
    backend: str = "dense"
    timings: Timings = dataclasses.field(default_factory=Timings)
    reliability: "Reliability | None" = None  # noqa: F821  (defined in _reliability)
    variance_components: dict | None = None
    variance_iterations: int = 0
    rejections: tuple = ()

    @property
    def sigma0(self) -> float:
        """A posteriori σ̂0."""
        return float(np.sqrt(self.precision.sigma0_squared))
