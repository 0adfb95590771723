"""A bundle on one normal-equation backend, in the datum that backend adjusts it in.

The backends (`jaxba._solvers`: `Dense`, `Schur`) hold the linear algebra of the normal
equations; `Adjustable` decides which problem each operation runs on and reads the results:

| operation     | the backend's (`Backend`)          | here, on top of it                         |
|---------------|------------------------------------|--------------------------------------------|
| datum check   | `rank`: N's null space at the      | the defect named (`_datum.check_rank`)     |
|               | approximations                     |                                            |
| solve         | `solve(problem, backend)`          | a released gauge moved into its datum      |
|               |                                    | (`_gauge`); a free network solved in a     |
|               |                                    | minimal datum, moved to its inner          |
|               |                                    | constraints (`_free_network`)              |
| precision     | `cofactors`: N⁻¹, or S⁻¹ and the   | σ̂0², σ, Cxx (`_covariance`); a free        |
|               | points' 3 x 3 blocks               | network's S-transformation                 |
| redundancy    | `leverages`: j N⁻¹ jᵀ per          | r = 1 - j N⁻¹ jᵀ                           |
| numbers       | observation                        | (`_covariance.redundancy_numbers`)         |

A backend that holds a free network's inner constraints (`holds_inner_constraints`: Dense)
checks and forms its cofactors with them (the bordered N⁻¹); one that cannot (Schur) works in
the minimal datum throughout. The statistics above (σ, correlations, ellipsoids, reliability,
variance components, data snooping) ask `adjustable(problem, result.backend)` and never which
backend it is.
"""

import functools
from collections.abc import Callable

import equinox as eqx
import numpy as np
from jaxtyping import Array

from .._problem._bundle import BundleProblem
from .._problem._parameters import Parameters
from .._solvers._backend import Backend
from .._solvers._solution import Solution
from .._solvers._solve import choose_backend, compile_stepwise_ahead, solve, stopping_rule
from ._adjustment import Adjustment
from ._covariance import Precision, precision, precision_from_cofactors, redundancy_numbers
from ._datum import check_rank, whitened_residuals
from ._free_network import (
    free_network_precision,
    free_network_redundancy_numbers,
    inner_constraint_group,
    minimal_constraints,
    to_inner_datum,
)
from ._gauge import released, to_gauge_datum


class Adjustable:
    """`problem` on `backend`, which is made ready (`Backend.ready`: the Schur split built once
    for every operation) for the problem it solves, a free network's minimal datum
    (`minimal_constraints`), else `problem` itself: on first use, so that the work and its
    programs fall in the phase that first needs them (`adjust`'s timings)."""

    def __init__(self, problem: BundleProblem, backend: Backend):
        self.problem = problem
        self.name = backend.name  # "dense" or "schur", as `Adjustment.backend` records it
        self.free_network = inner_constraint_group(problem) is not None
        # A free network's cofactors from the minimal datum, S-transformed.
        self.in_minimal_datum = self.free_network and not backend.holds_inner_constraints
        self._chosen = backend
        self._released: dict[bool, tuple[BundleProblem, Backend]] = {}  # `_solved_on`'s

    @functools.cached_property
    def solved(self) -> BundleProblem:
        """The problem the backend solves."""
        if not self.free_network:
            return self.problem
        return minimal_constraints(self.problem, self.problem.initial)

    @functools.cached_property
    def backend(self) -> Backend:
        """The backend, ready for `solved`."""
        return self._chosen.ready(self.solved)

    def check_datum(self, labels: list[str] | None = None) -> None:
        """`DatumError` naming the unobservable directions (one label per scalar unknown)."""
        checked = self.solved if self.in_minimal_datum else self.problem
        check_rank(checked, self.backend.rank(checked), labels=labels)

    def solve(self, *, max_steps: int, rtol: float, atol: float, stop: str = "statistical",
              on_step: Callable | None = None) -> Solution:
        """Levenberg-Marquardt from the problem's approximations, stopping by the rule `stop`
        names (`stopping_rule`); parameters in its datum: a minimal datum left to the damping
        where the backend can (`released_gauge`; only the Gauss-Newton steps hold it, and the
        "cost" rule has none), then moved into it; a free network in its minimal datum, then
        moved to its inner constraints (as stiff observations the constraints left
        Levenberg-Marquardt crawling on weak blocks)."""
        settings = dict(max_steps=max_steps, rtol=rtol, atol=atol, on_step=on_step,
                        **stopping_rule(stop))
        problem, backend = self._solved_on(settings["step_tolerance"])
        solution = solve(problem, backend, **settings)
        if self._releases_gauge:
            return _moved(solution, to_gauge_datum(self.problem, solution.parameters))
        if not self.free_network:
            return solution
        return _moved(solution, to_inner_datum(self.problem, solution.parameters))

    def compile_ahead(self, *, rtol: float, atol: float, stop: str = "statistical") -> None:
        """Start compiling the step program of `solve(..., on_step=...)` with these settings
        on a worker thread (`compile_stepwise_ahead`), where the backend compiles its
        programs at the top level (Schur: programs of seconds; Dense: nothing)."""
        if self._chosen.top_level:
            settings = stopping_rule(stop)
            compile_stepwise_ahead(*self._solved_on(settings["step_tolerance"]), rtol=rtol,
                                   atol=atol, **settings)

    def compile_statistics_ahead(self) -> None:
        """Start compiling `precision_and_whitened`'s cofactors program on a worker thread
        where the backend can (`Backend.cofactors_ahead`: after the datum check)."""
        if not self.in_minimal_datum:
            self.backend.cofactors_ahead(self.problem)

    @property
    def _releases_gauge(self) -> bool:
        return bool(self.problem.gauge) and not self.free_network and self._chosen.releases_gauge

    def _solved_on(self, step_tolerance: float) -> tuple[BundleProblem, Backend]:
        """The problem `solve` solves and its backend, ready (its split built once)."""
        if not self._releases_gauge:
            return self.solved, self.backend
        held = step_tolerance > 0  # the statistical test needs the Gauss-Newton steps
        if held not in self._released:
            problem, gauge = released(self.problem)
            backend = self._chosen.released_gauge(gauge if held else None).ready(problem)
            self._released[held] = problem, backend
        return self._released[held]

    def precision(self, params: Parameters, *, sigma0: float = 1.0) -> Precision:
        """σ̂0², σ of every unknown and the covariance at `params` (`LinAlgError` where the
        dense normal matrix is singular); in blocks with the redundancy numbers where the
        backend forms them so (`SchurCovariance.redundancy`: one program for both)."""
        if self.in_minimal_datum:
            return free_network_precision(self.problem, params, sigma0=sigma0,
                                          backend=self.backend)
        return precision(self.problem, params, sigma0=sigma0, backend=self.backend)

    def precision_and_whitened(
        self, params: Parameters, *, sigma0: float = 1.0
    ) -> tuple[Precision, tuple[Array, ...]]:
        """`precision` and the whitened residuals at `params` (`BundleProblem.whitened`,
        per group): from the cofactors' program where the backend forms them there."""
        if self.in_minimal_datum:
            return (self.precision(params, sigma0=sigma0),
                    whitened_residuals(self.problem, params))
        cofactors = self.backend.cofactors(self.problem, params)
        whitened = (whitened_residuals(self.problem, params) if cofactors.whitened is None
                    else cofactors.whitened)
        return precision_from_cofactors(self.problem, params, cofactors, sigma0=sigma0), whitened

    def redundancy_numbers(self, params: Parameters) -> tuple[np.ndarray, np.ndarray]:
        """(r_i, e_i) of the real observations, flat in `observation_mask` order."""
        if self.in_minimal_datum:
            return free_network_redundancy_numbers(self.problem, params, backend=self.backend)
        return redundancy_numbers(self.backend.leverages(self.problem, params))


def _moved(solution: Solution, parameters: Parameters) -> Solution:
    return eqx.tree_at(lambda s: s.parameters, solution, parameters)


def adjustable(problem: BundleProblem, solver: str = "auto") -> Adjustable:
    """`problem` on the backend `solver` names: "dense", "schur", or "auto" (`choose_backend`:
    the Schur split for large bundles). `ValueError` for another name."""
    return Adjustable(problem, choose_backend(problem, solver))


def adjusted_redundancy_numbers(result: Adjustment) -> tuple[np.ndarray, np.ndarray]:
    """(r_i, e_i) at an adjustment's solution, from the backend that adjusted it: the ones
    computed with its covariance where it kept them, else computed now."""
    blocks = result.precision.schur
    if blocks is not None and blocks.redundancy is not None:
        return blocks.redundancy
    return adjustable(result.problem, result.backend).redundancy_numbers(result.parameters)
