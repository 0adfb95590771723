"""`jaxba.adjust` with the object points eliminated against the dense path, on one block.

    python benchmarks/adjust_schur_vs_dense.py [--images 40] [--points 600] [--solvers schur dense]

The nadir block of `schur_bundle_block.synthetic_block` (one SMAC camera with 7 free IOPs,
GNSS/INS, control, distances). Each solver runs in a fresh process (`--one SOLVER`): the datum
check, the solve and the statistics of `jaxba.adjust` plus the redundancy numbers of
`jaxba.reliability`, compile time included (first call in the process); peak RSS is the
process's. Prints a Markdown table; σ̂0, σ(c) and Σ r_i must agree between the rows.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def run_one(images: int, points: int, solver: str) -> dict:
    import importlib.util
    import resource

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import jaxba

    path = pathlib.Path(__file__).with_name("schur_bundle_block.py")
    spec = importlib.util.spec_from_file_location("schur_bundle_block", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    problem = module.synthetic_block(images, points, dense_fraction=0.83, seed=1)
    start = time.perf_counter()
    result = jaxba.adjust(problem, solver=solver)
    adjust_seconds = time.perf_counter() - start
    reliability = jaxba.reliability(result)
    total_seconds = time.perf_counter() - start
    return {
        "solver": solver,
        "unknowns": problem.n_unknowns(),
        "observations": problem.n_observations(),
        "converged": result.converged,
        "sigma0": result.sigma0,
        "std_c": float(result.precision.std.cameras["smac"][0, 2]),
        "sum_r": float(sum(np.sum(r) for r in reliability.redundancy_numbers)),
        "adjust_seconds": adjust_seconds,
        "total_seconds": total_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=40)
    parser.add_argument("--points", type=int, default=600)
    parser.add_argument("--solvers", nargs="+", default=["schur", "dense"])
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.images, args.points, args.one)))
        return
    rows = []
    for solver in args.solvers:
        command = [sys.executable, __file__, "--images", str(args.images), "--points",
                   str(args.points), "--one", solver]
        output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
        rows.append(json.loads(output.strip().splitlines()[-1]))
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print("| solver | unknowns | observations | σ̂0 | σ(c) mm | Σ r_i | adjust s |"
          " + reliability s | peak RSS MiB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['solver']} | {row['unknowns']} | {row['observations']} |"
              f" {row['sigma0']:.6f} | {row['std_c']:.6e} | {row['sum_r']:.1f} |"
              f" {row['adjust_seconds']:.1f} | {row['total_seconds']:.1f} |"
              f" {row['peak_rss_mib']:.0f} |")


if __name__ == "__main__":
    main()
