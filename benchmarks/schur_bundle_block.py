"""A large synthetic self-calibrating block for the Schur backend, built in memory (no files).

    python benchmarks/schur_bundle_block.py [--images 200] [--points 3000] [--dense-fraction 0.83]

A nadir block: `images` cameras on a grid 500 m above a 200 m x 200 m field of `points`
(Z within ±10 m), one SMAC camera (c = 35 mm, the BASC lens's relative distortion), every
point inside every image; each (image, point) pair is observed with probability
`dense-fraction` (0.83: 200 x 3000 -> ~1M image residuals). Image σ 0.004 mm with that noise;
GNSS/INS on every EOP (0.05 m, 0.01°), 20 control points (0.01 m), 5 distances (1 mm);
free: xp, yp, c, K1, K2, P1, P2 and everything else. Approximations: EOPs ±0.5 m / ±0.2°,
points ±0.5 m, c ±0.05 mm. Prints the problem size, the compile and solve seconds and the
process's peak resident memory (JSON on the last line); *_cpu_seconds are the process's CPU
seconds (all threads), a measure of the work that a loaded machine does not inflate.
"""

import argparse
import json
import os
import resource
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxba._models._cameras import CAMERA_MODELS  # noqa: E402
from jaxba._models._rotation import opk_to_matrix  # noqa: E402
from jaxba._problem._bundle import BundleProblem  # noqa: E402
from jaxba._problem._observations import Distances, ImagePoints, ParameterObservations  # noqa: E402
from jaxba._problem._parameters import Parameters  # noqa: E402

IOP = np.array([0.01, -0.02, 35.0, 0.0, -2.0e-5, 1.0e-9, 0.0, 2.0e-6, -1.0e-6, 0.0, 0.0, 0.0])
FREE_IOP = np.array([1, 1, 1, 0, 1, 1, 0, 1, 1, 0, 0, 0], dtype=bool)
SIGMA_IMAGE = 0.004  # mm


def _project(iop, eop, point):
    """The measured image point of `point` (mm): SMAC distortion at the measured point, solved
    by fixed-point iteration (x = image_point(p, x))."""
    camera = CAMERA_MODELS["smac"].from_parameters(iop)
    p_camera = opk_to_matrix(eop[3:]) @ (point - eop[:3])
    x = camera.image_point(p_camera, jnp.stack([iop[0], iop[1]]), 0.0)
    for _ in range(6):
        x = camera.image_point(p_camera, x, 0.0)
    return x


def synthetic_block(
    n_images: int = 200, n_points: int = 3000, *, dense_fraction: float = 0.83, seed: int = 0
) -> BundleProblem:
    """The block described in the module docstring as a `BundleProblem`."""
    rng = np.random.default_rng(seed)
    columns = int(np.ceil(np.sqrt(n_images)))
    grid = np.stack(np.meshgrid(np.linspace(-100, 100, columns), np.linspace(-100, 100, columns)))
    stations = grid.reshape(2, -1).T[:n_images]
    angles = rng.normal(0.0, np.radians(1.0), (n_images, 3))
    angles[:, 2] += np.pi * (np.arange(n_images) % 2)  # alternate strip direction
    eops = np.column_stack([stations, np.full(n_images, 500.0), angles])
    points = np.column_stack(
        [rng.uniform(-100, 100, (n_points, 2)), rng.uniform(-10, 10, n_points)]
    )
    pairs = np.argwhere(rng.random((n_images, n_points)) < dense_fraction)
    image, point = pairs[:, 0], pairs[:, 1]
    measured = jax.jit(jax.vmap(_project, in_axes=(None, 0, 0)))(
        jnp.asarray(IOP), jnp.asarray(eops[image]), jnp.asarray(points[point])
    )
    measured = np.asarray(measured) + rng.normal(0.0, SIGMA_IMAGE, measured.shape)

    control = rng.choice(n_points, 20, replace=False)
    rest = np.setdiff1d(np.arange(n_points), control)
    ends = rng.choice(rest, (5, 2), replace=False)
    lengths = np.linalg.norm(points[ends[:, 0]] - points[ends[:, 1]], axis=1)
    gnss_sigma = np.array([0.05] * 3 + [np.radians(0.01)] * 3)
    groups = (
        ImagePoints(
            name="image_points", model="smac", camera=jnp.zeros(image.size, int),
            image=jnp.asarray(image), point=jnp.asarray(point), measured=jnp.asarray(measured),
            stddev=jnp.full(measured.shape, SIGMA_IMAGE),
        ),
        ParameterObservations(
            name="gnss_ins", block="images", rows=jnp.arange(n_images),
            observed=jnp.asarray(eops + rng.normal(0.0, 1.0, eops.shape) * gnss_sigma),
            stddev=jnp.asarray(np.broadcast_to(gnss_sigma, eops.shape)),
        ),
        ParameterObservations(
            name="control", block="points", rows=jnp.asarray(control),
            observed=jnp.asarray(points[control] + rng.normal(0.0, 0.01, (20, 3))),
            stddev=jnp.full((20, 3), 0.01),
        ),
        Distances(
            name="distances", a=jnp.asarray(ends[:, 0]), b=jnp.asarray(ends[:, 1]),
            observed=jnp.asarray(lengths[:, None] + rng.normal(0.0, 0.001, (5, 1))),
            stddev=jnp.full((5, 1), 0.001),
        ),
    )  # fmt: skip
    iop0 = IOP.copy()
    iop0[2] += 0.05
    eop0 = eops + rng.uniform(-1, 1, eops.shape) * np.array([0.5] * 3 + [np.radians(0.2)] * 3)
    initial = Parameters(
        cameras={"smac": jnp.asarray(iop0[None])},
        images=jnp.asarray(eop0),
        points=jnp.asarray(points + rng.uniform(-0.5, 0.5, points.shape)),
    )
    free = Parameters(
        cameras={"smac": jnp.asarray(FREE_IOP[None])},
        images=jnp.ones(eops.shape, bool),
        points=jnp.ones(points.shape, bool),
    )
    return BundleProblem(initial=initial, free=free, groups=groups)


def main() -> None:
    from jaxba._solvers._schur._descent import Schur
    from jaxba._solvers._schur._structure import bundle_structure
    from jaxba._solvers._solve import lower_solve
    from jaxba._solvers._trust_region import STEP_TOLERANCE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=200)
    parser.add_argument("--points", type=int, default=3000)
    parser.add_argument("--dense-fraction", type=float, default=0.83)
    parser.add_argument("--max-steps", type=int, default=50)
    args = parser.parse_args()
    start = time.perf_counter()
    problem = synthetic_block(args.images, args.points, dense_fraction=args.dense_fraction)
    structure = bundle_structure(problem)
    n_residuals = sum(int(np.sum(np.asarray(g.mask()))) for g in problem.groups)
    build_seconds = time.perf_counter() - start
    print(f"{n_residuals} residuals, {problem.n_unknowns()} unknowns,"
          f" reduced side {structure.n_reduced}; built in {build_seconds:.1f} s", flush=True)
    settings = dict(max_steps=args.max_steps, rtol=1e-10, atol=1e-10,
                    step_tolerance=STEP_TOLERANCE)
    start, cpu = time.perf_counter(), time.process_time()
    lowered, arguments = lower_solve(problem, Schur(structure), **settings)
    compiled = lowered.compile()
    compile_seconds, compile_cpu = time.perf_counter() - start, time.process_time() - cpu
    initial_cost = 0.5 * sum(float(jnp.sum(r**2)) for r in problem.residuals(problem.initial))
    start, cpu = time.perf_counter(), time.process_time()
    solution = jax.block_until_ready(compiled(*arguments))
    solve_seconds, solve_cpu = time.perf_counter() - start, time.process_time() - cpu
    results = {
        "n_images": args.images,
        "n_points": args.points,
        "n_residuals": n_residuals,
        "n_unknowns": problem.n_unknowns(),
        "n_reduced": structure.n_reduced,
        "initial_cost": initial_cost,
        "final_cost": float(solution.cost),
        "sigma0": float(np.sqrt(2 * float(solution.cost) / (n_residuals - problem.n_unknowns()))),
        "steps": int(solution.steps),
        "converged": bool(solution.converged),
        "compile_seconds": compile_seconds,
        "solve_seconds": solve_seconds,
        "compile_cpu_seconds": compile_cpu,
        "solve_cpu_seconds": solve_cpu,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    print(json.dumps(results))


if __name__ == "__main__":
    main()
