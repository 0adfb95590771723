"""Wall time of `jaxba batch` on 20 synthetic projects against one `jaxba adjust`.

Writes 20 projects with `write_synthetic_project(seed=k, n_images=8..16, n_targets=30..60)`
into a temporary folder, then runs, each in a fresh process with `OPENBLAS_NUM_THREADS=1`
and a warm persistent compilation cache (a first run of each fills it; its time is printed
as "cold"), as a user who runs them again:

- `jaxba adjust` of the largest project (16 images, 60 targets);
- `jaxba batch` of all 20 (padded, vmapped solves).

Prints the wall times and their ratio (target: batch at most 1.5x single, warm).

    python benchmarks/batch_vs_single.py [--n 20] [--repeat 2]
"""

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

from _processes import process_environment

import jaxba


def write_projects(root: pathlib.Path, n: int) -> list[pathlib.Path]:
    paths = []
    for k in range(n):
        n_images = 8 + (8 * k) // max(n - 1, 1)
        n_targets = 30 + (30 * k) // max(n - 1, 1)
        truth = jaxba.write_synthetic_project(
            root / f"p{k:02d}", name=f"p{k:02d}", seed=k, n_images=n_images,
            n_targets=n_targets)
        paths.append(truth.project_file)
    return paths


def timed(command: list[str], home: pathlib.Path) -> float:
    env = process_environment(HOME=str(home))
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=2, help="runs of each; best is kept")
    args = parser.parse_args()
    jaxba_cli = [str(pathlib.Path(sys.executable).parent / "jaxba")]  # the installed script
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        paths = write_projects(root / "projects", args.n)
        home = root / "home"  # one persistent compilation cache, filled by the cold runs
        adjust = [*jaxba_cli, "adjust", str(paths[-1]), "--out"]
        batch_of_all = [*jaxba_cli, "batch", *map(str, paths), "--out"]
        cold = (timed([*adjust, str(root / "single_cold")], home),
                timed([*batch_of_all, str(root / "batch_cold")], home))
        single, batch = [], []
        for r in range(args.repeat):
            single.append(timed([*adjust, str(root / f"single{r}")], home))
            batch.append(timed([*batch_of_all, str(root / f"batch{r}")], home))
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"| command | cold s | warm s (best of {args.repeat}) | warm runs |")
    print("|---|---|---|---|")
    print(f"| jaxba adjust (largest project) | {cold[0]:.1f} | {min(single):.1f} |"
          f" {', '.join(f'{t:.1f}' for t in single)} |")
    print(f"| jaxba batch ({args.n} projects) | {cold[1]:.1f} | {min(batch):.1f} |"
          f" {', '.join(f'{t:.1f}' for t in batch)} |")
    print(f"ratio batch / single, warm: {min(batch) / min(single):.2f}")


if __name__ == "__main__":
    main()
