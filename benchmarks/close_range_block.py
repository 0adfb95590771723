"""A close-range synthetic block for `solve_schur`: many points, each seen by few images.

    python benchmarks/close_range_block.py [--images 60] [--points 26000] [--repeat 3]

`images` cameras on a ring of radius 15 m, at 0.5 m and 2.5 m height in turn, every third
rolled by 90°, look at the axis of a cylinder (radius 5 m, height 3 m) carrying `points`
points; each point is seen by 3 or 4 images 3 ring steps apart around the nearest one in
azimuth (3.4 on average: 60 x 26000 -> ~88k image points, ~79k unknowns).
One SMAC camera (c = 35 mm), free xp, yp, c, K1, K2; image σ 0.004 mm with that noise; datum
from 12 control points (5 mm) and 3 distances (1 mm). Approximations: EOPs ±0.05 m / ±0.2°,
points ±0.05 m, c +0.05 mm. Prints the problem size, the seconds of one normal-equation
build (once per accepted iterate) and of one damped solve (every trial step), best of
`repeat`, then the compile and solve seconds of `solve_schur` (JSON on the last line); CPU
seconds count all threads of the process, a measure of the work that a loaded machine does
not inflate.
"""

import argparse
import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from schur_bundle_block import IOP, SIGMA_IMAGE, _project  # noqa: E402

from jaxba._observations import Distances, ImagePoints, ParameterObservations  # noqa: E402
from jaxba._parameters import Parameters  # noqa: E402
from jaxba._problem import BundleProblem  # noqa: E402
from jaxba._rotation import matrix_to_opk  # noqa: E402

FREE_IOP = np.array([1, 1, 1, 0, 1, 1, 0, 0, 0, 0, 0, 0], dtype=bool)


def _look_at(station: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """ω, φ, κ of a camera at `station` whose viewing direction (-z) points at `target`,
    rolled by `roll` (rad) about it."""
    back = (station - target) / np.linalg.norm(station - target)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    x = np.cos(roll) * right + np.sin(roll) * up
    rotation = np.stack([x, np.cross(back, x), back])  # rows: camera axes
    return np.asarray(matrix_to_opk(jnp.asarray(rotation)))


def close_range_block(n_images: int = 60, n_points: int = 26000, *, seed: int = 0):
    """The block described in the module docstring as a `BundleProblem`."""
    rng = np.random.default_rng(seed)
    azimuth = 2 * np.pi * np.arange(n_images) / n_images
    heights = np.where(np.arange(n_images) % 2, 0.5, 2.5)
    stations = np.column_stack([15 * np.cos(azimuth), 15 * np.sin(azimuth), heights])
    rolls = np.pi / 2 * (np.arange(n_images) % 3 == 0)
    angles = [_look_at(s, np.array([0, 0, 1.5]), roll) for s, roll in zip(stations, rolls)]
    eops = np.column_stack([stations, angles])
    theta = rng.uniform(0, 2 * np.pi, n_points)
    points = np.column_stack([5 * np.cos(theta), 5 * np.sin(theta), rng.uniform(0, 3, n_points)])

    step = 2 * np.pi / n_images
    seen = 3 + (rng.random(n_points) < 0.4)
    nearest = np.round(theta / step).astype(int)
    offsets = np.array([0, -3, 3, 6])
    image = np.concatenate([(nearest[seen > k] + offsets[k]) % n_images for k in range(4)])
    point = np.concatenate([np.flatnonzero(seen > k) for k in range(4)])
    measured = jax.jit(jax.vmap(_project, in_axes=(None, 0, 0)))(
        jnp.asarray(IOP), jnp.asarray(eops[image]), jnp.asarray(points[point]))
    measured = np.asarray(measured) + rng.normal(0.0, SIGMA_IMAGE, measured.shape)

    control = rng.choice(n_points, 12, replace=False)
    ends = rng.choice(np.setdiff1d(np.arange(n_points), control), (3, 2), replace=False)
    lengths = np.linalg.norm(points[ends[:, 0]] - points[ends[:, 1]], axis=1)
    groups = (
        ImagePoints(
            name="image_points", model="smac", camera=jnp.zeros(image.size, int),
            image=jnp.asarray(image), point=jnp.asarray(point), measured=jnp.asarray(measured),
            stddev=jnp.full(measured.shape, SIGMA_IMAGE),
        ),
        ParameterObservations(
            name="control", block="points", rows=jnp.asarray(control),
            observed=jnp.asarray(points[control] + rng.normal(0.0, 0.005, (12, 3))),
            stddev=jnp.full((12, 3), 0.005),
        ),
        Distances(
            name="distances", a=jnp.asarray(ends[:, 0]), b=jnp.asarray(ends[:, 1]),
            observed=jnp.asarray(lengths[:, None] + rng.normal(0.0, 0.001, (3, 1))),
            stddev=jnp.full((3, 1), 0.001),
        ),
    )  # fmt: skip
    iop0 = IOP.copy()
    iop0[2] += 0.05
    eop0 = eops + rng.uniform(-1, 1, eops.shape) * np.array([0.05] * 3 + [np.radians(0.2)] * 3)
    initial = Parameters(
        cameras={"smac": jnp.asarray(iop0[None])},
        images=jnp.asarray(eop0),
        points=jnp.asarray(points + rng.uniform(-0.05, 0.05, points.shape)),
    )
    free = Parameters(
        cameras={"smac": jnp.asarray(FREE_IOP[None])},
        images=jnp.ones(eops.shape, bool),
        points=jnp.ones(points.shape, bool),
    )
    return BundleProblem(initial=initial, free=free, groups=groups)


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
    from jaxba._schur._bundle import (
        FUNCTION_TOLERANCE,
        _solve_schur,
        bundle_normal_equations,
        bundle_structure,
        solve_bundle_damped,
    )

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=60)
    parser.add_argument("--points", type=int, default=26000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--max-steps", type=int, default=50)
    args = parser.parse_args()
    start = time.perf_counter()
    problem = close_range_block(args.images, args.points)
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

    settings = (args.max_steps, 1e-10, 1e-10, FUNCTION_TOLERANCE, None)
    start = time.perf_counter()
    compiled = _solve_schur.lower(problem, structure, *settings).compile()
    compile_seconds = time.perf_counter() - start
    start, start_cpu = time.perf_counter(), time.process_time()
    solution = jax.block_until_ready(compiled(problem, structure, *settings))
    solve_seconds, solve_cpu = time.perf_counter() - start, time.process_time() - start_cpu
    print(json.dumps({
        "n_images": args.images,
        "n_points": args.points,
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
