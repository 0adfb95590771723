"""What loading the compiled programs costs one `jaxba adjust` run, per program, warm cache.

    python benchmarks/program_loads.py configs/lab/lab.toml
    python benchmarks/blocks.py close-range /tmp/cr
    python benchmarks/program_loads.py /tmp/cr/close_range.toml

A warm run reads every executable from jax's persistent compilation cache, but jax first
traces each program to a jaxpr and lowers it to MLIR to find its cache key, in every process.
The project is adjusted once to fill the cache (a fresh process), then again in a fresh
process that records jax's compile events (`jax.monitoring`: trace, lower, backend compile or
cache read, each with the program's name). Prints one Markdown row per program (a program
run with several shapes counts once per shape) and the totals; OPENBLAS_NUM_THREADS=1.
"""

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile

EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "load"}


def _child(argv: list[str]) -> None:
    """Adjust with the compile events recorded; print them as JSON on the last line."""
    import jax

    from jaxba._cli._main import main

    events = []

    def listen(event: str, seconds: float, **kwargs) -> None:
        if event in EVENTS:
            events.append((EVENTS[event], kwargs.get("fun_name", "?"), seconds))

    jax.monitoring.register_event_duration_secs_listener(listen)
    code = main(argv)
    print(json.dumps({"code": code, "events": events}))


def _adjust(project: str, out: str, *, record: bool) -> dict | None:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    argv = ["adjust", project, "--out", out]
    command = ([sys.executable, __file__, "--child", *argv] if record
               else [sys.executable, "-m", "jaxba", *argv])
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return json.loads(done.stdout.splitlines()[-1]) if record else None


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        _child(sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("project", help="a jaxba project file")
    args = parser.parse_args()
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
