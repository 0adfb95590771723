"""Calibrations per second: jaxba's batched (vmapped) solve against cv2.calibrateCamera.

N replicates of Zhang's calibration (5 images x 256 corners of a planar target, one "opencv"
camera; configs/zhang): the image points are recomputed from the adjusted solution of the real
data (the "truth"), the truth's fx, fy, cx, cy varied by N(0, 5 px) per replicate and Gaussian
noise of `--noise` px added. jaxba solves all N in one compiled call
(`jaxba._adjust._batch.solve_batch`: the Levenberg-Marquardt of `solve`, vmapped over chunks of
`--chunk` replicates, the chunks one after the other) from the project's approximations
(Zhang's closed form, rounded intrinsics); OpenCV calibrates each replicate in a loop from its
own initialisation (CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST: fx, fy, cx, cy, k1, k2 and the
poses; jaxba also estimates the skew). Both in the same process, one after the other.
Then `jaxba batch`'s program on the same replicates (the datum screen, the solve and the
statistics: cofactors of all unknowns, leverages of all observations; chunks of `--chunk`)
against `cv2.calibrateCameraExtended` (which also gives the estimates' standard deviations).

    OPENBLAS_NUM_THREADS=1 python benchmarks/batch_vs_opencv.py [--n 1000] [--chunk 10]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jaxba  # noqa: E402
from jaxba._adjust._batch import _adjust_program, solve_batch  # noqa: E402
from jaxba._problem._observations import collinearity_residual  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def replicates(n: int, noise_px: float, seed: int):
    """The zhang problem, its truth, and per replicate the noisy image points (n, 1280, 2)
    and the true intrinsics."""
    project = jaxba.build_project(jaxba.read_project(ROOT / "configs/zhang/zhang.toml"))
    problem = project.problem
    truth = jaxba.adjust(problem, check=False).parameters
    group = problem.groups[0]
    rng = np.random.default_rng(seed)
    iops = np.repeat(np.asarray(truth.cameras["opencv"])[None], n, axis=0)
    iops[:, 0, :4] += rng.normal(0.0, 5.0, (n, 4))

    def computed(iop):
        def one(eop, point):
            return collinearity_residual("opencv", iop, eop, point, jnp.zeros(2), jnp.ones(2),
                                         problem.refraction)
        # residual with measured 0 and σ 1 is -computed
        return -jax.vmap(one)(truth.images[group.image], truth.points[group.point])

    ideal = np.asarray(jax.jit(jax.vmap(computed))(jnp.asarray(iops[:, 0])))
    measured = ideal + rng.normal(0.0, noise_px, ideal.shape)
    return project, problem, truth, measured, iops[:, 0]


def _replicated(problem, measured):
    """The replicates as one problem with a leading batch axis, and its plan broadcast."""
    plan = jaxba.advanced.linearisation_plan(problem)
    problems = jax.vmap(lambda m: eqx.tree_at(lambda p: p.groups[0].measured, problem, m))(
        jnp.asarray(measured))
    return problems, jaxba.advanced.broadcast_plan(plan, measured.shape[0]), plan.n_free


def _timed(run):
    """run()'s result and seconds, timed twice: compile = the first call less the second."""
    start = time.perf_counter()
    run()
    first_seconds = time.perf_counter() - start
    start = time.perf_counter()
    out = run()
    seconds = time.perf_counter() - start
    return out, seconds, first_seconds - seconds


def run_jaxba(problem, measured, chunk: int):
    """All replicates in one `solve_batch` call (chunks of `chunk`, vmapped, one after the
    other)."""
    problems, plans, _ = _replicated(problem, measured)
    solutions, seconds, compile_seconds = _timed(lambda: jax.block_until_ready(
        solve_batch(problems, plans, max_steps=100, chunk_size=chunk)))
    iops = np.asarray(solutions.parameters.cameras["opencv"][:, 0])
    return iops, np.asarray(solutions.converged), np.asarray(solutions.steps), seconds, \
        compile_seconds


def run_program(problem, measured, chunk: int):
    """`jaxba batch`'s program (datum screen, solve, statistics: cofactors, leverages) of all
    replicates in one call, chunks of `chunk` one after the other (`jaxba batch` calls it
    once per chunk); seconds and compile seconds."""
    problems, plans, n_free = _replicated(problem, measured)
    n = jax.device_put(np.full(measured.shape[0], n_free))
    _, seconds, compile_seconds = _timed(lambda: jax.block_until_ready(
        _adjust_program(problems, plans, n, 100, 1e-8, 1e-8, 1e-9, chunk)))
    return seconds, compile_seconds


def run_opencv(problem, measured, extended: bool = False):
    """`cv2.calibrateCamera` of every replicate in a loop (`extended`:
    `calibrateCameraExtended`, with the standard deviations of the estimates)."""
    group = problem.groups[0]
    image_rows = np.asarray(group.image)
    object_points = np.asarray(problem.initial.points)[np.asarray(group.point)]
    n_images = int(image_rows.max()) + 1
    objects = [object_points[image_rows == i].astype(np.float32) for i in range(n_images)]
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    out = []
    start = time.perf_counter()
    for replicate in measured:
        images = [replicate[image_rows == i].astype(np.float32).reshape(-1, 1, 2)
                  for i in range(n_images)]
        calibrate = cv2.calibrateCameraExtended if extended else cv2.calibrateCamera
        rms, k, dist, *_ = calibrate(objects, images, (640, 480), None, None, flags=flags)
        out.append([k[0, 0], k[1, 1], k[0, 2], k[1, 2], dist.ravel()[0], dist.ravel()[1], rms])
    return np.array(out), time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--chunk", type=int, default=10,
                        help="problems per vmapped chunk (solve_batch's chunk_size)")
    parser.add_argument("--noise", type=float, default=0.5, help="image noise σ, px")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    project, problem, truth, measured, true_iops = replicates(args.n, args.noise, args.seed)
    iops, converged, steps, seconds, compile_seconds = run_jaxba(problem, measured, args.chunk)
    program_seconds, program_compile = run_program(problem, measured, args.chunk)
    cv, cv_seconds = run_opencv(problem, measured)
    _, extended_seconds = run_opencv(problem, measured, extended=True)
    names = jaxba.OpenCVCamera.parameter_names
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f};"
          f" jax {jax.__version__}, OpenCV {cv2.__version__}")
    print(f"{args.n} Zhang-size calibrations (5 images x 256 points), noise {args.noise} px")
    print("| solver | calibrations/s | ms per calibration | compile s | converged |")
    print("|---|---|---|---|---|")
    print(f"| jaxba solve_batch (chunks of {args.chunk}) | {args.n / seconds:.1f} |"
          f" {1e3 * seconds / args.n:.2f} | {compile_seconds:.1f} |"
          f" {int(converged.sum())}/{args.n} (steps median {int(np.median(steps))}) |")
    print(f"| jaxba batch program: datum screen, solve, statistics (chunks of {args.chunk}) |"
          f" {args.n / program_seconds:.1f} | {1e3 * program_seconds / args.n:.2f} |"
          f" {program_compile:.1f} | - |")
    print(f"| cv2.calibrateCamera loop, 1 thread | {args.n / cv_seconds:.1f} |"
          f" {1e3 * cv_seconds / args.n:.2f} | - | - |")
    print(f"| cv2.calibrateCameraExtended loop (with σ), 1 thread |"
          f" {args.n / extended_seconds:.1f} | {1e3 * extended_seconds / args.n:.2f} | - | - |")
    print(f"throughput ratio jaxba / OpenCV: {cv_seconds / seconds:.2f}; batch program /"
          f" calibrateCameraExtended: {extended_seconds / program_seconds:.2f}")
    for j, name in enumerate(("fx", "fy", "cx", "cy", "k1", "k2")):
        k = names.index(name)
        true = true_iops[:, k] if k < 4 else np.asarray(truth.cameras["opencv"][0, k])
        err_j, err_cv = iops[:, k] - true, cv[:, j] - true
        print(f"  {name}: rms error jaxba {np.sqrt(np.mean(err_j**2)):.4g},"
              f" OpenCV {np.sqrt(np.mean(err_cv**2)):.4g}")


if __name__ == "__main__":
    main()
