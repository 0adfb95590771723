"""A BAL problem as a project against `jaxba bal`: compile time, iterations, CPU and memory.

    python benchmarks/bal_project_compile.py [--repeats 1] [--json OUT.json] [FILE ...]

For each BAL file (default: Dubrovnik-16 and Ladybug-49 from $JAXBA_BAL_DATA, else
/work/shared/data/bal, as benchmarks/bal_vs_ceres.py), `jaxba import bal FILE --out DIR`
writes the project; then, alternating, `jaxba adjust DIR/NAME.toml` and `jaxba bal FILE` run
in fresh processes with OPENBLAS_NUM_THREADS=1 and an empty persistent compilation cache each
(JAX_COMPILATION_CACHE_DIR: what a first run on a new machine compiles). Per run: compile
seconds and programs (results.json: the whole adjustment's `timings` for `adjust`, the
solve's `compile_seconds` for `bal`), iterations (trial steps, accepted or not, as Ceres
counts them), the final cost ½Σe², for `adjust` the free unknowns without a σ and how many
unknowns `no_sigma` names, the process's CPU seconds (user + system) and peak RSS (GNU
time). Prints a
Markdown table with the compile seconds and CPU seconds of `adjust` as a ratio to `bal`'s
in the same repeat.

`adjust` does more than `bal` (datum check, statistics, reports), so its compile seconds hold
the statistics' programs too; the claim measured is that a project's compile time no longer
grows with its cameras (one image-point group per camera model, not per camera).
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

from _processes import process_environment

ROOT = pathlib.Path(__file__).resolve().parents[1]
JAXBA = [sys.executable, "-m", "jaxba"]
DATA = pathlib.Path(os.environ.get("JAXBA_BAL_DATA", "/work/shared/data/bal"))
DEFAULT = ["problem-16-22106-pre.txt.bz2", "problem-49-7776-pre.txt.bz2"]


def _run(command: list[str], cache: pathlib.Path, expect=(0,)) -> tuple[float, float]:
    """CPU seconds (user + system) and peak RSS (MiB) of `command` in a fresh process with
    an empty cache, from GNU time."""
    env = process_environment(JAX_COMPILATION_CACHE_DIR=str(cache))
    usage = cache.with_suffix(".time")
    done = subprocess.run(["/usr/bin/time", "-f", "%U %S %M", "-o", str(usage), *command],
                          env=env, capture_output=True, text=True, cwd=ROOT)
    if done.returncode not in expect:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    user, system, rss_kib = usage.read_text().split()[-3:]
    return float(user) + float(system), float(rss_kib) / 1024


def _adjust(project: pathlib.Path, tmp: pathlib.Path, k: int) -> dict:
    out = tmp / f"adjust{k}"
    cpu, rss = _run([*JAXBA, "adjust", str(project), "--out", str(out)], tmp / f"cache_a{k}",
                    expect=(0, 1))
    data = json.loads((out / "results.json").read_text())
    sigma = [entry["std"] for block in ("cameras", "images", "points")
             for unknowns in data[block].values() for entry in unknowns.values()
             if isinstance(entry, dict) and entry.get("status") == "free"]
    return {"compile_s": data["timings"]["seconds"]["compile"],
            "programs": data["timings"]["compilations"], "iterations": data["steps"] - 1,
            "final_cost": data["iterations"][-1]["cost"], "sigma0": data["sigma0"],
            "converged": data["converged"],
            "no_sigma": sum(s is None for s in sigma), "named": len(data["no_sigma"]),
            "cpu_s": cpu, "rss_mib": rss}


def _bal(path: pathlib.Path, tmp: pathlib.Path, k: int) -> dict:
    out = tmp / f"bal{k}"
    cpu, rss = _run([*JAXBA, "bal", str(path), "--out", str(out)],
                    tmp / f"cache_b{k}")
    data = json.loads((out / "results.json").read_text())
    return {"compile_s": data["compile_seconds"], "programs": data["compilations"],
            "iterations": data["iterations"], "final_cost": data["final_cost"],
            "converged": data["converged"], "cpu_s": cpu, "rss_mib": rss}


def measure(path: pathlib.Path, repeats: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        name = path.name.split(".")[0]
        subprocess.run([*JAXBA, "import", "bal", str(path), "--out", str(tmp / "project")],
                       check=True, capture_output=True, cwd=ROOT)
        project = tmp / "project" / f"{name}.toml"
        runs = [(_adjust(project, tmp, k), _bal(path, tmp, k)) for k in range(repeats)]
    return {"problem": name, "adjust": [a for a, _ in runs], "bal": [b for _, b in runs]}


def _row(problem: str, run: str, entries: list[dict], ratios: dict) -> str:
    def median(key):
        values = [e[key] for e in entries if e[key] is not None]
        return statistics.median(values) if values else float("nan")

    sigma = (f"{median('no_sigma'):.0f} / {median('named'):.0f}" if "no_sigma" in entries[0]
             else "-")
    return (f"| {problem} | {run} | {median('compile_s'):.2f} | {median('programs'):.0f} |"
            f" {median('iterations'):.0f} | {median('final_cost'):.8f} | {sigma} |"
            f" {median('cpu_s'):.1f} | {median('rss_mib'):.0f} |"
            f" {ratios.get('compile', '')} | {ratios.get('cpu', '')} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=pathlib.Path)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args()
    files = args.files or [DATA / name for name in DEFAULT]
    results = [measure(path, args.repeats) for path in files]
    print("| problem | run | compile s | programs | iterations | final cost |"
          " σ missing / named | CPU s | peak RSS MiB | compile / bal | CPU / bal |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for result in results:
        compile_ratio = statistics.median(
            a["compile_s"] / b["compile_s"] for a, b in zip(result["adjust"], result["bal"]))
        cpu_ratio = statistics.median(
            a["cpu_s"] / b["cpu_s"] for a, b in zip(result["adjust"], result["bal"]))
        print(_row(result["problem"], "jaxba adjust (import bal)", result["adjust"],
                   {"compile": f"{compile_ratio:.2f}x", "cpu": f"{cpu_ratio:.2f}x"}))
        print(_row(result["problem"], "jaxba bal", result["bal"], {}))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
