"""`jaxba batch` of N Zhang-size project files against a Python loop of OpenCV reading them.

    OPENBLAS_NUM_THREADS=1 python benchmarks/batch_end_to_end.py [--n 1000] [--repeat 1]

Writes N projects like configs/zhang (5 images x 256 corners of a planar target, one "opencv"
camera, fx fy cx cy k1 k2 free as OpenCV estimates them (no skew), σ 1 px): the image points
are recomputed from the adjusted solution of the real data with fx, fy, cx, cy varied by
N(0, 5 px) per project and Gaussian noise of 0.5 px added; each project is a folder of its
own files. Then, each in a
fresh process with OPENBLAS_NUM_THREADS=1 and a warm persistent compilation cache (a first
`jaxba batch` of the same projects fills it; its time is printed as "cold"):

- `jaxba batch P1.toml ... PN.toml --out DIR` with its default reports (per project
  NAME.out, NAME.res, NAME.sigma, results.json, observations.csv; summary.csv and .json) and
  its default worker processes (one per CPU, at most one per 100 projects), the same with
  `--reports compact` (NAME.out, NAME.sigma and results.json: no file with a row per
  observation), and with `--jobs 1` (everything in one process);
- a Python loop that reads each project's image_coordinates.txt and target_points.txt with
  NumPy and calls `cv2.calibrateCameraExtended` (1 thread; CALIB_FIX_K3 |
  CALIB_ZERO_TANGENT_DIST, Zhang's initialisation), writing
  nothing.

Prints the wall and CPU times (user + system of every process a command started, worker
processes included: on a shared machine the steadier figure; this process adopts and waits for
the ones that outlive their parent, such as the forkserver the workers come from), the
throughput ratio and the largest difference between the two estimates of fx, fy, cx, cy (px)
over all projects.
"""

import argparse
import csv
import ctypes
import os
import pathlib
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
from _processes import process_environment

ROOT = pathlib.Path(__file__).resolve().parents[1]
ZHANG = ROOT / "configs" / "zhang"
OPENCV_LOOP = r"""
import sys, time, pathlib
import numpy as np, cv2
cv2.setNumThreads(1)
start = time.perf_counter()
flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
out = []
for toml in sys.argv[1:]:
    folder = pathlib.Path(toml).parent
    points = np.loadtxt(folder / "target_points.txt", usecols=(1, 2, 3), dtype=np.float32)
    ids = np.loadtxt(folder / "target_points.txt", usecols=0, dtype=str)
    row = {p: k for k, p in enumerate(ids)}
    table = np.loadtxt(folder / "image_coordinates.txt", dtype=str)
    objects, images = [], []
    for image in dict.fromkeys(table[:, 0]):
        rows = table[table[:, 0] == image]
        objects.append(points[[row[p] for p in rows[:, 1]]])
        images.append(rows[:, 2:4].astype(np.float32).reshape(-1, 1, 2))
    rms, k, dist, *_ = cv2.calibrateCameraExtended(objects, images, (640, 480), None, None,
                                                   flags=flags)
    out.append([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])
np.save(sys.stdin.readline().strip(), np.array(out))
print(time.perf_counter() - start)
"""


def write_projects(root: pathlib.Path, n: int, seed: int = 0, noise: float = 0.5) -> list:
    """N Zhang-like project folders under `root`; returns their TOML paths."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    import jaxba
    from jaxba.advanced import collinearity_residual

    project = jaxba.build_project(jaxba.read_project(ZHANG / "zhang.toml"))
    problem = project.problem
    truth = jaxba.adjust(problem, check=False).parameters
    group = problem.groups[0]
    rng = np.random.default_rng(seed)
    iops = np.repeat(np.asarray(truth.cameras["opencv"]), n, axis=0)
    iops[:, :4] += rng.normal(0.0, 5.0, (n, 4))

    def computed(iop):
        def one(eop, point):
            return -collinearity_residual("opencv", iop, eop, point, jnp.zeros(2), jnp.ones(2),
                                          problem.refraction)
        return jax.vmap(one)(truth.images[group.image], truth.points[group.point])

    ideal = np.asarray(jax.jit(jax.vmap(computed))(jnp.asarray(iops)))
    measured = ideal + rng.normal(0.0, noise, ideal.shape)
    images = np.array(project.image_ids)[np.asarray(group.image)]
    points = np.array(project.point_ids)[np.asarray(group.point)]
    paths = []
    for k in range(n):
        folder = root / f"zhang{k:04d}"
        shutil.copytree(ZHANG, folder, ignore=shutil.ignore_patterns("image_coordinates.txt"))
        toml = folder / "zhang.toml"
        toml.write_text(toml.read_text().replace('name = "zhang"', f'name = "zhang{k:04d}"'))
        cameras = folder / "cameras.toml"  # no skew: OpenCV estimates none
        cameras.write_text(cameras.read_text().replace('"skew", ', ""))
        lines = ["# image_id point_id u v (pixel)"]
        lines += [f"{i} {p} {u:.6f} {v:.6f}" for i, p, (u, v) in zip(images, points, measured[k])]
        (folder / "image_coordinates.txt").write_text("\n".join(lines) + "\n")
        paths.append(toml)
    return paths


PR_SET_CHILD_SUBREAPER = 36  # Linux prctl: orphaned descendants become this process' children


def adopt_orphans() -> None:
    """Make this process the reaper of its descendants' orphans (Linux), so that their CPU
    time reaches RUSAGE_CHILDREN once they are waited for (`timed`)."""
    if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_CHILD_SUBREAPER) failed")


def timed(command: list[str], home: pathlib.Path, stdin: str = "") -> tuple[float, float, str]:
    """Wall s, CPU s (user + system of the process and of every process it started) and
    stdout."""
    env = process_environment(HOME=str(home))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, check=True, env=env, input=stdin, capture_output=True,
                          text=True)
    wall = time.perf_counter() - start
    while True:  # the adopted orphans (a forkserver ends once its parent has)
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            break
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return wall, cpu, done.stdout


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=1, help="warm runs of each; best kept")
    parser.add_argument("--keep", type=pathlib.Path, help="leave the projects and reports here")
    args = parser.parse_args()
    adopt_orphans()
    jaxba_cli = str(pathlib.Path(sys.executable).parent / "jaxba")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or pathlib.Path(tmp)
        home = pathlib.Path(tmp) / "home"
        paths = [str(p) for p in write_projects(root / "projects", args.n)]
        cold = timed([jaxba_cli, "batch", *paths, "--out", str(root / "cold")], home)[:2]
        batch, compact, alone, opencv = [], [], [], []
        for r in range(args.repeat):
            out = root / f"batch{r}"
            batch.append(timed([jaxba_cli, "batch", *paths, "--out", str(out)], home)[:2])
            compact.append(timed([jaxba_cli, "batch", *paths, "--out", str(root / f"compact{r}"),
                                  "--reports", "compact"], home)[:2])
            alone.append(timed([jaxba_cli, "batch", *paths, "--out", str(root / f"one{r}"),
                                "--jobs", "1"], home)[:2])
            estimates = pathlib.Path(tmp) / "opencv.npy"
            opencv.append(timed([sys.executable, "-c", OPENCV_LOOP, *paths], home,
                                stdin=f"{estimates}\n")[:2])
        with open(out / "summary.csv", newline="") as file:
            rows = list(csv.DictReader(file))
        ours = np.array([[float(row[f"C1.opencv.{n}"]) for n in ("fx", "fy", "cx", "cy")]
                         for row in rows])
        difference = np.max(np.abs(ours - np.load(estimates)))
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"{args.n} Zhang-size projects (5 images x 256 points), warm cache, best of"
          f" {args.repeat}")
    print("| command | wall s | projects/s | CPU s | CPU ms per project |")
    print("|---|---|---|---|---|")
    rows = [("jaxba batch (cold cache)", cold),
            ("jaxba batch (default: a worker process per CPU)", min(batch)),
            ("jaxba batch --reports compact (no per-observation files)", min(compact)),
            ("jaxba batch --jobs 1 (one process)", min(alone)),
            ("OpenCV loop (calibrateCameraExtended, 1 thread, reads the files)", min(opencv))]
    for name, (wall, cpu) in rows:
        print(f"| {name} | {wall:.1f} | {args.n / wall:.1f} | {cpu:.1f} |"
              f" {1000 * cpu / args.n:.1f} |")
    print(f"throughput ratio jaxba / OpenCV: {min(opencv)[0] / min(batch)[0]:.2f}"
          f" (--reports compact: {min(opencv)[0] / min(compact)[0]:.2f})")
    print(f"largest |jaxba - OpenCV| of fx, fy, cx, cy: {difference:.2e} px")


if __name__ == "__main__":
    main()
