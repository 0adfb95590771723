"""The normal-equation backends' face to the solve: what `solve` asks of Dense and Schur.

A backend is an equinox Module (a pytree: it travels through `jax.jit` and `jax.vmap` with the
problem) that turns a `BundleProblem` into one optimistix least-squares problem, residual
function, solver (jaxba's trust-region Levenberg-Marquardt with the backend's damped step),
start and arguments, and reads the adjusted Parameters back from optimistix's solution. `solve`
(`_solve.py`) runs it; the backends never call optimistix themselves.
"""

import abc
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import optimistix as optx
from jaxtyping import Array

from .._problem._bundle import BundleProblem
from .._problem._parameters import Parameters


class Tolerances(NamedTuple):
    """The trust-region loop's stopping rules (`jaxba._solvers._trust_region`): optimistix's
    Cauchy test (`rtol`, `atol`), the statistical step test (`step`: gᵀN⁻¹g ≤ step², in σ;
    0 off; static: it decides what is compiled), the relative cost change of an accepted
    step (`function`; 0 off) and whether the statistical test and the Gauss-Newton steps
    come at every accepted point (`gauss_newton`, static; False: only where the cost change
    passed: `LevenbergMarquardt.gauss_newton`)."""

    rtol: float | Array
    atol: float | Array
    step: float
    function: float | Array
    gauss_newton: bool = True


class LeastSquares(NamedTuple):
    """`optx.least_squares(fn, solver, y0, args, has_aux=True)`'s inputs: `fn(y, args)`
    returns (residuals, None)."""

    fn: Callable
    solver: optx.AbstractLeastSquaresSolver
    y0: Any
    args: Any


class Backend(eqx.Module):
    """How one backend solves the normal equations of a `BundleProblem` inside the loop."""

    name: ClassVar[str]  # "dense" or "schur", as `Adjustment.backend` records it
    # Its Cauchy test's default rtol = atol.
    tolerance: ClassVar[float]
    # Compiled at the top level with the solvers' XLA options (`solver_jit`), which jax
    # refuses on a program nested in `jax.jit` / `jax.vmap`; False: a plain `eqx.filter_jit`,
    # nestable (the Dense backend, which batches vmap).
    top_level: ClassVar[bool]
    # Whether `least_squares` computes (from the problem's values, e.g. a column scale), so
    # that a stepwise solve compiles it; False: it only assembles modules.
    compiled_setup: ClassVar[bool]

    def ready(self, problem: BundleProblem) -> "Backend":
        """This backend with what it derives from `problem`'s indices in NumPy filled in
        (not possible under `jax.jit` / `jax.vmap`: there it must be given)."""
        return self

    def for_steps(self) -> "Backend":
        """This backend tuned for one problem stepped from Python (not vmapped)."""
        return self

    @abc.abstractmethod
    def least_squares(self, problem: BundleProblem, tolerances: Tolerances) -> LeastSquares:
        """The least-squares problem the loop solves for `problem`."""

    @abc.abstractmethod
    def parameters(self, problem: BundleProblem, args: Any, value: Any) -> Parameters:
        """The adjusted Parameters of the loop's final iterate `value` (`args` as given)."""
