"""Where a Zhang-size project's time goes in `jaxba batch`: CPU ms per project, stage by stage.

    OPENBLAS_NUM_THREADS=1 python benchmarks/batch_stages.py [--n 200] [--repeat 2]

Writes N projects as benchmarks/batch_end_to_end.py does, then runs `jaxba batch`'s pipeline
on them in this one process, a stage at a time over all projects (the command interleaves
the stages, on worker processes):

- read: the project files, every output checked against every input, and the tables;
- build: each project's problem, in NumPy;
- group: the projects' kinds and padded shapes, the chunks of 10;
- solve: each chunk padded, its stored program run (datum screen, solve, statistics) and
  each project's results taken out;
- one line per report, formatted: NAME.out (with the tables gathered for all the reports, as
  the batch's writer gathers them first), NAME.res, NAME.sigma, results.json,
  observations.csv;
- write: each project's files replaced together, not flushed one by one (as the batch does).

A first pass loads the programs and warms the caches; then each stage is timed `--repeat`
times over all projects, the best kept. CPU of this process (`time.process_time`: user and
system, XLA's threads included).
"""

import argparse
import pathlib
import shutil
import tempfile
import time

from batch_end_to_end import write_projects

# The report files as the table names them.
REPORT_NAMES = {"out": "NAME.out", "res": "NAME.res", "sigma": "NAME.sigma",
                "json": "results.json", "observations": "observations.csv"}


def stage_times(paths: list[pathlib.Path], out: pathlib.Path) -> dict[str, float]:
    """CPU seconds of each stage over all `paths`, reports written under `out`."""
    from jaxba._cli._batch_adjust import CHUNK, _chunks
    from jaxba._cli._batch_read import read_batch
    from jaxba._cli._batch_solve import solve_chunk
    from jaxba._files._atomic import replace_files
    from jaxba._gc import paused_gc
    from jaxba._project import build_project
    from jaxba._report._collect import shared_tables
    from jaxba._report._outputs import report_paths
    from jaxba._report._write import _WRITERS

    shutil.rmtree(out, ignore_errors=True)
    times: dict[str, float] = {}
    clock = time.process_time()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.process_time()
        times[stage] = times.get(stage, 0.0) + now - clock
        clock = now

    entries = read_batch(paths, out)
    lap("read")
    for entry in entries:
        entry.project = build_project(entry.spec, on_device=False)
    lap("build")
    chunks = _chunks(entries, CHUNK)
    lap("group")
    solved = []
    for members, chunk in chunks:
        solved += zip(members, solve_chunk(chunk))
    lap("solve")
    texts = []
    for entry, outcome in solved:
        paths_by_kind = report_paths(entry.name, entry.out_dir, entry.reports)
        with shared_tables(), paused_gc():
            files = {}
            for kind, path in paths_by_kind.items():
                files[path] = _WRITERS[kind](entry.project, outcome.result)
                lap(f"format {REPORT_NAMES[kind]}")
        texts.append((entry.out_dir, files))
    for folder, files in texts:
        folder.mkdir(parents=True, exist_ok=True)
        replace_files(files, durable=False)
    lap("write")
    return times


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=2, help="timed passes; best kept")
    args = parser.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        paths = write_projects(root / "projects", args.n)
        stage_times(paths, root / "out")  # programs loaded, caches warm
        runs = [stage_times(paths, root / "out") for _ in range(args.repeat)]
    best = {stage: min(run[stage] for run in runs) for stage in runs[0]}
    print(f"{args.n} Zhang-size projects, one process, CPU ms per project (best of"
          f" {args.repeat})")
    print("| stage | ms |\n|---|---|")
    for stage, seconds in best.items():
        print(f"| {stage} | {1000 * seconds / args.n:.2f} |")
    print(f"| all | {1000 * sum(best.values()) / args.n:.2f} |")


if __name__ == "__main__":
    main()
