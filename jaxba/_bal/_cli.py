"""`run_bal`: solve a BAL problem file with the Schur Levenberg-Marquardt, time it, report it.

Plain Python around the jitted core: reads the file, compiles the solve once for the
problem's shapes (timed separately), runs it with per-iteration progress (the `verbose`
hook of `jaxba._progress`), and writes `results.json`.
"""

import functools
import json
import os
import pathlib
import resource
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optimistix as optx

from .._progress import Iteration, StepRecorder, listening, report_step
from .._schur import SchurLevenbergMarquardt, TwoBlockProblem, TwoBlockY, two_block_residuals
from ._model import bal_initial, bal_two_block
from ._reader import read_bal


@functools.partial(
    jax.jit, static_argnames=("max_steps", "rtol", "atol", "function_tolerance", "progress")
)
def _solve(
    problem: TwoBlockProblem,
    y0: TwoBlockY,
    *,
    max_steps: int,
    rtol: float,
    atol: float,
    function_tolerance: float,
    progress: bool = True,
):
    """The whole solve, jitted: final (cameras, points), cost, iterations, steps, result,
    accepted steps.

    iterations = trial steps, as Ceres counts them: the solver's steps less step 0 (the
    evaluation of y0).
    `progress`: report every step to the host (`report_step`, a `jax.debug.callback`).
    Executables with host callbacks are never written to jax's persistent compilation
    cache (jax/_src/compiler.py `_cache_write`: "Not writing persistent cache entry ...
    because it uses host callbacks"), so progress=False is what makes a second run on
    the same shapes load the solve from the cache.
    """
    solver = SchurLevenbergMarquardt(
        problem,
        rtol=rtol,
        atol=atol,
        function_tolerance=function_tolerance,
        verbose=report_step if progress else False,
    )
    solution = optx.least_squares(
        two_block_residuals, solver, y0, args=problem, max_steps=max_steps, throw=False
    )
    final_cost = 0.5 * jnp.sum(two_block_residuals(solution.value, problem) ** 2)
    steps = solution.stats["num_steps"]
    iterations = jnp.maximum(steps - 1, 0)
    accepted = solution.state.num_accepted_steps - 1  # less step 0
    return solution.value, final_cost, iterations, steps, solution.result, accepted


def _buffers_mib(memory) -> float | None:
    """Arguments + outputs + temporaries of the compiled solve (None if XLA cannot say)."""
    if memory is None:
        return None
    total = memory.argument_size_in_bytes + memory.output_size_in_bytes + memory.temp_size_in_bytes
    return total / 2**20


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
    progress: bool | None = None,
) -> dict:
    """Solve the BAL problem in `path` (plain, .bz2 or .gz) and write `out_dir/results.json`.

    Levenberg-Marquardt with the Schur-complement step (`SchurLevenbergMarquardt`), all
    parameters free, no robust loss; stops when an accepted step changes the cost by less
    than `function_tolerance` (relative, as Ceres), on optimistix's rtol/atol test, or
    after `max_steps` steps (trial steps, rejected ones included, as Ceres counts
    iterations). `on_iteration` is called for every accepted iterate (None: silent).
    `progress` (default: whether `on_iteration` is given) compiles the per-step host
    callback in; without it the solve has no host callback, jax's persistent compilation
    cache can store it (a second run on the same shapes compiles from the cache) and
    "cost_history" holds only the initial and final costs.

    Needs float64 (`jax.config.update("jax_enable_x64", True)`; the jaxba CLI sets it).
    Returns the dict written to results.json: "problem", "n_cameras", "n_points",
    "n_observations", "initial_cost", "final_cost" (½Σr², pixels²), "iterations" (trial
    steps, accepted or not, as Ceres counts them), "solver_steps" (optimistix's count:
    also step 0, the evaluation of the start), "accepted_iterations", "converged", "message",
    "cost_history" (accepted iterates), "read_seconds", "compile_seconds",
    "solve_seconds" (the compiled solve alone), "peak_rss_mib" (the process's peak
    resident memory so far, JAX runtime and compiler included), "xla_buffers_mib" (the
    compiled solve's arguments, outputs and temporaries).
    """
    if not jax.config.jax_enable_x64:
        raise ValueError(
            "run_bal needs float64: call jax.config.update('jax_enable_x64', True) first"
        )
    out_dir = pathlib.Path(out_dir)
    start = time.perf_counter()
    bal = read_bal(path)
    problem = bal_two_block(bal)
    y0 = bal_initial(bal)
    read_seconds = time.perf_counter() - start

    start = time.perf_counter()
    initial_cost = float(0.5 * jnp.sum(jax.jit(two_block_residuals)(y0, problem) ** 2))
    settings = dict(
        max_steps=max_steps, rtol=rtol, atol=atol, function_tolerance=function_tolerance
    )
    if progress is None:
        progress = on_iteration is not None
    settings["progress"] = progress
    compiled = _solve.lower(problem, y0, **settings).compile()
    compile_seconds = time.perf_counter() - start
    memory = compiled.memory_analysis()

    n_unknowns = 9 * bal.n_cameras + 3 * bal.n_points
    recorder = StepRecorder(
        redundancy=2 * bal.n_observations - n_unknowns, on_iteration=on_iteration
    )
    with listening(recorder):
        start = time.perf_counter()
        outputs = jax.block_until_ready(compiled(problem, y0))
        _, final_cost, iterations, steps, result, accepted = outputs
        solve_seconds = time.perf_counter() - start
    final_cost = float(final_cost)
    if progress:
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
        "iterations": int(iterations),
        "solver_steps": int(steps),
        "accepted_iterations": int(accepted),
        "converged": converged,
        "message": "converged" if converged else str(optx.RESULTS[result]),
        "cost_history": cost_history,
        "read_seconds": read_seconds,
        "compile_seconds": compile_seconds,
        "solve_seconds": solve_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "xla_buffers_mib": _buffers_mib(memory),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    return results
