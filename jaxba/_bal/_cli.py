"""`run_bal`: solve a BAL problem file with the Schur Levenberg-Marquardt, time it, report it.

Plain Python around the jitted core: reads the file, solves (with per-iteration progress
one compiled step at a time, `least_squares_stepwise`; without it as one compiled program),
times compilation and solve separately, and writes `results.json`.
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

from .._float64 import require_float64
from .._progress import Iteration, StepRecorder
from .._report._atomic import replace_files
from .._schur import SchurLevenbergMarquardt, TwoBlockProblem, TwoBlockY, two_block_residuals
from .._steps import least_squares_stepwise
from .._timing import CompileLog
from ._model import bal_initial, bal_two_block
from ._reader import BalProblem, read_bal


def _solver(problem: TwoBlockProblem, *, rtol, atol, function_tolerance):
    return SchurLevenbergMarquardt(
        problem, rtol=rtol, atol=atol, function_tolerance=function_tolerance)


@eqx.filter_jit
def _solve(problem: TwoBlockProblem, y0: TwoBlockY, *, max_steps, **settings) -> optx.Solution:
    """The whole solve as one compiled program (no progress)."""
    return optx.least_squares(two_block_residuals, _solver(problem, **settings), y0,
                              args=problem, max_steps=max_steps, throw=False)


@eqx.filter_jit
def _cost(problem: TwoBlockProblem, y: TwoBlockY):
    return 0.5 * jnp.sum(two_block_residuals(y, problem) ** 2)


def _print_iteration(iteration: Iteration) -> None:
    print(f"  iteration {iteration.iteration:3d}  cost {iteration.cost:.9e}", flush=True)


def run_bal(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    max_steps: int = 100,
    function_tolerance: float = 1e-6,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    on_iteration: Callable[[Iteration], None] | None = _print_iteration,
    bal: BalProblem | None = None,
) -> dict:
    """Solve the BAL problem in `path` (plain, .bz2 or .gz) and write `out_dir/results.json`.

    Levenberg-Marquardt with the Schur-complement step (`SchurLevenbergMarquardt`), all
    parameters free, no robust loss; stops when an accepted step changes the cost by less
    than `function_tolerance` (relative, as Ceres), on optimistix's rtol/atol test, or
    after `max_steps` steps (trial steps, rejected ones included, as Ceres counts
    iterations). `on_iteration` is called for every accepted iterate (None: silent). `bal`:
    the problem of `path` if already read (`read_bal`).
    With `on_iteration` the solver runs one compiled step at a time (`least_squares_stepwise`);
    without it the solve is one compiled program and "cost_history" holds only the initial
    and final costs. Neither holds a host callback, so jax's persistent compilation cache
    serves a second run on the same shapes.

    Needs float64 (`jax.config.update("jax_enable_x64", True)`; the jaxba CLI sets it).
    Returns the dict written to results.json: "problem", "n_cameras", "n_points",
    "n_observations", "initial_cost", "final_cost" (½Σr², pixels²), "iterations" (trial
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
    problem = bal_two_block(bal)
    y0 = bal_initial(bal)
    read_seconds = time.perf_counter() - start

    settings = dict(rtol=rtol, atol=atol, function_tolerance=function_tolerance)
    n_unknowns = 9 * bal.n_cameras + 3 * bal.n_points
    recorder = StepRecorder(
        redundancy=2 * bal.n_observations - n_unknowns, on_iteration=on_iteration
    )
    with CompileLog() as compiles:
        start = time.perf_counter()
        initial_cost = float(_cost(problem, y0))
        if on_iteration is None:
            solution = _solve(problem, y0, max_steps=max_steps, **settings)
        else:
            solution = least_squares_stepwise(
                two_block_residuals, _solver(problem, **settings), y0, problem,
                max_steps=max_steps, on_step=recorder)
        final_cost = float(solution.state.cost)  # ½|r|² at the final (accepted) iterate
        wall = time.perf_counter() - start
    result = solution.result
    steps = int(solution.stats["num_steps"])
    accepted = int(solution.state.num_accepted_steps) - 1  # less step 0
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
