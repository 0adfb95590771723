"""jaxba's BAL solve (a BundleProblem, Schur backend) against Ceres on BAL problems, side by side.

    python benchmarks/bal_vs_ceres.py [PROBLEM ...] [--threads 1 2] [--json OUT.json]

Builds benchmarks/ceres_bal.cc with g++ (needs Ceres 2.x headers and library, e.g.
`apt-get install -y libceres-dev`), decompresses each problem to a temporary folder, runs
Ceres (SPARSE_SCHUR and DENSE_SCHUR, the given thread counts), `jaxba._io._bal.run_bal` and the
Python peers of `bal_peers.py` (`--peers`: scipy least_squares with a sparse Jacobian, stock
optx.LevenbergMarquardt where its dense Jacobian fits), each in a fresh process with
OPENBLAS_NUM_THREADS=1, and prints a Markdown table. Default problems: the BAL files of
/work/shared/data/bal, else tests/data/bal.
"""

import argparse
import bz2
import gzip
import json
import pathlib
import subprocess
import sys
import tempfile

from _processes import process_environment

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_FOLDERS = (pathlib.Path("/work/shared/data/bal"), ROOT / "tests" / "data" / "bal")
DEFAULT_NAMES = ("problem-49-7776-pre.txt.bz2", "problem-16-22106-pre.txt.bz2")

JAXBA_RUN = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
from jaxba._cli._bal import run_bal
results = run_bal(sys.argv[1], sys.argv[2], on_iteration=None)
print(json.dumps(results))
"""


def build_ceres(work: pathlib.Path, source: str = "ceres_bal.cc") -> pathlib.Path:
    """Compile benchmarks/`source` with g++ into `work`; returns the executable."""
    executable = work / pathlib.Path(source).stem
    command = [
        "g++",
        "-O3",
        "-DNDEBUG",
        "-std=c++17",
        str(HERE / source),
        "-o",
        str(executable),
        "-I/usr/include/eigen3",
        "-lceres",
        "-lglog",
        "-lgflags",
        "-lpthread",
    ]
    subprocess.run(command, check=True)
    return executable


def decompress(path: pathlib.Path, work: pathlib.Path) -> pathlib.Path:
    opener = {".bz2": bz2.open, ".gz": gzip.open}.get(path.suffix)
    if opener is None:
        return path
    plain = work / path.stem
    with opener(path, "rb") as source:
        plain.write_bytes(source.read())
    return plain


def run_ceres(executable, plain, linear_solver, threads) -> dict:
    output = subprocess.run(
        [str(executable), str(plain), linear_solver, str(threads)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(output)


def run_jaxba(path, work) -> dict:
    environment = process_environment()
    output = subprocess.run(
        [sys.executable, "-c", JAXBA_RUN, str(path), str(work / "jaxba-out")],
        check=True,
        capture_output=True,
        text=True,
        env=environment,
    ).stdout
    results = json.loads(output.strip().splitlines()[-1])
    results["solver"] = "jaxba solve, Schur backend (BundleProblem)"
    return results


def run_peer(peer: str, path) -> dict:
    environment = process_environment()
    output = subprocess.run(
        [sys.executable, str(HERE / "bal_peers.py"), peer, str(path)],
        check=True,
        capture_output=True,
        text=True,
        env=environment,
    ).stdout
    return json.loads(output.strip().splitlines()[-1])


def table(rows: list[tuple[str, dict]]) -> str:
    lines = [
        "| problem | solver | final cost | iterations | solve s | compile s | peak RSS MiB |",
        "|---|---|---|---|---|---|---|",
    ]
    for problem, r in rows:
        solver = r["solver"]
        if "skipped" in r:
            lines.append(f"| {problem} | {solver} | not run: {r['skipped']} | | | | |")
            continue
        if "linear_solver" in r:
            solver += f" {r['linear_solver']}, {r['threads']} thread(s)"
        compile_seconds = f"{r['compile_seconds']:.2f}" if "compile_seconds" in r else "-"
        lines.append(
            f"| {problem} | {solver} | {r['final_cost']:.6f} | {r['iterations']} |"
            f" {r['solve_seconds']:.3f} | {compile_seconds} | {r['peak_rss_mib']:.0f} |"
        )
    return "\n".join(lines)


def default_problems() -> list[pathlib.Path]:
    found = []
    for name in DEFAULT_NAMES:
        for folder in DEFAULT_FOLDERS:
            if (folder / name).exists():
                found.append(folder / name)
                break
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("problems", nargs="*", type=pathlib.Path)
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--json", type=pathlib.Path, default=None, help="also write all results")
    parser.add_argument("--peers", nargs="*", choices=("scipy", "optx"), default=["scipy", "optx"])
    args = parser.parse_args()
    problems = args.problems or default_problems()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        work = pathlib.Path(folder)
        executable = build_ceres(work)
        for path in problems:
            name = path.name.split(".")[0]
            plain = decompress(path, work)
            for linear_solver in ("SPARSE_SCHUR", "DENSE_SCHUR"):
                for threads in args.threads:
                    rows.append((name, run_ceres(executable, plain, linear_solver, threads)))
            rows.append((name, run_jaxba(path, work)))
            for peer in args.peers:
                rows.append((name, run_peer(peer, path)))
            print(f"done: {name}", file=sys.stderr, flush=True)
    print(table(rows))
    if args.json is not None:
        args.json.write_text(json.dumps([{"problem": p, **r} for p, r in rows], indent=2) + "\n")


if __name__ == "__main__":
    main()
