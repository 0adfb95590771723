"""`run_batch` of N Zhang-size projects in this process against a Dask LocalCluster.

Writes N copies of Zhang's calibration (configs/zhang: 5 images x 256 corners, one "opencv"
camera, 1280 image points) with N(0, `--noise` px) added to the image coordinates, each its
own project, then in one run, with one fresh persistent compilation cache (the workers
inherit it, as `jaxba batch --scheduler local` on one machine does):

- in this process: `run_batch` twice (the first compiles, the second runs the compiled
  programs), the default chunks of 10 projects;
- on a LocalCluster of `--workers` single-threaded worker processes (`--scheduler local:N`),
  started once: `run_batch(..., scheduler=client)` twice (the first: each worker imports jax
  and loads the programs from the cache; the second: warm workers);
- the CPU time per project of each step, on one chunk (little changed by other load, unlike
  the wall times): reading and building (client), the task's NumPy copy (client), solving
  the chunk (worker), the results' NumPy copy (worker), the reports (client);
- the scheduling overhead: `--empty` tasks that do nothing, submitted at once and gathered
  (seconds per task at the client), and, for the warm Dask batch, the workers' busy time
  (the task stream's compute spans) between the first task's start and the last one's end:
  workers idle per task = (workers x that window - busy) / tasks.

Reports are written by the client in both modes (the same code). Prints a Markdown table.

    OPENBLAS_NUM_THREADS=1 python benchmarks/dask_batch.py [--n 200] [--workers 2]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import pathlib  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
ZHANG = ROOT / "configs" / "zhang"


def write_projects(root: pathlib.Path, n: int, noise: float, seed: int) -> list[pathlib.Path]:
    """N copies of configs/zhang named z000.., image coordinates + N(0, noise) px."""
    rng = np.random.default_rng(seed)
    lines = (ZHANG / "image_coordinates.txt").read_text().splitlines()
    toml = (ZHANG / "zhang.toml").read_text()
    paths = []
    for k in range(n):
        name = f"z{k:03d}"
        folder = root / name
        folder.mkdir(parents=True)
        for file in ("cameras.toml", "orientation.txt", "target_points.txt"):
            shutil.copy(ZHANG / file, folder / file)
        rows = []
        for line in lines:
            if line.startswith("#"):
                rows.append(line)
                continue
            image, point, u, v = line.split()
            du, dv = rng.normal(0.0, noise, 2).tolist()
            rows.append(f"{image} {point} {float(u) + du!r} {float(v) + dv!r}")
        (folder / "image_coordinates.txt").write_text("\n".join(rows) + "\n")
        path = folder / f"{name}.toml"
        path.write_text(toml.replace('name = "zhang"', f'name = "{name}"'))
        paths.append(path)
    return paths


def cpu_per_project(paths: list[pathlib.Path], out: pathlib.Path) -> dict[str, float]:
    """CPU ms per project (this process's CPU time: little changed by other load) of each
    step of a batch for one chunk of `paths`, the programs compiled already; and the KB per
    project a task sends to its worker and gets back."""
    import pickle

    import jaxba
    from jaxba._cli._batch_solve import Chunk, solve_chunk
    from jaxba._dask import numpy_copy
    from jaxba._report import write_reports

    n, cpu = len(paths), {}

    def step(name, function):
        start = time.process_time()
        value = function()
        cpu[name] = (time.process_time() - start) / n * 1e3
        return value

    specs = step("read (client)", lambda: [jaxba.read_project(p) for p in paths])

    def build():  # jax computes the arrays asynchronously: their copy waits for them
        projects = [jaxba.build_project(s) for s in specs]
        return projects, numpy_copy(Chunk(tuple(projects), size=n))

    projects, task = step("build, task to NumPy (client)", build)
    outcomes = step("solve the chunk (worker)", lambda: solve_chunk(task))
    back = step("results to NumPy (worker)", lambda: numpy_copy(outcomes))
    step("reports (client)", lambda: [write_reports(p, o.result, out / p.spec.name)
                                      for p, o in zip(projects, back)])
    cpu["KB sent per project"] = len(pickle.dumps(task)) / n / 1024
    cpu["KB back per project"] = len(pickle.dumps(back)) / n / 1024
    return cpu


def timed(function):
    start = time.perf_counter()
    value = function()
    return value, time.perf_counter() - start


def _noop(k):
    return k


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--noise", type=float, default=0.3, help="image noise σ, px")
    parser.add_argument("--empty", type=int, default=500, help="empty tasks timed")
    args = parser.parse_args()
    # One fresh compilation cache for the run, before jax is imported (here, not at import:
    # the worker processes import this module too); the workers inherit the variable.
    cache = tempfile.mkdtemp(prefix="jaxba-dask-bench-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = cache
    try:
        run(args)
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def run(args):
    from jaxba._jax_setup import setup_jax

    setup_jax()  # as the command line: float64, one BLAS thread, the cache above
    from distributed import Client, LocalCluster, get_task_stream

    from jaxba._cli._batch_run import CHUNK, run_batch

    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        paths = write_projects(root / "projects", args.n, args.noise, seed=0)
        rows = {}
        rows["here, cold"], here_cold = timed(lambda: run_batch(paths, root / "here1"))
        rows["here, warm"], here_warm = timed(lambda: run_batch(paths, root / "here2"))
        cluster_seconds = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            cluster_seconds = time.perf_counter() - cluster_seconds
            rows["dask, cold"], dask_cold = timed(
                lambda: run_batch(paths, root / "dask1", scheduler=client))
            with get_task_stream(client) as stream:
                rows["dask, warm"], dask_warm = timed(
                    lambda: run_batch(paths, root / "dask2", scheduler=client))
            spans = [(s["start"], s["stop"]) for task in stream.data
                     for s in task["startstops"] if s["action"] == "compute"]
            busy = sum(stop - start for start, stop in spans)
            window = max(stop for _, stop in spans) - min(start for start, _ in spans)
            n_tasks = len(stream.data)
            _, empty_seconds = timed(lambda: client.gather(client.map(
                _noop, range(args.empty), pure=False)))
        cpu = cpu_per_project(paths[:CHUNK], root / "cpu")
        load.append(os.getloadavg()[0])
    for name, summary in rows.items():
        bad = [r["name"] for r in summary if r["status"] != "ok"]
        assert not bad, f"{name}: not ok: {bad}; {summary[0]['reason']}"
    worst = max(abs(a[k] - b[k]) / max(abs(a[k]), 1e-300)
                for a, b in zip(rows["here, warm"], rows["dask, warm"])
                for k in a if isinstance(a[k], float))
    n = args.n
    print(f"machine: {os.cpu_count()} CPUs, load average {load[0]:.1f} before, {load[1]:.1f}"
          f" after; {n} Zhang-size projects (1280 image points, redundancy"
          f" {rows['here, warm'][0]['redundancy']}), chunks of {CHUNK}: {-(-n // CHUNK)} tasks")
    print("| run | wall s | projects/s |")
    print("|---|---|---|")
    for name, seconds in (("in-process, first (compiles)", here_cold),
                          ("in-process, second", here_warm),
                          (f"Dask LocalCluster {args.workers} workers, first", dask_cold),
                          (f"Dask LocalCluster {args.workers} workers, second", dask_warm)):
        print(f"| {name} | {seconds:.2f} | {n / seconds:.1f} |")
    print(f"LocalCluster start: {cluster_seconds:.2f} s")
    print(f"warm Dask batch: {n_tasks} tasks, {busy / n_tasks * 1e3:.0f} ms compute each;"
          f" from the first task's start to the last one's end {window:.2f} s, workers busy"
          f" {busy:.2f} s of {args.workers} x {window:.2f} s: idle"
          f" {(args.workers * window - busy) / n_tasks * 1e3:.0f} ms per task; the client"
          f" alone (reading and building before, the last reports after)"
          f" {dask_warm - window:.2f} s")
    print(f"empty tasks: {args.empty} in {empty_seconds:.2f} s,"
          f" {empty_seconds / args.empty * 1e3:.2f} ms each")
    print(f"Dask against in-process (warm runs): largest relative difference {worst:.1e}")
    print(f"per project, one chunk of {CHUNK}, compiled: " + ", ".join(
        f"{name} {value:.1f}" + ("" if name.startswith("KB") else " ms CPU")
        for name, value in cpu.items()))


if __name__ == "__main__":
    main()
