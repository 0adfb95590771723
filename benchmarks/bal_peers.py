"""The Python peers of `bal_vs_ceres.py`, one run per process:

    python benchmarks/bal_peers.py scipy PROBLEM      # scipy least_squares, sparse Jacobian
    python benchmarks/bal_peers.py optx PROBLEM       # stock optx.LevenbergMarquardt (dense)

Both minimise BAL's ½ Σ |residual|² (jaxba._io._bal's model) from the file's start, stop on a
relative cost change below 1e-6 as Ceres' function tolerance does (scipy: ftol; optx:
rtol = atol = 1e-6 on its Cauchy test), and print one JSON line (final cost, iterations,
solve and compile seconds, peak RSS). scipy's `least_squares(method="trf", tr_solver="lsmr",
x_scale="jac")` gets the exact Jacobian as a `scipy.sparse` matrix (the per-observation
blocks by `jax.jacrev`, compiled once: "compile s"). Stock optimistix materialises the dense
Jacobian and QR-factorises it: run only where that fits (`--max-dense-gib`, default 2).
"""

import argparse
import json
import os
import resource
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxba._io._bal._reader import read_bal  # noqa: E402
from jaxba._models._cameras import NoRefraction  # noqa: E402
from jaxba._problem._observations import collinearity_residual  # noqa: E402

FUNCTION_TOLERANCE = 1e-6


def bal_residual(camera, point, observed):
    """One observation's residual (observed - x, pixels) from a BAL camera row (r, t, f, k1,
    k2): jaxba's "bal" camera and "rodrigues" pose, as `jaxba bal` solves it."""
    return collinearity_residual("bal", camera[6:], camera[:6], point, observed, jnp.ones(2),
                                 NoRefraction(), pose="rodrigues")


def _split(x, n_cameras):
    return x[: 9 * n_cameras].reshape(n_cameras, 9), x[9 * n_cameras :].reshape(-1, 3)


def run_scipy(path) -> dict:
    import scipy.optimize
    import scipy.sparse

    bal = read_bal(path)
    n_cameras, n_obs = bal.n_cameras, bal.n_observations
    cameras_i, points_i = jnp.asarray(bal.camera_index), jnp.asarray(bal.point_index)
    observed = jnp.asarray(bal.observed)

    @jax.jit
    def residuals(x):
        cameras, points = _split(x, n_cameras)
        return jnp.ravel(jax.vmap(bal_residual)(cameras[cameras_i], points[points_i], observed))

    @jax.jit
    def blocks(x):
        cameras, points = _split(x, n_cameras)
        jc, jp = jax.vmap(jax.jacrev(bal_residual, argnums=(0, 1)))(
            cameras[cameras_i], points[points_i], observed)
        return jnp.concatenate([jc, jp], axis=2)  # (n_obs, 2, 12)

    rows = np.repeat(np.arange(2 * n_obs), 12)
    columns = np.concatenate([
        9 * bal.camera_index[:, None] + np.arange(9),
        9 * n_cameras + 3 * bal.point_index[:, None] + np.arange(3),
    ], axis=1)  # (n_obs, 12)
    columns = np.repeat(columns[:, None, :], 2, axis=1).ravel()
    n = 9 * n_cameras + 3 * bal.n_points

    def jacobian(x):
        values = np.asarray(blocks(jnp.asarray(x))).ravel()
        return scipy.sparse.csr_matrix((values, (rows, columns)), shape=(2 * n_obs, n))

    x0 = np.concatenate([bal.cameras.ravel(), bal.points.ravel()])
    start = time.perf_counter()
    jax.block_until_ready((residuals(x0), blocks(x0)))
    compile_seconds = time.perf_counter() - start
    start = time.perf_counter()
    solution = scipy.optimize.least_squares(
        lambda x: np.asarray(residuals(jnp.asarray(x))), x0, jac=jacobian, method="trf",
        tr_solver="lsmr", x_scale="jac", ftol=FUNCTION_TOLERANCE, xtol=1e-10, gtol=1e-10)
    solve_seconds = time.perf_counter() - start
    return {
        "solver": "scipy least_squares trf/lsmr, sparse Jacobian",
        "final_cost": float(solution.cost),
        "iterations": int(solution.nfev),
        "solve_seconds": solve_seconds,
        "compile_seconds": compile_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "message": solution.message,
    }


def run_optx(path, max_dense_gib: float) -> dict:
    import optimistix as optx

    bal = read_bal(path)
    n = 9 * bal.n_cameras + 3 * bal.n_points
    dense_gib = 2 * bal.n_observations * n * 8 / 2**30
    if dense_gib > max_dense_gib:
        return {"solver": "optx.LevenbergMarquardt (stock, dense)",
                "skipped": f"dense Jacobian {dense_gib:.0f} GiB > {max_dense_gib} GiB"}
    cameras_i, points_i = jnp.asarray(bal.camera_index), jnp.asarray(bal.point_index)
    observed = jnp.asarray(bal.observed)

    def residuals(x, _):
        cameras, points = _split(x, bal.n_cameras)
        return jnp.ravel(jax.vmap(bal_residual)(cameras[cameras_i], points[points_i], observed))

    solver = optx.LevenbergMarquardt(rtol=FUNCTION_TOLERANCE, atol=FUNCTION_TOLERANCE)
    x0 = jnp.asarray(np.concatenate([bal.cameras.ravel(), bal.points.ravel()]))

    @jax.jit
    def solve(x0):
        solution = optx.least_squares(residuals, solver, x0, max_steps=500, throw=False)
        return solution.value, solution.stats["num_steps"]

    start = time.perf_counter()
    compiled = solve.lower(x0).compile()
    compile_seconds = time.perf_counter() - start
    start = time.perf_counter()
    value, steps = jax.block_until_ready(compiled(x0))
    solve_seconds = time.perf_counter() - start
    return {
        "solver": "optx.LevenbergMarquardt (stock, dense)",
        "final_cost": float(0.5 * jnp.sum(residuals(value, None) ** 2)),
        "iterations": int(steps),
        "solve_seconds": solve_seconds,
        "compile_seconds": compile_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("peer", choices=("scipy", "optx"))
    parser.add_argument("problem")
    parser.add_argument("--max-dense-gib", type=float, default=2.0)
    args = parser.parse_args()
    if args.peer == "scipy":
        result = run_scipy(args.problem)
    else:
        result = run_optx(args.problem, args.max_dense_gib)
    print(json.dumps(result))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
