"""Per-step costs of the Schur backend on the close-range block of `blocks.py`.

    python benchmarks/close_range_block.py [--seed 0] [--repeat 3] [--max-steps 50]

The block (60 images, ~26,000 points each seen by ~3.4 images, ~181,000 image coordinates,
~79,000 unknowns, c xp yp K1 K2 free, dependent relative orientation) is written by
`blocks.write_block(..., "close-range")` and read like any project. Prints the problem size,
the seconds of one normal-equation build (once per accepted iterate) and of one damped solve
(every trial step), best of `repeat`, then the compile and solve seconds of `solve` (Schur)
(JSON on the last line); CPU seconds count all threads of the process, a measure of the work
that a loaded machine does not inflate.
"""

import argparse
import json
import os
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from blocks import write_block  # noqa: E402

import jaxba  # noqa: E402


def close_range_block(seed: int) -> jaxba.BundleProblem:
    """The close-range block of `blocks.py`, built from its project files."""
    with tempfile.TemporaryDirectory() as folder:
        project = write_block(folder, "close-range", seed=seed)["project"]
        return jaxba.build_project(jaxba.read_project(project)).problem


def _best_seconds(function, *args, repeat: int) -> tuple[float, float]:
    """The fastest of `repeat` timed calls of a compiled `function` (after one warm-up):
    wall seconds and the process's CPU seconds (all threads; a loaded machine does not
    inflate them)."""
    jax.block_until_ready(function(*args))
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        jax.block_until_ready(function(*args))
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return min(wall), min(cpu)


def main() -> None:
    from jaxba._solvers._schur._assembly import bundle_normal_equations
    from jaxba._solvers._schur._descent import Schur
    from jaxba._solvers._schur._reduced_solve import solve_bundle_damped
    from jaxba._solvers._schur._structure import bundle_structure
    from jaxba._solvers._solve import lower_solve
    from jaxba._solvers._trust_region import STEP_TOLERANCE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--max-steps", type=int, default=50)
    args = parser.parse_args()
    start = time.perf_counter()
    problem = close_range_block(args.seed)
    structure = bundle_structure(problem)
    n_residuals = sum(int(np.sum(np.asarray(g.mask()))) for g in problem.groups)
    print(f"{n_residuals} residuals, {problem.n_unknowns()} unknowns, reduced side"
          f" {structure.n_reduced}; built in {time.perf_counter() - start:.1f} s", flush=True)

    normal_fn = jax.jit(bundle_normal_equations)
    normal = normal_fn(problem, structure, problem.initial)
    damped_fn = jax.jit(solve_bundle_damped)
    normal_seconds = _best_seconds(normal_fn, problem, structure, problem.initial,
                                   repeat=args.repeat)
    damped_seconds = _best_seconds(damped_fn, structure, normal, 1e-3, repeat=args.repeat)
    print(f"normal equations {normal_seconds[0]:.3f} s ({normal_seconds[1]:.3f} s CPU), damped"
          f" solve {damped_seconds[0]:.3f} s ({damped_seconds[1]:.3f} s CPU)", flush=True)

    settings = dict(max_steps=args.max_steps, rtol=1e-10, atol=1e-10,
                    step_tolerance=STEP_TOLERANCE, function_tolerance=0.0)
    start = time.perf_counter()
    lowered, arguments = lower_solve(problem, Schur(structure), **settings)
    compiled = lowered.compile()
    compile_seconds = time.perf_counter() - start
    start, start_cpu = time.perf_counter(), time.process_time()
    solution = jax.block_until_ready(compiled(*arguments))
    solve_seconds, solve_cpu = time.perf_counter() - start, time.process_time() - start_cpu
    print(json.dumps({
        "n_images": int(problem.initial.images.shape[0]),
        "n_points": int(problem.initial.points.shape[0]),
        "n_residuals": n_residuals,
        "n_unknowns": problem.n_unknowns(),
        "n_reduced": structure.n_reduced,
        "normal_equations_seconds": normal_seconds[0],
        "normal_equations_cpu_seconds": normal_seconds[1],
        "damped_solve_seconds": damped_seconds[0],
        "damped_solve_cpu_seconds": damped_seconds[1],
        "final_cost": float(solution.cost),
        "steps": int(solution.steps),
        "converged": bool(solution.converged),
        "compile_seconds": compile_seconds,
        "solve_seconds": solve_seconds,
        "solve_cpu_seconds": solve_cpu,
    }))


if __name__ == "__main__":
    main()
