"""The normal-equation backends' one interface: what `solve` and the statistics ask of Dense
and Schur.

A backend is an equinox Module (a pytree: it travels through `jax.jit` and `jax.vmap` with the
problem) that holds the linear algebra of one form of the normal equations N = JᵀJ (whitened):

| operation      | `Dense` (`_dense.py`,              | `Schur` (`_schur/`)                      |
|                | `_dense_statistics.py`)            |                                          |
|----------------|------------------------------------|------------------------------------------|
| solve          | Levenberg-Marquardt on N           | on S = U - W V⁻¹ Wᵀ, the points          |
|                |                                    | back-substituted (`_descent.py`)         |
| `rank`         | SVD of the equilibrated Jacobian   | null space of S, extended to the points  |
|                |                                    | (`_null_space.py`)                       |
| `cofactors`    | N⁻¹ (bordered by a free network's  | S⁻¹ and every point's 3 x 3 block        |
|                | inner constraints)                 | (`_cofactors.py`, `_leverages.py`)       |
| `leverages`    | diag(J N⁻¹ Jᵀ)                     | per observation from the blocks          |
| `normal_solve` | N⁻¹ b from N⁻¹                     | N⁻¹ b by the split (`_reduced_solve.py`) |

For the solve a backend turns a `BundleProblem` into one optimistix least-squares problem
(residual function, solver: jaxba's trust-region Levenberg-Marquardt with the backend's damped
step, start and arguments) and reads the adjusted Parameters back from optimistix's solution;
`solve` (`_solve.py`) runs it, the backends never call optimistix themselves. The statistics
(`jaxba._statistics`: σ, reliability, the datum check's messages, free networks) read the
other operations' results (`Rank`, `Cofactors`, `Leverages`) and never ask which backend
formed them.
"""

import abc
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

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


class Rank(NamedTuple):
    """The normal equations at the approximations as the datum check reads them, per free
    unknown (`free_indices` order): whether its column of the whitened Jacobian is
    `finite`; that column's norm (`column_norms`, √ of N's diagonal); and `null_space`
    (d, n_free), a basis of the directions no observation sees (rows, unscaled units), None
    where N is regular, or where a column is not finite or zero (no decomposition then: the
    datum check refuses those columns first)."""

    finite: np.ndarray
    column_norms: np.ndarray
    null_space: np.ndarray | None


class Leverages(NamedTuple):
    """j N⁻¹ jᵀ of every real observation's Jacobian row j (`leverage`; the redundancy
    number is 1 - leverage) and its whitened residual, flat in `observation_mask` order."""

    leverage: np.ndarray
    whitened: np.ndarray


class Cofactors(NamedTuple):
    """N⁻¹ of the whitened bundle at a solution, as far as a backend forms it.

    - `squares`: eᵀe, the whitened residuals' sum of squares (σ̂0² = σ0² eᵀe / r);
    - `matrix`: (n_free, n_free) all of N⁻¹ (`free_indices` order); None where only blocks
      are formed:
    - `reduced_positions` (n_r,): `flatten` positions of the reduced unknowns (IOPs, EOPs,
      distance points) and `reduced` (n_r, n_r) their block S⁻¹ (rows of fixed unknowns 0);
    - `points` (n_points, 3, 3): every object point's block (0 for fixed coordinates, NaN
      for a point no two rays intersect);
    - `leverages`, `whitened` (per group, `BundleProblem.whitened`): where the backend forms
      them with the cofactors (one program), else None.
    """

    squares: float
    matrix: np.ndarray | None = None
    reduced_positions: np.ndarray | None = None
    reduced: np.ndarray | None = None
    points: np.ndarray | None = None
    leverages: Leverages | None = None
    whitened: tuple[Array, ...] | None = None


class Backend(eqx.Module):
    """One form of a `BundleProblem`'s normal equations: the damped solve inside the loop,
    and at given parameters their rank, cofactors and leverages (NumPy results, outside
    `jax.jit`; the backend made `ready` for the problem)."""

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
    # Whether its normal matrix holds rows over all unknowns (a free network's inner
    # constraints, `jaxba._statistics._free_network`); False: a free network is adjusted in
    # a minimal datum and its cofactors carried over to the inner constraints.
    holds_inner_constraints: ClassVar[bool]
    # Whether it can leave a minimal datum to the damping (`released_gauge`).
    releases_gauge: ClassVar[bool] = False

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

    def released_gauge(self, gauge: Parameters) -> "Backend":
        """A backend for the problem with the free unknowns `gauge` (booleans like
        `problem.free`, a minimal datum) released: only its Gauss-Newton steps hold them.
        Only where `releases_gauge`."""
        raise NotImplementedError(f"the {self.name} backend holds the datum in every step")

    @abc.abstractmethod
    def rank(self, problem: BundleProblem) -> Rank:
        """The rank of `problem`'s normal equations at its approximations."""

    @abc.abstractmethod
    def cofactors(self, problem: BundleProblem, params: Parameters) -> Cofactors:
        """N⁻¹ at `params` (where N is singular: `LinAlgError`, or NaN cofactors)."""

    def cofactors_ahead(self, problem: BundleProblem) -> None:
        """Start compiling `cofactors`' program on a worker thread where the backend can
        (`jaxba._programs.compile_ahead`); else nothing."""

    @abc.abstractmethod
    def leverages(self, problem: BundleProblem, params: Parameters) -> Leverages:
        """The real observations' leverages at `params`."""

    @abc.abstractmethod
    def normal_solve(self, problem: BundleProblem, params: Parameters,
                     rhs: Float[np.ndarray, "m n_all"]) -> Float[np.ndarray, "m n_all"]:
        """N⁻¹ b at `params` for each right-hand side b (a row of `rhs`, `flatten`
        positions); entries of fixed unknowns ignored in `rhs` and 0 in the result."""
