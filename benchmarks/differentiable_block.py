"""`jaxba.adjusted` on the close-range block of `blocks.py` (Schur backend).

    python benchmarks/differentiable_block.py [PROJECT.toml] [--repeat 2] [--check]

PROJECT.toml: block A as `python benchmarks/blocks.py close-range DIR` writes it (default:
written to a temporary folder, seed 0). Times, compilation apart, the forward `adjusted`
(the Schur backend's Levenberg-Marquardt from the approximations) and one reverse pass: the
gradient of f = Σ_i IOP_i / σ_i over the free IOPs (σ_i = √(N⁻¹)_ii at the optimum, a priori
σ0 = 1) w.r.t. all image coordinates, as `jax.value_and_grad`. The dense adjoint would need
the (n_free, n_free) Hessian (~50 GB at 79,000 unknowns) and is not run. Also prints the
CG iterations of that reverse pass's adjoint solve and, with `--check`, the gradient's
largest entry against a central difference of two re-adjustments. Wall and CPU seconds
(all threads), best of `repeat`, and the peak resident memory; JSON on the last line.
"""

import argparse
import json
import os
import resource
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402

import jaxba  # noqa: E402
from jaxba._solvers._schur._adjoint import (  # noqa: E402
    HESSIAN_TAGS,
    SchurPreconditionedCG,
    _optimality,
    gauss_newton_factor,
)
from jaxba._solvers._schur._structure import bundle_structure  # noqa: E402
from jaxba._statistics._differentiable import adjusted  # noqa: E402

OBS_STEP = 1e-3  # mm, central-difference step of one image coordinate (~0.3 σ)


def _objective(measured, problem, structure, weights):
    """f = Σ weights · camera 0's IOPs of the block adjusted from `measured`."""
    moved = eqx.tree_at(lambda p: p.groups[0].measured, problem, measured)
    params = adjusted(moved, backend="schur", structure=structure)
    return jnp.sum(weights * params.cameras["smac"][0])


def _timed(compiled, *args, repeat):
    """Best wall and CPU seconds of `repeat` runs of a compiled program, and its output."""
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(compiled(*args))
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return min(wall), min(cpu), out


def _compiled(function, *args):
    start = time.perf_counter()
    compiled = eqx.filter_jit(function).lower(*args).compile()
    return compiled, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("project", nargs="?")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    if args.project is None:
        sys.path.insert(0, os.path.dirname(__file__))
        from blocks import write_block

        folder = tempfile.mkdtemp()
        args.project = write_block(folder, "close-range", seed=0)["project"]
    problem = jaxba.build_project(jaxba.read_project(args.project)).problem
    structure = bundle_structure(problem)
    measured = problem.groups[0].measured
    n_coordinates = int(np.sum(np.asarray(problem.groups[0].mask())))
    print(f"{problem.n_observations()} observations ({n_coordinates} image coordinates),"
          f" {problem.n_unknowns()} unknowns, reduced side {structure.n_reduced}", flush=True)

    # σ of the free IOPs at the optimum (outside the timings): N⁻¹ e_i through the Schur split.
    optimum = adjusted(problem, backend="schur", structure=structure)
    factor = gauss_newton_factor(problem, structure, optimum)
    free = np.flatnonzero(np.asarray(problem.free.cameras["smac"][0]))
    zero = jax.tree.map(jnp.zeros_like, optimum)
    variances = []
    for i in free:
        unit = eqx.tree_at(lambda p: p.cameras["smac"], zero,
                           zero.cameras["smac"].at[0, i].set(1.0))
        variances.append(float(factor.solve(unit).cameras["smac"][0, i]))
    weights = jnp.zeros(problem.initial.cameras["smac"].shape[1]).at[free].set(
        1.0 / np.sqrt(variances))

    inputs = (measured, problem, structure, weights)
    forward, forward_compile = _compiled(_objective, *inputs)
    reverse, reverse_compile = _compiled(jax.value_and_grad(_objective), *inputs)
    print(f"compiled: forward {forward_compile:.1f} s, value and gradient"
          f" {reverse_compile:.1f} s", flush=True)
    forward_wall, forward_cpu, value = _timed(forward, *inputs, repeat=args.repeat)
    reverse_wall, reverse_cpu, (_, gradient) = _timed(reverse, *inputs, repeat=args.repeat)
    print(f"forward {forward_wall:.2f} s ({forward_cpu:.2f} s CPU), value and gradient"
          f" {reverse_wall:.2f} s ({reverse_cpu:.2f} s CPU)", flush=True)

    # The adjoint solve of this reverse pass on its own: H v = ∂f/∂x̂, its CG iterations.
    cotangent = jax.grad(lambda x: jnp.sum(weights * x.cameras["smac"][0]))(optimum)
    operator = lx.JacobianLinearOperator(
        lambda y, _: _optimality(y, None, (None, problem)), optimum, None, tags=HESSIAN_TAGS)
    cg = lx.linear_solve(operator, cotangent, SchurPreconditionedCG(factor), throw=False)
    cg_steps = int(cg.stats["num_steps"])

    result = {
        "n_images": int(problem.initial.images.shape[0]),
        "n_points": int(problem.initial.points.shape[0]),
        "n_image_coordinates": n_coordinates,
        "n_unknowns": problem.n_unknowns(),
        "n_reduced": structure.n_reduced,
        "objective": float(value),
        "forward_compile_seconds": forward_compile,
        "value_and_gradient_compile_seconds": reverse_compile,
        "forward_seconds": forward_wall,
        "forward_cpu_seconds": forward_cpu,
        "value_and_gradient_seconds": reverse_wall,
        "value_and_gradient_cpu_seconds": reverse_cpu,
        "cg_steps": cg_steps,
        "cg_converged": bool(cg.result == lx.RESULTS.successful),
    }
    if args.check:
        k, j = np.unravel_index(int(np.argmax(np.abs(np.asarray(gradient)))), gradient.shape)
        ahead = forward(measured.at[k, j].add(OBS_STEP), problem, structure, weights)
        back = forward(measured.at[k, j].add(-OBS_STEP), problem, structure, weights)
        result["check_gradient"] = float(gradient[k, j])
        result["check_central_difference"] = float(ahead - back) / (2 * OBS_STEP)
    result["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(result))


if __name__ == "__main__":
    main()
