"""`run_bal`: solve a BAL problem file as a `BundleProblem` with the Schur backend, time it,
report it.

Plain Python around the jitted core: reads the file, builds the bundle and its Schur split,
solves with `solve` on the Schur backend (with progress one compiled step at a time,
without it as one compiled program), times compilation and solve separately, and writes
`results.json`.
"""

import json
import math
import os
import pathlib
import resource
import time
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import optimistix as optx

from .._files._atomic import replace_files
from .._float64 import require_float64
from .._io._bal._model import bal_bundle
from .._io._bal._reader import BalProblem, read_bal
from .._problem._bundle import BundleProblem
from .._solvers._progress import Iteration, StepRecorder
from .._solvers._schur._descent import Schur
from .._solvers._schur._structure import bundle_structure
from .._solvers._solve import solve
from .._solvers._trust_region import CERES_FUNCTION_TOLERANCE
from .._timing import CompileLog
from ._common import say


@eqx.filter_jit
def _cost(problem: BundleProblem):
    return 0.5 * sum(jnp.sum(e**2) for e in problem.residuals(problem.initial))


def _print_iteration(iteration: Iteration) -> None:
    say(f"  iteration {iteration.iteration:3d}  cost {iteration.cost:.9e}")


def run_bal(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    max_steps: int = 100,
    function_tolerance: float = CERES_FUNCTION_TOLERANCE,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    on_iteration: Callable[[Iteration], None] | None = _print_iteration,
    bal: BalProblem | None = None,
) -> dict:
    """Solve the BAL problem in `path` (plain, .bz2 or .gz) and write `out_dir/results.json`.

    The file becomes a BundleProblem (`bal_bundle`: "bal" cameras, "rodrigues" poses, σ = 1
    pixel) solved by `solve` on the Schur backend (as `jaxba adjust` solves a block), all
    parameters free, no robust loss and no datum check (BAL's gauge freedom is
    left to the damping); stops when an accepted step changes the cost by less than
    `function_tolerance` (relative, as Ceres), on optimistix's rtol/atol test, or after
    `max_steps` steps (trial steps, rejected ones included, as Ceres counts iterations).
    `on_iteration` is called for every accepted iterate (None: silent). `bal`: the problem
    of `path` if already read (`read_bal`). With `on_iteration` the solver runs one compiled
    step at a time (`least_squares_stepwise`); without it the solve is one compiled program
    (~15 % faster on BAL: the loop reuses its buffers) and "cost_history" holds only the
    initial and final costs. Neither holds a host callback, so jax's persistent compilation
    cache serves a second run on the same shapes.

    Needs float64 (`jax.config.update("jax_enable_x64", True)`; the jaxba CLI sets it).
    Returns the dict written to results.json: "problem", "n_cameras", "n_points",
    "n_observations", "initial_cost", "final_cost" (½Σe², pixels²), "iterations" (trial
    steps, accepted or not, as Ceres counts them), "solver_steps" (optimistix's count:
    also step 0, the evaluation of the start), "accepted_iterations", "converged", "message",
    "cost_history" (accepted iterates), "read_seconds", "compile_seconds"
    (tracing and compiling, or loading from the persistent cache), "solve_seconds" (the
    rest of the solve's wall time), "compilations" (programs compiled or loaded),
    "peak_rss_mib" (the process's peak resident memory so far, JAX runtime and compiler
    included). Non-finite numbers are written as null. The file is replaced at once
    (`replace_files`).
    """
    require_float64("run_bal")
    out_dir = pathlib.Path(out_dir)
    start = time.perf_counter()
    bal = read_bal(path) if bal is None else bal
    problem = bal_bundle(bal)
    structure = bundle_structure(problem)
    read_seconds = time.perf_counter() - start

    recorder = StepRecorder(
        redundancy=problem.n_observations() - problem.n_unknowns(), on_iteration=on_iteration
    )
    with CompileLog() as compiles:
        start = time.perf_counter()
        initial_cost = float(_cost(problem))
        solution = solve(
            problem, Schur(structure), max_steps=max_steps, rtol=rtol, atol=atol,
            step_tolerance=0.0, function_tolerance=function_tolerance,
            on_step=None if on_iteration is None else recorder)
        final_cost = float(solution.cost)  # ½|e|² at the final (accepted) iterate
        wall = time.perf_counter() - start
    result = solution.result
    steps = int(solution.steps)
    accepted = int(solution.accepted_steps) - 1  # less step 0, the start
    if on_iteration is not None:
        cost_history = [iteration.cost for iteration in recorder.iterations]
    else:
        cost_history = [initial_cost, final_cost]
    converged = bool(result == optx.RESULTS.successful)
    results = {
        "problem": str(path),
        "n_cameras": bal.n_cameras,
        "n_points": bal.n_points,
        "n_observations": bal.n_observations,
        "initial_cost": initial_cost,
        "final_cost": final_cost,
        "iterations": max(steps - 1, 0),
        "solver_steps": steps,
        "accepted_iterations": accepted,
        "converged": converged,
        "message": "converged" if converged else str(optx.RESULTS[result]),
        "cost_history": cost_history,
        "read_seconds": read_seconds,
        "compile_seconds": compiles.seconds,
        "solve_seconds": wall - compiles.seconds,
        "compilations": compiles.count,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    replace_files({out_dir / "results.json": json.dumps(_json_safe(results), indent=2) + "\n"})
    return results


def _json_safe(value):
    """`value` with every non-finite float (a diverged cost) as None: JSON has no NaN."""
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
