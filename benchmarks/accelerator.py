"""BAL problems and the synthetic 60-image close-range block on whatever device jax uses.

    python benchmarks/accelerator.py [--bal FILE ...] [--block] [--zhang N [--chunk K]]
        [--repeat 2] [--json OUT]

Run it once with a GPU visible and once with `JAX_PLATFORMS=cpu` on the same machine to
compare; the project never needs a GPU (`pip install jax[cuda13]` or a jax with a CUDA
plugin is what makes one visible). In one process per device, float64, each case run
`--repeat` times (the first compiles; the best of the others is kept):

- each BAL file: `jaxba.run_bal` (the Schur backend as one compiled program, Ceres'
  function tolerance 1e-6): compile seconds, solve seconds, iterations, final cost;
- `--block`: the close-range block of `blocks.py` (60 images, ~26,000 points, ~181,000
  image coordinates, c xp yp K1 K2 free, dependent datum) adjusted by `adjust_project` with
  its phases (datum check, solve, statistics: covariance of every unknown's σ, reliability)
  timed apart, compile seconds apart;
- `--zhang N`: N replicates of Zhang's calibration (`batch_vs_opencv.py`'s) solved by the
  vmapped Levenberg-Marquardt in one call, `--chunk` replicates at a time (default all N);
  "solve s" is the whole batch's.

Prints one Markdown table and, with `--json`, writes the rows.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import jaxba  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from blocks import write_block  # noqa: E402


def bal_rows(path: str, repeat: int) -> dict:
    runs = []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(repeat):
            runs.append(jaxba.run_bal(path, out, on_iteration=None))
    best = min(runs[1:] or runs, key=lambda run: run["solve_seconds"])
    return {"case": pathlib.Path(path).name.split(".")[0], "compile_s": runs[0]["compile_seconds"],
            "solve_s": best["solve_seconds"], "iterations": best["iterations"],
            "final_cost": best["final_cost"], "statistics_s": None}


def block_row(repeat: int) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        path = write_block(folder, "close-range", seed=0)["project"]
        project = jaxba.build_project(jaxba.read_project(path))
    runs = []
    for _ in range(repeat):
        timings = jaxba.Timings()
        start = time.perf_counter()
        result = jaxba.adjust_project(project, timings=timings)
        runs.append((time.perf_counter() - start, timings, result))
    first = runs[0][1]
    _, timings, result = min(runs[1:] or runs, key=lambda run: run[0])
    seconds = {p.name: p.seconds - p.compile_seconds for p in timings.phases}
    return {"case": "close-range block (60 images)",
            "compile_s": sum(p.compile_seconds for p in first.phases),
            "solve_s": seconds.get("solve", 0.0), "iterations": result.steps,
            "final_cost": result.iterations[-1].cost,
            "statistics_s": seconds.get("datum check", 0.0) + seconds.get("statistics", 0.0)}


def zhang_row(n: int, chunk: int | None, repeat: int) -> dict:
    from batch_vs_opencv import replicates, run_jaxba

    _, problem, _, measured, _ = replicates(n, 0.5, 0)
    runs = [run_jaxba(problem, measured, chunk or n) for _ in range(max(repeat - 1, 1))]
    _, converged, steps, seconds, compile_seconds = min(runs, key=lambda run: run[3])
    return {"case": f"{n} Zhang calibrations, vmapped ({int(converged.sum())} converged)",
            "compile_s": compile_seconds, "solve_s": seconds,
            "iterations": f"{int(np.median(steps))} (median)", "final_cost": float("nan"),
            "statistics_s": None}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bal", nargs="*", default=[])
    parser.add_argument("--block", action="store_true")
    parser.add_argument("--zhang", type=int, default=0)
    parser.add_argument("--chunk", type=int)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args()
    device = jax.devices()[0]
    name = (f"CPU ({os.cpu_count()} cores)" if device.platform == "cpu"
            else f"{device.platform.upper()} {device.device_kind}")
    rows = [bal_rows(path, args.repeat) for path in args.bal]
    if args.block:
        rows.append(block_row(args.repeat))
    if args.zhang:
        rows.append(zhang_row(args.zhang, args.chunk, args.repeat))
    print(f"device: {name}; jax {jax.__version__}")
    print("| case | device | compile s | solve s | datum + statistics s | iterations |"
          " final cost |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        statistics = "-" if row["statistics_s"] is None else f"{row['statistics_s']:.3f}"
        cost = "-" if np.isnan(row["final_cost"]) else f"{row['final_cost']:.6f}"
        print(f"| {row['case']} | {name} | {row['compile_s']:.2f} | {row['solve_s']:.3f} |"
              f" {statistics} | {row['iterations']} | {cost} |")
    if args.json:
        args.json.write_text(json.dumps([dict(row, device=name) for row in rows], indent=1))


if __name__ == "__main__":
    main()
