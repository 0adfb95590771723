"""`jaxba adjust` against Ceres 2.1 on synthetic photogrammetric blocks, side by side.

    python benchmarks/block_vs_ceres.py [--shapes close-range close-range-free free-network]
        [--skip-free] [--memory-gib 12] [--timeout 1200] [--json OUT.json]

For each shape (benchmarks/blocks.py) the block is generated into a temporary folder and run,
each in a fresh process with OPENBLAS_NUM_THREADS=1, wall time and peak RSS from
/usr/bin/time:
- `jaxba adjust PROJECT --out DIR` twice (the CLI, with HOME in the temporary folder so that
  jaxba's persistent compilation cache starts cold, then warm: what a user's second run
  costs, the import included): read, datum check, solve, statistics
  (covariance, reliability), reports, compilation included;
- the same pipeline through the Python API (`phases`: `adjust_project` with its `Timings`),
  every phase's run seconds and, apart, the seconds it spent compiling;
- benchmarks/ceres_bundle.cc (built with g++) with SPARSE_SCHUR and DENSE_SCHUR, 1 thread,
  on a text export of the same jaxba problem (`export_problem`, from jaxba's own readers):
  solve, then the IOP covariance (SPARSE_QR). A free network has no inner constraints in Ceres:
  it fixes the first image's six EOPs instead (a minimal datum: the same minimum, and the IOPs
  are invariant under the datum, so their σ agree).
Every child runs under an address-space cap (`--memory-gib`) and `--timeout`; one that fails
is reported as such in the table. Prints two Markdown tables (totals with jaxba / Ceres
ratios, jaxba's phases) and the check of the initial costs (jaxba's ½Σe² at the
approximations against Ceres').
"""

import argparse
import json
import os
import pathlib
import resource
import signal
import subprocess
import sys
import tempfile

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _processes import process_environment  # noqa: E402
from bal_vs_ceres import build_ceres  # noqa: E402
from blocks import write_block  # noqa: E402

SHAPES = {  # name -> (blocks.py shape, free datum)
    "close-range": ("close-range", False),
    "close-range-free": ("close-range", True),
    "free-network": ("free-network", True),
}
LINEAR_SOLVERS = ("SPARSE_SCHUR", "DENSE_SCHUR")
PHASES = ("read", "build", "datum check", "solve", "statistics", "reports")
CLI = "from jaxba._cli._main import entry; entry()"  # what the `jaxba` program runs


# --- jaxba's pipeline, phase by phase (run in a child: `--child phases`) -----------------


def pipeline_pass(project_file: pathlib.Path, out_dir: pathlib.Path) -> tuple[dict, dict]:
    """One `jaxba adjust` through the API, its phases timed by `jaxba._timing.Timings`
    (as the CLI does). Returns ({"run": {phase: seconds}, "compile": {phase: seconds}},
    {"final_cost", "iterations" (accepted), "steps", "std_c"})."""
    import jaxba
    from jaxba._report import write_reports
    from jaxba._timing import Timings

    timings = Timings()
    with timings.phase("read"):
        spec = jaxba.read_project(project_file)
    with timings.phase("build"):
        project = jaxba.build_project(spec)
    result = jaxba.adjust_project(project, timings=timings)
    with timings.phase("reports"):
        write_reports(project, result, out_dir)
    by_name = {phase.name: phase for phase in timings.phases}
    times = {
        "run": {p: by_name[p].seconds - by_name[p].compile_seconds for p in PHASES},
        "compile": {p: by_name[p].compile_seconds for p in PHASES},
    }
    c = json.loads((out_dir / "results.json").read_text())["cameras"]["C1"]["c"]
    outcome = {
        "final_cost": float(result.iterations[-1].cost),
        "iterations": len(result.iterations) - 1,
        "steps": result.steps,
        "std_c": c["std"],
    }
    return times, outcome


def phases_main(project_file: pathlib.Path, out_dir: pathlib.Path) -> None:
    """One pass in this process; prints JSON {"run", "compile", ...outcome}."""
    import jax
    import threadpoolctl

    threadpoolctl.threadpool_limits(1, user_api="blas")
    jax.config.update("jax_enable_x64", True)
    times, outcome = pipeline_pass(project_file, out_dir)
    print(json.dumps({**times, **outcome}))


# --- the Ceres export ---------------------------------------------------------------------


def export_problem(project_file: pathlib.Path, path: pathlib.Path) -> None:
    """Write jaxba's problem of `project_file` as ceres_bundle.cc's text export.

    Supports one SMAC camera model, image points and distances, and a free network's inner
    constraints (exported as the first image's six EOPs fixed); angles in radians, image
    coordinates and σ in mm. Prints JSON {"initial_cost": jaxba's ½Σe² at the
    approximations, "ceres_datum": what replaced the inner constraints, or null}.
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxba
    from jaxba._models._cameras import NoRefraction
    from jaxba._problem._inner_constraints import InnerConstraints
    from jaxba._problem._observations import Distances, ImagePoints

    problem = jaxba.build_project(jaxba.read_project(project_file)).problem
    if list(problem.initial.cameras) != ["smac"] or problem.robust is not None:
        raise ValueError("export_problem: one SMAC camera model and no robust loss only")
    if not isinstance(problem.refraction, NoRefraction):
        raise ValueError("export_problem: no atmospheric refraction")
    initial_cost = 0.5 * sum(float(np.sum(np.square(e))) for e in problem.whitened(problem.initial))
    initial, free = problem.initial, problem.free
    image_free = np.asarray(free.images).copy()
    image_points, distances, datum = [], [], None
    for group in problem.groups:
        if isinstance(group, ImagePoints):
            image_points.append(group)
        elif isinstance(group, Distances):
            distances.append(group)
        elif isinstance(group, InnerConstraints):
            image_free[0], datum = False, "first image's six EOPs fixed"
        else:
            raise ValueError(f"export_problem: no export for group {group.name!r}")

    def rows(values, flags, prefix=None):
        table = np.column_stack([np.asarray(values), np.asarray(flags, dtype=int)])
        formats = ["%.17g"] * np.shape(values)[1] + ["%d"] * np.shape(values)[1]
        if prefix is not None:
            table, formats = np.column_stack([prefix, table]), ["%d", *formats]
        return "\n".join(" ".join(f % v for f, v in zip(formats, row)) for row in table)

    observations = np.concatenate([
        np.column_stack([g.camera, g.image, g.point, g.measured, g.stddev]) for g in image_points
    ])
    camera_of_image = np.zeros(len(image_free), dtype=int)
    camera_of_image[observations[:, 1].astype(int)] = observations[:, 0].astype(int)
    lines = [
        f"cameras {len(initial.cameras['smac'])}",
        rows(initial.cameras["smac"], free.cameras["smac"]),
        f"images {len(image_free)}",
        rows(initial.images, image_free, prefix=camera_of_image),
        f"points {len(initial.points)}",
        rows(initial.points, free.points),
        f"observations {len(observations)}",
        "\n".join(" ".join(f"{int(v)}" for v in row[:3]) + "".join(f" {v:.17g}" for v in row[3:])
                  for row in observations),
        f"distances {sum(len(g.a) for g in distances)}",
        *(f"{a} {b} {d[0]:.17g} {s[0]:.17g}" for g in distances
          for a, b, d, s in zip(np.asarray(g.a), np.asarray(g.b), np.asarray(g.observed),
                                np.asarray(g.stddev))),
    ]
    path.write_text("\n".join(line for line in lines if line) + "\n")
    print(json.dumps({"initial_cost": initial_cost, "ceres_datum": datum}))


CHILD_TASKS = {"phases": phases_main, "export": export_problem}


# --- running children ---------------------------------------------------------------------


def measured_run(command: list[str], work: pathlib.Path, *, memory_gib: float, timeout: float,
                 env: dict | None = None, ok_codes: tuple[int, ...] = (0,)) -> dict:
    """Run `command` under /usr/bin/time with an address-space cap (GiB) and a timeout (s).

    Returns {"ok" (exit status in `ok_codes`), "stdout", "wall_seconds", "peak_rss_mib"}
    and, when not ok, "failure" (the exit status and the last line of stderr, or the timeout).
    """
    limit = int(memory_gib * 2**30)
    timing = work / "time.txt"

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    environment = process_environment(env)
    wrapped = ["/usr/bin/time", "-f", "%e %M", "-o", str(timing), *command]
    child = subprocess.Popen(wrapped, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=environment, preexec_fn=cap, start_new_session=True)
    try:
        stdout, stderr = child.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(child.pid, signal.SIGKILL)
        child.communicate()
        return {"ok": False, "failure": f"time cap {timeout:.0f} s reached"}
    wall, rss_kib = timing.read_text().split()[-2:]
    outcome = {"stdout": stdout, "stderr": stderr, "wall_seconds": float(wall),
               "peak_rss_mib": float(rss_kib) / 1024, "ok": child.returncode in ok_codes}
    if not outcome["ok"]:
        outcome["failure"] = failure(child.returncode, stderr, memory_gib)
    return outcome


def failure(returncode: int, stderr: str, memory_gib: float) -> str:
    """Why a child failed: its exit status and the last line of its stderr."""
    last = (stderr.strip().splitlines() or ["no message"])[-1][:160]
    return f"exit {returncode} under a {memory_gib:g} GiB cap: {last}"


def run_jaxba_cli(project: pathlib.Path, work: pathlib.Path, **caps) -> dict:
    """`jaxba adjust PROJECT --out DIR` with the compilation cache in `work`/home (cold at
    the first call, warm after); results.json read back.

    Exit status 1 (not converged, reports written) counts as a run.
    """
    out = work / "cli-out"
    home = work / "home"
    home.mkdir(exist_ok=True)
    run = measured_run([sys.executable, "-c", CLI, "adjust", str(project), "--out", str(out)],
                       work, env=process_environment(HOME=str(home)), ok_codes=(0, 1), **caps)
    if run["ok"] and not (out / "results.json").exists():
        run |= {"ok": False, "failure": failure(1, run["stderr"], caps["memory_gib"])}
    if run["ok"]:
        results = json.loads((out / "results.json").read_text())
        run |= {"final_cost": results["iterations"][-1]["cost"],
                "iterations": len(results["iterations"]) - 1, "steps": results["steps"],
                "std_c": results["cameras"]["C1"]["c"]["std"]}
    return run


def run_child(task: str, arguments: list[pathlib.Path], work: pathlib.Path, **caps) -> dict:
    """This script's `--child TASK ARGS...` (`CHILD_TASKS`) in a fresh process, its JSON merged
    into the run's record."""
    command = [sys.executable, str(pathlib.Path(__file__).resolve()), "--child", task,
               *map(str, arguments)]
    run = measured_run(command, work, **caps)
    if run["ok"]:
        run |= json.loads(run["stdout"].strip().splitlines()[-1])
    return run


def run_ceres(executable: pathlib.Path, export: pathlib.Path, linear_solver: str,
              work: pathlib.Path, **caps) -> dict:
    """ceres_bundle on the export, 1 thread."""
    run = measured_run([str(executable), str(export), linear_solver, "1"], work, **caps)
    if run["ok"]:
        result = json.loads(run["stdout"])
        run |= result | {"std_c": result["cameras"][0]["c"]["std"] if result["cameras"] else None}
    return run


def run_shape(name: str, executable: pathlib.Path, work: pathlib.Path, args) -> dict:
    """Generate one block and run everything on it; returns its results."""
    shape, free = SHAPES[name]
    folder = work / name
    block = write_block(folder / "project", shape, free=free)
    project = pathlib.Path(block["project"])
    caps = dict(memory_gib=args.memory_gib, timeout=args.timeout)
    results = {"block": block}
    results["jaxba_cli"] = run_jaxba_cli(project, folder, **caps)
    results["jaxba_cli_warm"] = run_jaxba_cli(project, folder, **caps)  # the cache filled
    print(f"{name}: jaxba adjust done", file=sys.stderr, flush=True)
    results["jaxba_phases"] = run_child("phases", [project, folder / "phases-out"], folder,
                                        **caps)
    print(f"{name}: jaxba phases done", file=sys.stderr, flush=True)
    if name == "close-range-free":
        return results  # Ceres has no inner constraints: the close-range row is its reference
    export = folder / "export.txt"
    results["export"] = run_child("export", [project, export], folder, **caps)
    if not results["export"]["ok"]:
        raise RuntimeError(f"{name}: export failed: {results['export']['failure']}")
    for linear_solver in LINEAR_SOLVERS:
        results[f"ceres_{linear_solver}"] = run_ceres(executable, export, linear_solver, folder,
                                                      **caps)
        print(f"{name}: ceres {linear_solver} done", file=sys.stderr, flush=True)
    return results


# --- tables -------------------------------------------------------------------------------


def _number(value, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def totals_table(all_results: dict) -> str:
    """Per shape: jaxba CLI, jaxba API (warm), each Ceres; ratios against Ceres SPARSE_SCHUR."""
    lines = [
        "| block | run | final cost | iterations | solve s | compile s | statistics s |"
        " whole s | peak RSS MiB | σ(c) µm | whole / Ceres SPARSE_SCHUR |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, results in all_results.items():
        reference = results.get("ceres_SPARSE_SCHUR", {})
        reference_wall = reference.get("wall_seconds") if reference.get("ok") else None
        for key, label in (("jaxba_cli", "jaxba adjust (CLI, cold)"),
                           ("jaxba_cli_warm", "jaxba adjust (CLI, warm)"),
                           ("jaxba_phases", "jaxba API, compile apart"),
                           *((f"ceres_{s}", f"Ceres {s}") for s in LINEAR_SOLVERS)):
            if key not in results:
                continue
            r = results[key]
            if not r["ok"]:
                lines.append(f"| {name} | {label} | not run / failed: {r['failure']} |"
                             " | | | | | | | |")
                continue
            solve = compile_seconds = statistics = None
            whole = r["wall_seconds"]
            if key == "jaxba_phases":
                run = r["run"]
                solve, whole = run["solve"], sum(run.values())
                compile_seconds = sum(r["compile"].values())
                statistics = run["statistics"]
            elif key.startswith("ceres"):
                solve, statistics = r["solve_seconds"], r["covariance_seconds"]
            iterations = r["iterations"] if key.startswith("ceres") else (
                f"{r['iterations']} ({r['steps']} steps)")
            ratio = "-" if reference_wall is None or key.startswith("ceres") else (
                f"{whole / reference_wall:.2f}x")
            lines.append(
                f"| {name} | {label} | {r['final_cost']:.4f} | {iterations} |"
                f" {_number(solve, 2)} | {_number(compile_seconds, 1)} |"
                f" {_number(statistics, 2)} | {whole:.2f} | {r.get('peak_rss_mib', 0):.0f} |"
                f" {_number(None if r['std_c'] is None else 1e3 * r['std_c'], 4)} | {ratio} |")
    return "\n".join(lines)


def phases_table(all_results: dict) -> str:
    """jaxba's phases: run seconds and, apart, compile seconds."""
    lines = ["| block | | " + " | ".join(PHASES) + " | total |",
             "|---|---|" + "---|" * (len(PHASES) + 1)]
    for name, results in all_results.items():
        r = results.get("jaxba_phases", {})
        if not r.get("ok"):
            continue
        for key, label in (("run", "run"), ("compile", "compile")):
            values = [r[key][p] for p in PHASES]
            lines.append(f"| {name} | {label} | " + " | ".join(f"{v:.2f}" for v in values)
                         + f" | {sum(values):.2f} |")
    return "\n".join(lines)


def cost_checks(all_results: dict) -> list[str]:
    """jaxba's initial cost against each Ceres run's, relative difference."""
    lines = []
    for name, results in all_results.items():
        if "export" not in results:
            continue
        jaxba_cost = results["export"]["initial_cost"]
        for solver in LINEAR_SOLVERS:
            r = results[f"ceres_{solver}"]
            if r["ok"]:
                relative = abs(r["initial_cost"] - jaxba_cost) / jaxba_cost
                lines.append(f"{name}: initial cost jaxba {jaxba_cost:.10e}, Ceres {solver} "
                             f"{r['initial_cost']:.10e}, relative difference {relative:.1e}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", choices=sorted(SHAPES), default=list(SHAPES))
    parser.add_argument("--skip-free", action="store_true",
                        help="leave out close-range-free (today it fails on memory)")
    parser.add_argument("--memory-gib", type=float, default=12.0,
                        help="address-space cap of every child (GiB)")
    parser.add_argument("--timeout", type=float, default=1200.0, help="time cap per child (s)")
    parser.add_argument("--json", type=pathlib.Path, default=None, help="also write all results")
    parser.add_argument("--child", nargs=3, metavar=("TASK", "PROJECT", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        task, project, out = args.child
        CHILD_TASKS[task](pathlib.Path(project), pathlib.Path(out))
        return
    shapes = [s for s in args.shapes if not (args.skip_free and s == "close-range-free")]
    all_results = {}
    with tempfile.TemporaryDirectory() as folder:
        work = pathlib.Path(folder)
        executable = build_ceres(work, "ceres_bundle.cc")
        for name in shapes:
            all_results[name] = run_shape(name, executable, work, args)
    for results in all_results.values():
        for r in results.values():
            r.pop("stdout", None)
            r.pop("stderr", None)
    if args.json is not None:
        args.json.write_text(json.dumps(all_results, indent=2) + "\n")
    print(totals_table(all_results))
    print()
    print(phases_table(all_results))
    print()
    print("\n".join(cost_checks(all_results)))


if __name__ == "__main__":
    main()
