"""One solve for every caller: adjust, batches, BAL, Monte Carlo and the differentiable path.

`solve(problem, backend)` runs jaxba's trust-region Levenberg-Marquardt
(`jaxba._solvers._trust_region`) with the backend's damped step (`Dense`: the normal equations
of all free unknowns; `Schur`: the object points eliminated) through `optx.least_squares`,
the only place that calls it. Three ways to run, one loop:

- at the top level, one compiled program (the Schur backend's with the solvers' XLA options);
- inside a caller's `jax.jit` / `jax.vmap` / `jax.grad` (a batch, Monte Carlo, `adjusted`),
  traced into the caller's program; `adjoint` says how derivatives pass the optimum;
- with `on_step`, one compiled step at a time from Python (`least_squares_stepwise`), every
  step reported, no host callback in a program (jax's persistent cache keeps them).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import optimistix as optx

from .._problem._bundle import BundleProblem
from .._programs import call_stored, stored
from ._backend import Backend, Tolerances
from ._compiled import solver_jit
from ._dense import Dense
from ._schur._choice import SOLVERS, use_schur
from ._schur._descent import Schur
from ._solution import Solution
from ._steps import StepInfo, compile_step_ahead, least_squares_stepwise
from ._trust_region import CERES_FUNCTION_TOLERANCE, COST_RULE_STEP_TOLERANCE, STEP_TOLERANCE

# Where a solve stops (`stopping_rule`): solve's step_tolerance, function_tolerance and
# gauss_newton.
STOPPING_RULES = {"statistical": (STEP_TOLERANCE, 0.0, True),
                  "cost": (COST_RULE_STEP_TOLERANCE, CERES_FUNCTION_TOLERANCE, False)}


def solve(
    problem: BundleProblem,
    backend: Backend | str = "auto",
    *,
    max_steps: int = 50,
    rtol: float | None = None,
    atol: float | None = None,
    step_tolerance: float = STEP_TOLERANCE,
    function_tolerance: float = 0.0,
    gauss_newton: bool = True,
    on_step: Callable[[StepInfo], None] | None = None,
    adjoint: optx.AbstractAdjoint | None = None,
) -> Solution:
    """Levenberg-Marquardt on `problem`'s free unknowns from its approximations.

    `backend`: a `Dense` or `Schur` backend, or its name ("auto": `choose_backend`).
    Converged at an accepted iterate from which the Gauss-Newton step would move every
    unknown by less than `step_tolerance` of its σ (gᵀN⁻¹g ≤ τ²; 0: off), where an accepted
    step lowered the cost by at most `function_tolerance` of it (0: off; BAL's gauge-free
    problems stop this way, as Ceres does; with `gauss_newton` False and a step tolerance,
    where both tests hold: `stopping_rule`'s "cost"), or where
    optimistix's Cauchy test passes (step and residual change within `rtol`, `atol`;
    default the backend's `tolerance`), or when
    every step from it is rejected down to the trust region's minimum radius. No datum
    check, no statistics.

    Pure (jit, vmap and grad pass through it) where the backend is: `Dense` with its `plan`
    given under a transformation that traces the problem's indices; `Schur` never under
    `jax.vmap` (its split is NumPy). `adjoint`: optimistix's, for derivatives of the
    solution (default `optx.ImplicitAdjoint()`). `on_step(StepInfo)` hears every step (not
    under a transformation).
    """
    backend = choose_backend(problem, backend) if isinstance(backend, str) else backend
    tolerances = _tolerances(backend, rtol, atol, step_tolerance, function_tolerance,
                             gauss_newton)
    adjoint = optx.ImplicitAdjoint() if adjoint is None else adjoint
    if _traced(problem):  # nested in the caller's program as a call of its own
        return _compiled(problem, backend, tolerances, max_steps, adjoint)
    backend = backend.ready(problem)
    if on_step is not None:
        return _stepwise(problem, backend.for_steps(), tolerances, max_steps, on_step)
    program, arguments = _program(problem, backend, tolerances, max_steps, adjoint)
    return call_stored("solve", program, arguments)


def lower_solve(
    problem: BundleProblem,
    backend: Backend | str = "auto",
    *,
    max_steps: int = 50,
    rtol: float | None = None,
    atol: float | None = None,
    step_tolerance: float = STEP_TOLERANCE,
    function_tolerance: float = 0.0,
    gauss_newton: bool = True,
):
    """`solve`'s compiled program for `problem` lowered, and its arguments: `lowered.compile()
    (*arguments)` is `solve(problem, backend, ...)` with the same settings, for timing
    compilation apart from the run."""
    backend = choose_backend(problem, backend) if isinstance(backend, str) else backend
    tolerances = _tolerances(backend, rtol, atol, step_tolerance, function_tolerance,
                             gauss_newton)
    program, arguments = _program(problem, backend.ready(problem), tolerances, max_steps,
                                  optx.ImplicitAdjoint())
    return program.lower(*arguments), arguments


def compile_stepwise_ahead(
    problem: BundleProblem,
    backend: Backend,
    *,
    rtol: float | None = None,
    atol: float | None = None,
    step_tolerance: float = STEP_TOLERANCE,
    function_tolerance: float = 0.0,
    gauss_newton: bool = True,
) -> None:
    """Start compiling the step program that `solve(problem, backend, ..., on_step=...)`
    with the same settings runs, on a worker thread (`compile_step_ahead`): for a caller
    with other work before the solve (a datum check). Nothing for a backend whose setup is a
    program of its own (`compiled_setup`: Dense)."""
    tolerances = _tolerances(backend, rtol, atol, step_tolerance, function_tolerance,
                             gauss_newton)
    backend = backend.ready(problem).for_steps()
    if not backend.compiled_setup:
        compile_step_ahead(*backend.least_squares(problem, tolerances), has_aux=True)


def stopping_rule(name: str) -> dict:
    """`solve`'s `step_tolerance`, `function_tolerance` and `gauss_newton` for the stopping
    rule `name`: "statistical" (the default: the Gauss-Newton steps, and stop where the next
    would move every unknown by less than `STEP_TOLERANCE` of its σ) or "cost" (Ceres' rule,
    as `jaxba bal`: damped steps until an accepted step lowers the cost by at most
    `CERES_FUNCTION_TOLERANCE` of it; there stop where the next Gauss-Newton step would move
    every unknown by less than `COST_RULE_STEP_TOLERANCE` of its σ, else try that step).
    `ValueError` for another name."""
    if name not in STOPPING_RULES:
        raise ValueError(f"stop must be one of {', '.join(STOPPING_RULES)}, not {name!r}")
    step_tolerance, function_tolerance, gauss_newton = STOPPING_RULES[name]
    return {"step_tolerance": step_tolerance, "function_tolerance": function_tolerance,
            "gauss_newton": gauss_newton}


def _tolerances(backend: Backend, rtol, atol, step_tolerance, function_tolerance,
                gauss_newton) -> Tolerances:
    """The stopping rules, rtol and atol defaulting to the backend's `tolerance`."""
    return Tolerances(rtol=backend.tolerance if rtol is None else rtol,
                      atol=backend.tolerance if atol is None else atol,
                      step=step_tolerance, function=function_tolerance,
                      gauss_newton=gauss_newton)


def _program(problem, backend, tolerances, max_steps, adjoint):
    """The top-level program and its arguments. The tolerances as arrays, traced: solves
    that differ only in them share one program (`jax.device_put`: `jnp.asarray` compiled a
    program to stage a Python float); the step test's stays static (whether it is 0
    decides what is compiled)."""
    tolerances = tolerances._replace(rtol=jax.device_put(tolerances.rtol),
                                     atol=jax.device_put(tolerances.atol),
                                     function=jax.device_put(tolerances.function))
    program = _top_level if backend.top_level else _compiled
    return program, (problem, backend, tolerances, max_steps, adjoint)


def choose_backend(problem: BundleProblem, name: str = "auto") -> Backend:
    """The backend `name` ("dense", "schur", or "auto": `use_schur`, the Schur split for
    large bundles) for `problem`. Where the problem's arrays are traced (`jax.jit`,
    `jax.vmap`: no NumPy count of its observations, and a batch needs it), "auto" is
    Dense. `ValueError` for another name, or for "schur" where the Schur split cannot
    adjust the problem (`use_schur`)."""
    if name not in SOLVERS:
        raise ValueError(f"backend must be one of {', '.join(SOLVERS)}, not {name!r}")
    if name == "dense":
        return Dense()
    try:  # the values under jax.grad, a tracer's error under jit / vmap (after its checks)
        schur = use_schur(stop_gradient(problem), name)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):
        schur = name == "schur"
    return Schur() if schur else Dense()


def _traced(problem: BundleProblem) -> bool:
    """Whether `problem` is being traced by a caller's transformation (`jax.jit`,
    `jax.vmap`, `jax.grad`: its arrays are tracers)."""
    return any(isinstance(leaf, jax.core.Tracer)
               for leaf in jax.tree.leaves(eqx.filter(problem, eqx.is_array)))


def stop_gradient(tree):
    """`tree` with `jax.lax.stop_gradient` on its inexact arrays (its other leaves as they
    are): a problem whose values count but whose derivatives do not."""
    dynamic, static = eqx.partition(tree, eqx.is_inexact_array)
    return eqx.combine(jax.lax.stop_gradient(dynamic), static)


def _least_squares(problem, backend, tolerances, max_steps, adjoint) -> Solution:
    fn, solver, y0, args = backend.least_squares(problem, tolerances)
    solution = optx.least_squares(fn, solver, y0, args=args, has_aux=True,
                                  max_steps=max_steps, adjoint=adjoint, throw=False)
    return _solution(problem, backend, args, solution)


_compiled = eqx.filter_jit(_least_squares)
# The whole loop in one program runs every iteration inside it: XLA's default emitters, the
# faster code (`jaxba._solvers._compiled`).
_top_level = solver_jit(_least_squares, fusion_emitters=True)


def _stepwise(problem, backend, tolerances, max_steps, on_step) -> Solution:
    if backend.compiled_setup:
        fn, solver, y0, args = _setup(problem, backend, tolerances)
    else:
        fn, solver, y0, args = backend.least_squares(problem, tolerances)
    solution = least_squares_stepwise(fn, solver, y0, args, has_aux=True,
                                      max_steps=max_steps, on_step=on_step)
    return _read_solution(problem, backend, args, solution)


def _solution(problem, backend: Backend, args, solution: optx.Solution) -> Solution:
    return Solution(
        parameters=backend.parameters(problem, args, solution.value),
        converged=solution.result == optx.RESULTS.successful,
        steps=solution.stats["num_steps"],
        accepted_steps=solution.state.num_accepted_steps,
        cost=solution.state.cost,  # ½Σẽ² at the final (accepted) iterate
        result=solution.result,
    )


@stored("solve_setup")
@eqx.filter_jit
def _setup(problem, backend, tolerances):
    return backend.least_squares(problem, tolerances)


_read_solution = stored("solve_solution")(eqx.filter_jit(_solution))
