"""`jaxba batch PROJECT... --out DIR`: many projects adjusted in padded, vmapped solves, here or
on a Dask cluster, with a summary."""

import argparse
import os
import pathlib

from ._common import EXIT_NOT_CONVERGED, EXIT_OK, UsageError, common_options, say, setup_jax


def add_batch(subparsers) -> None:
    parser = subparsers.add_parser(
        "batch",
        help="adjust many projects in padded, vmapped solves, here or on a Dask cluster",
        description=(
            "Adjust every PROJECT.toml (projects of one kind share one compiled, vmapped solve),"
            " write each project's reports into DIR/<project name>/ and summary.csv and"
            " summary.json into DIR. A failing project is reported in the summary and does"
            " not stop the others. With --scheduler the solves run as tasks on the workers of"
            " a Dask cluster (pip install 'jaxba[dask]'). Exit codes: 0 all converged, 1 some"
            " project failed or did not converge, 2 bad usage (or a report would overwrite"
            " an input, or the scheduler cannot be used), 3 internal error, 130 interrupted."
        ),
        parents=[common_options()],
    )
    parser.add_argument("projects", type=pathlib.Path, nargs="+", metavar="PROJECT.toml")
    parser.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR",
                        help="folder for the per-project reports and the summary")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="a bar over the projects (default: only on a terminal)")
    parser.add_argument(
        "--scheduler", default=None, metavar="ADDRESS|local[:N]",
        help="solve on Dask: a scheduler's address (tcp://host:8786), or local:N for N worker"
             " processes on this machine (local: one per CPU); default: in this process")
    parser.add_argument(
        "--jobs", type=int, default=None, metavar="N",
        help="worker processes on this machine, each adjusting a share of the projects from"
             " end to end, reports included (default: one per CPU, at most one per 100"
             " projects; 1: all in this process; not with --scheduler)")
    parser.add_argument(
        "--chunk", type=int, default=None, metavar="N",
        help="projects per vmapped solve, one Dask task (default 10); the results do not"
             " depend on where the solves run, only (to rounding) on N")
    parser.add_argument(
        "--reports", choices=("all", "compact"), default="all",
        help="each project's reports: all (NAME.out, NAME.res, NAME.sigma, results.json,"
             " observations.csv; default) or compact (without the two files of a row per"
             " observation, NAME.res and observations.csv)")
    parser.add_argument(
        "--resume", action="store_true",
        help="skip projects whose reports are all in DIR already (an earlier, interrupted"
             " run); their summary rows are read from their results.json")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from jaxba._cli._batch_read import read_batch
    from jaxba._dask import SchedulerError, check_scheduler
    from jaxba._files import output_lock
    from jaxba._report._outputs import report_kinds

    if args.chunk is not None and args.chunk < 1:
        raise UsageError(f"--chunk {args.chunk}: must be at least 1")
    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: must be at least 1")
    if args.jobs is not None and args.scheduler is not None:
        raise UsageError("--jobs and --scheduler: give one (--scheduler local:N starts N Dask"
                         " workers)")
    try:
        if args.scheduler is not None:  # before anything is read: Dask installed?
            check_scheduler(args.scheduler)
    except SchedulerError as error:
        raise UsageError(str(error)) from None
    from jaxba._cli._batch_processes import worker_processes
    from jaxba._cli._batch_run import worker_count

    jobs = args.jobs or _cpus()
    # Worker processes started first: their start-up (jax, the pipeline) overlaps the
    # reading. Every report checked against every input; the tables are read where each
    # project is adjusted (with workers, in the workers, each its share).
    expected = 1 if args.scheduler is not None else worker_count(len(args.projects), jobs)
    with worker_processes(expected) as workers:
        entries = read_batch(args.projects, args.out, tables=False,
                             reports=report_kinds(args.reports))
        with output_lock(args.out):
            from jaxba._cli._batch_run import run_batch
            from jaxba._cli._progress_bar import project_progress

            if workers is None:  # adjusted here
                setup_jax()
                if args.own_process:
                    from jaxba import _report
                    from jaxba._gc import freeze_long_lived

                    _report.write_batch_reports  # imported now, frozen with the rest
                    freeze_long_lived()  # the modules and the entries live until the end

            with project_progress(len(args.projects), say, bar=args.progress) as progress:
                try:
                    rows = run_batch(args.projects, args.out, progress=progress.say,
                                     advance=progress.advance, entries=entries,
                                     scheduler=args.scheduler, chunk_size=args.chunk,
                                     resume=args.resume, jobs=jobs, workers=workers)
                except SchedulerError as error:
                    raise UsageError(str(error)) from None
    ok = sum(row["status"] == "ok" for row in rows)
    say(f"{ok} of {len(rows)} projects converged")
    return EXIT_OK if ok == len(rows) else EXIT_NOT_CONVERGED


def _cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
