"""The two normal-equation backends behind one interface, for `adjust` and the statistics.

A backend is made for one problem and says how its normal equations are formed and used:

| operation          | `DenseBackend` (calibrations) | `SchurBackend` (blocks)                   |
|--------------------|-------------------------------|-------------------------------------------|
| datum check        | rank of the dense JᵀJ         | null space of S, extended to the points   |
| solve              | Levenberg-Marquardt on N      | Levenberg-Marquardt on S, back-substitute |
| precision          | N⁻¹                           | S⁻¹ and every point's 3 x 3 block         |
| redundancy numbers | diag(J N⁻¹ Jᵀ)                | per-observation leverages from the blocks |
| free network       | minimal datum, bordered N⁻¹   | minimal datum, then S-transformation      |

The statistics above them (σ, correlations, ellipsoids, reliability, variance components, data
snooping) ask `backend_for(problem, result.backend)` and never which one it is.
"""

import abc
from collections.abc import Callable

import equinox as eqx
import numpy as np
from jaxtyping import Array

from .._problem._bundle import BundleProblem
from .._problem._linearisation import dense_jacobian
from .._problem._parameters import Parameters
from .._solvers._dense import Dense
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import bundle_structure
from .._solvers._solution import Solution
from .._solvers._solve import choose_backend, solve, stopping_rule
from ._adjustment import Adjustment
from ._covariance import Precision, equilibrated_jacobian, precision, scaled_cofactor
from ._datum import check_datum, whitened_residuals
from ._free_network import (
    free_network_precision,
    free_network_redundancy_numbers,
    inner_constraint_group,
    minimal_constraints,
    to_inner_datum,
)
from ._gauge import released, to_gauge_datum
from ._schur_datum import check_datum_schur
from ._schur_reliability import (
    schur_precision_and_redundancy,
    schur_redundancy_numbers,
    schur_statistics,
)


class Backend(abc.ABC):
    """Normal equations of one `BundleProblem`: datum check, solve, precision, redundancy."""

    name: str  # "dense" or "schur", as `Adjustment.backend` records it

    def __init__(self, problem: BundleProblem):
        self.problem = problem

    @abc.abstractmethod
    def check_datum(self, labels: list[str] | None = None) -> None:
        """`DatumError` naming the unobservable directions (one label per scalar unknown)."""

    @abc.abstractmethod
    def solve(self, *, max_steps: int, rtol: float, atol: float, stop: str = "statistical",
              on_step: Callable | None = None) -> Solution:
        """Levenberg-Marquardt from the problem's approximations, stopping by the rule `stop`
        names (`stopping_rule`); parameters in its datum."""

    @abc.abstractmethod
    def precision(self, params: Parameters, *, sigma0: float = 1.0) -> Precision:
        """σ̂0², σ of every unknown and the covariance at `params` (`LinAlgError` where the
        normal matrix is singular)."""

    def precision_and_whitened(
        self, params: Parameters, *, sigma0: float = 1.0
    ) -> tuple[Precision, tuple[Array, ...]]:
        """`precision` and the whitened residuals at `params` (`BundleProblem.whitened`,
        per group); `LinAlgError` as `precision`."""
        return self.precision(params, sigma0=sigma0), whitened_residuals(self.problem, params)

    @abc.abstractmethod
    def redundancy_numbers(self, params: Parameters) -> tuple[np.ndarray, np.ndarray]:
        """(r_i, e_i) of the real observations, flat in `observation_mask` order."""


class DenseBackend(Backend):
    """All unknowns in one dense normal matrix: calibrations, batches, vmap."""

    name = "dense"

    def check_datum(self, labels=None):
        check_datum(self.problem, labels=labels)

    def solve(self, *, max_steps, rtol, atol, stop="statistical", on_step=None):
        """A free network in the minimal datum of `minimal_constraints`, then moved to its
        inner constraints (as the Schur backend: adjusted as stiff observations, the
        constraints left Levenberg-Marquardt crawling on weak blocks)."""
        options = dict(max_steps=max_steps, rtol=rtol, atol=atol, on_step=on_step,
                       **stopping_rule(stop))
        if inner_constraint_group(self.problem) is None:
            return solve(self.problem, Dense(), **options)
        minimal = minimal_constraints(self.problem, self.problem.initial)
        solution = solve(minimal, Dense(), **options)
        inner = to_inner_datum(self.problem, solution.parameters)
        return eqx.tree_at(lambda s: s.parameters, solution, inner)

    def precision(self, params, *, sigma0=1.0):
        return precision(self.problem, params, sigma0=sigma0)

    def redundancy_numbers(self, params):
        """1 - diag(J N⁻¹ Jᵀ), from the column-scaled dense Jacobian."""
        jacobian, whitened = (np.asarray(a) for a in dense_jacobian(self.problem, params))
        scaled = equilibrated_jacobian(jacobian)[0]
        leverage = np.sum((scaled @ scaled_cofactor(scaled)) * scaled, axis=1)
        return 1.0 - leverage, whitened


class SchurBackend(Backend):
    """Object points eliminated (`bundle_structure`, built once for every operation). A free
    network is solved with a minimal datum and carried over to its inner constraints
    (`jaxba._statistics._free_network`)."""

    name = "schur"

    def __init__(self, problem: BundleProblem):
        super().__init__(problem)
        self.free_network = inner_constraint_group(problem) is not None
        self.solved = (minimal_constraints(problem, problem.initial) if self.free_network
                       else problem)
        self.structure = bundle_structure(self.solved)

    def check_datum(self, labels=None):
        check_datum_schur(self.solved, labels=labels, structure=self.structure)

    def solve(self, *, max_steps, rtol, atol, stop="statistical", on_step=None):
        """A minimal datum's gauge released (only the Gauss-Newton steps hold it; the
        "cost" rule has none) and the solution moved into the datum after."""
        options = dict(max_steps=max_steps, rtol=rtol, atol=atol, on_step=on_step,
                       **stopping_rule(stop))
        if self.problem.gauge and not self.free_network:  # the datum after the solve
            problem, gauge = released(self.problem)
            held = gauge if options["step_tolerance"] > 0 else None
            solution = solve(problem, Schur(gauge=held), **options)
            moved = to_gauge_datum(self.problem, solution.parameters)
            return eqx.tree_at(lambda s: s.parameters, solution, moved)
        solution = solve(self.solved, Schur(self.structure), **options)
        if not self.free_network:
            return solution
        inner = to_inner_datum(self.problem, solution.parameters)
        return eqx.tree_at(lambda s: s.parameters, solution, inner)

    def precision(self, params, *, sigma0=1.0):
        """With the redundancy numbers in `SchurCovariance.redundancy`: both from one
        compiled program (normal equations, S⁻¹ and the point cofactors formed once)."""
        if self.free_network:
            return free_network_precision(self.problem, params, sigma0=sigma0,
                                          structure=self.structure)
        return schur_precision_and_redundancy(self.problem, params, sigma0=sigma0,
                                              structure=self.structure)

    def precision_and_whitened(self, params, *, sigma0=1.0):
        """Both from the statistics' one program (a bundle with a datum)."""
        if self.free_network:
            return super().precision_and_whitened(params, sigma0=sigma0)
        return schur_statistics(self.problem, params, sigma0=sigma0, structure=self.structure)

    def redundancy_numbers(self, params):
        if self.free_network:
            return free_network_redundancy_numbers(self.problem, params)
        return schur_redundancy_numbers(self.problem, params, structure=self.structure)


BACKENDS: dict[str, type[Backend]] = {"dense": DenseBackend, "schur": SchurBackend}


def backend_for(problem: BundleProblem, solver: str = "auto") -> Backend:
    """The backend for `problem`: `solver` "dense", "schur", or "auto" (`choose_backend`:
    the Schur split for large bundles). `ValueError` for another name."""
    return BACKENDS[choose_backend(problem, solver).name](problem)


def adjusted_redundancy_numbers(result: Adjustment) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) at an adjustment's solution, from the backend that adjusted it: the ones
    computed with its covariance where it kept them, else computed now."""
    blocks = result.precision.schur
    if blocks is not None and blocks.redundancy is not None:
        return blocks.redundancy
    return backend_for(result.problem, result.backend).redundancy_numbers(result.parameters)
