"""What loading the compiled programs costs one `jaxba adjust` run, per program, warm cache;
and what calling the batch's program through its stored export saves `jaxba batch`.

    python benchmarks/program_loads.py configs/lab/lab.toml
    python benchmarks/blocks.py close-range /tmp/cr
    python benchmarks/program_loads.py /tmp/cr/close_range.toml
    python benchmarks/program_loads.py --batch 20 --repeat 3

A warm run reads every executable from jax's persistent compilation cache, but jax first
traces each program to a jaxpr and lowers it to MLIR to find its cache key, in every process.
The project is adjusted once to fill the cache (a fresh process), then again in a fresh
process that records jax's compile events (`jax.monitoring`: trace, lower, backend compile or
cache read, each with the program's name). Prints one Markdown row per program (a program
run with several shapes counts once per shape) and the totals; OPENBLAS_NUM_THREADS=1.

With `--batch N`: N Zhang-size projects (benchmarks/batch_end_to_end.py's) and `jaxba batch`
of all of them in fresh processes, the batch's program called through its stored export
(`jaxba._programs`, "stored") or traced as before ("traced": the store switched off in that
process), each once to fill the caches, then `--repeat` times alternating. Prints per run
the process's CPU seconds, the CPU seconds of the first call of the batch's program (to its
first result) and jax's trace, lower and cache-read seconds (all programs).
"""

import argparse
import collections
import json
import os
import pathlib
import resource
import subprocess
import sys
import tempfile
import time

from _processes import process_environment

EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "load"}


def _child(argv: list[str]) -> None:
    """Run the command line with the compile events recorded; print them, the process's CPU
    seconds and those of the batch program's first call as JSON on the last line. A first
    argument "stored" or "traced" says how the batch's program is called."""
    import jax

    from jaxba import _programs
    from jaxba._adjust import _batch
    from jaxba._cli._main import main

    events, first = [], []
    if argv[0] in ("stored", "traced"):
        mode, argv = argv[0], argv[1:]
        if mode == "traced":
            _programs._folder = lambda: None
        call_stored = _batch.call_stored

        def timed(*args, **kwargs):
            start = time.process_time()
            out = jax.block_until_ready(call_stored(*args, **kwargs))
            first.append(time.process_time() - start)
            return out

        _batch.call_stored = timed

    def listen(event: str, seconds: float, **kwargs) -> None:
        if event in EVENTS:
            events.append((EVENTS[event], kwargs.get("fun_name", "?"), seconds))

    jax.monitoring.register_event_duration_secs_listener(listen)
    code = main(argv)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"code": code, "events": events, "cpu": usage.ru_utime + usage.ru_stime,
                      "first": first[0] if first else None}))


def _run(argv: list[str]) -> dict:
    env = process_environment()
    command = [sys.executable, __file__, "--child", *argv]
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return json.loads(done.stdout.splitlines()[-1])


def _batch_runs(n: int, repeat: int) -> None:
    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    from batch_end_to_end import write_projects

    with tempfile.TemporaryDirectory() as tmp:
        paths = [str(p) for p in write_projects(pathlib.Path(tmp) / "projects", n)]
        runs = []
        for r in range(repeat + 1):  # the first of each fills the caches
            for mode in ("stored", "traced"):
                out = pathlib.Path(tmp) / f"{mode}{r}"
                run = _run([mode, "batch", *paths, "--out", str(out)])
                if run["code"] != 0 or run["first"] is None:
                    raise RuntimeError(f"jaxba batch ({mode}) failed: exit {run['code']}")
                runs.append((r, mode, run))
    print(f"jaxba batch of {n} Zhang-size projects, load average {os.getloadavg()[0]:.2f}\n")
    print("| run | program | process CPU s | first call CPU s | trace s | lower s |"
          " cache read s |")
    print("|---|---|---|---|---|---|---|")
    for r, mode, run in runs:
        seconds = collections.Counter()
        for kind, _, s in run["events"]:
            seconds[kind] += s
        print(f"| {'fill' if r == 0 else r} | {mode} | {run['cpu']:.2f} | {run['first']:.2f} |"
              f" {seconds['trace']:.2f} | {seconds['lower']:.2f} | {seconds['load']:.2f} |")


def _adjust(project: str, out: str, *, record: bool) -> dict | None:
    argv = ["adjust", project, "--out", out]
    if record:
        return _run(argv)
    env = process_environment()
    command = [sys.executable, "-m", "jaxba", *argv]
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return None


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        _child(sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("project", nargs="?", help="a jaxba project file")
    parser.add_argument("--batch", type=int, metavar="N",
                        help="jaxba batch of N Zhang-size projects, stored against traced")
    parser.add_argument("--repeat", type=int, default=3, help="--batch: runs of each")
    args = parser.parse_args()
    if args.batch:
        _batch_runs(args.batch, args.repeat)
        return
    if args.project is None:
        parser.error("a project file, or --batch N")
    with tempfile.TemporaryDirectory() as out:
        _adjust(args.project, out, record=False)  # fills the cache
        events = _adjust(args.project, out, record=True)["events"]
    # jax names the trace by the function ("_step") and the lowering and compilation by the
    # program ("jit(_step)"): one row per function.
    rows = collections.defaultdict(collections.Counter)
    for kind, name, seconds in events:
        name = name[4:-1] if name.startswith("jit(") and name.endswith(")") else name
        rows[name][kind] += seconds
        rows[name][kind + " n"] += 1
    print(f"{args.project}: {sum(r['load n'] for r in rows.values())} programs loaded,"
          f" load average {os.getloadavg()[0]:.2f}\n")
    print("| program | loads | trace s | lower s | cache read s | total s |")
    print("|---|---|---|---|---|---|")
    total = collections.Counter()
    for name, row in sorted(rows.items(), key=lambda item: -sum(
            item[1][k] for k in ("trace", "lower", "load"))):
        seconds = row["trace"] + row["lower"] + row["load"]
        print(f"| {name} | {row['load n']} | {row['trace']:.3f} | {row['lower']:.3f} |"
              f" {row['load']:.3f} | {seconds:.3f} |")
        total.update(row)
    print(f"| all | {total['load n']} | {total['trace']:.3f} | {total['lower']:.3f} |"
          f" {total['load']:.3f} | {total['trace'] + total['lower'] + total['load']:.3f} |")


if __name__ == "__main__":
    main()
