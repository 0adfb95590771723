"""The `jaxba` command line: `jaxba adjust PROJECT.toml [--out DIR]`, `jaxba init PROJECT.toml
--out DIR`, `jaxba import KIND SOURCE --out DIR`, `jaxba batch ...`, `jaxba bal PROBLEM`.

Thin: reading, adjusting and reporting live in the library and `jaxba._report`; this module
parses arguments, sets up jax (float64, persistent compilation cache), holds the output
folder's lock for the run, prints progress and maps outcomes to exit codes: 0 success, 1 not
converged (reports still written), 2 bad input (or an output folder that cannot be used),
3 internal error (a bug: one line, the traceback with --debug), 130 interrupted (Ctrl-C).
Each subcommand is an `_add_<name>` function that registers its parser and its `run` function.
"""

import argparse
import contextlib
import dataclasses
import os
import pathlib
import shutil
import signal
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Iterator, Sequence

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 3
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report a Ctrl-C
EXIT_CODES = (
    "Exit codes: 0 converged, 1 not converged (reports written), 2 bad input, 3 internal"
    " error, 130 interrupted."
)


class _UsageError(Exception):
    """Bad input from the user: printed as `jaxba: error: ...`, exit code 2."""


_interrupted = threading.Event()


def _remember_interrupt(signum, frame) -> None:
    _interrupted.set()
    raise KeyboardInterrupt


@contextlib.contextmanager
def _remembered_interrupts() -> Iterator[None]:
    """While a command runs, a Ctrl-C is also remembered (`_raise_if_interrupted`).

    Python drops an exception raised inside a garbage-collector callback ("Exception
    ignored in ..."), and jax runs one at every collection (`_xla_gc_callback`): a Ctrl-C
    whose KeyboardInterrupt surfaced there was lost, and the run went on to write its
    reports. Such a dropped KeyboardInterrupt is not printed either (it is not an error:
    the run stops with "interrupted" at the next check). Only where SIGINT raises
    KeyboardInterrupt (Python's default handler; not in a background job that ignores it)
    and in the main thread."""
    if (signal.getsignal(signal.SIGINT) is not signal.default_int_handler
            or threading.current_thread() is not threading.main_thread()):
        yield
        return
    _interrupted.clear()
    signal.signal(signal.SIGINT, _remember_interrupt)
    report_unraisable = sys.unraisablehook

    def drop_interrupts(unraisable) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            report_unraisable(unraisable)

    sys.unraisablehook = drop_interrupts
    try:
        yield
        _raise_if_interrupted()
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.unraisablehook = report_unraisable
        _interrupted.clear()  # a later command in this process starts uninterrupted


def _raise_if_interrupted() -> None:
    """KeyboardInterrupt if a Ctrl-C came (and was lost) since the command started."""
    if _interrupted.is_set():
        raise KeyboardInterrupt


def _error(message: str, kind: str = "error") -> None:
    print(f"jaxba: {kind}: {message}", file=sys.stderr, flush=True)


def _say(message: str = "") -> None:
    print(message, flush=True)


def _setup_jax() -> None:
    """jax as every jaxba command runs it (`jaxba._jax_setup.setup_jax`)."""
    from jaxba._jax_setup import setup_jax

    setup_jax()


# --- jaxba adjust ---------------------------------------------------------------------------


def _add_adjust(subparsers) -> None:
    parser = subparsers.add_parser(
        "adjust",
        help="adjust a project and write its reports",
        description=(
            "Adjust the bundle of PROJECT.toml and write NAME.out, NAME.res, NAME.sigma,"
            " results.json and observations.csv (NAME = the project name). " + EXIT_CODES
        ),
        parents=[_common_options()],
    )
    parser.add_argument("project", type=pathlib.Path, help="the project file (TOML)")
    parser.add_argument(
        "--out", type=pathlib.Path, default=None, metavar="DIR",
        help="folder for the reports (default: the project file's folder)",
    )
    parser.add_argument(
        "--plots", action="store_true",
        help="also write the report's figures as PNG: residuals, normalised_residuals,"
             " coverage, distortion_<camera>, correlation_<camera>, point_ellipses",
    )
    parser.add_argument(
        "--report", choices=("html",), action="append", default=[], metavar="html",
        help="also write NAME.html: summary, tables and figures in one offline page",
    )
    parser.add_argument(
        "--solver", choices=("auto", "dense", "schur"), default=None,
        help="dense normal equations, or object points eliminated (Schur complement); auto:"
             " schur above 2000 unknowns (default: the project's solver setting, auto)",
    )
    parser.set_defaults(run=_adjust)


def _write_figures(project, result, out_dir, *, plots: bool, html: bool) -> list[pathlib.Path]:
    """The report's figures (`figure_set`) as NAME.png files (`plots`) and NAME.html
    (`html`) with them embedded, in `out_dir`; each figure drawn once.

    Never over an input: a figure whose file name is an input's is skipped with a warning
    (NAME.html was checked before the run); the files replace the old ones together
    (`replace_files`).
    """
    from jaxba._report import html_path, html_report, png_bytes, replace_files
    from jaxba._report._plots import figure_set

    out_dir = pathlib.Path(out_dir)
    inputs = {pathlib.Path(path).resolve() for path in project.spec.input_files}
    images = {figure.name: png_bytes(figure.make()) for figure in figure_set(project, result)}
    files = {}
    for name, image in images.items() if plots else ():
        path = out_dir / f"{name}.png"
        if path.resolve() in inputs:
            _error(f"--plots: {path} is an input file of the project; not written", "warning")
            continue
        files[path] = image
    if html:
        files[html_path(project.spec, out_dir)] = html_report(project, result, figures=images)
    replace_files(files)
    return list(files)


def _read_checked(args: argparse.Namespace):
    """Read the project and check the output folder, without jax: bad input is reported
    within a fraction of a second. Returns the spec, the output folder and the seconds."""
    from jaxba._io._project import ProjectError, read_project
    from jaxba._report import OutputError, check_outputs, check_targets, html_path

    start = time.perf_counter()
    try:
        spec = read_project(args.project)
        out_dir = args.out if args.out is not None else spec.path.parent
        check_outputs(spec, out_dir)
        if "html" in args.report:
            check_targets([html_path(spec, out_dir)], spec.input_files, f"project {spec.name!r}")
    except (ProjectError, OutputError) as error:
        raise _UsageError(str(error)) from None
    _warn_unused_cameras(spec)
    return spec, out_dir, time.perf_counter() - start


def _warn_unused_cameras(spec) -> None:
    warning = spec.unused_camera_warning()
    if warning:
        _error(warning, "warning")


def _check_matplotlib(args: argparse.Namespace) -> None:
    """Refuse --plots and --report html before the run where matplotlib (a dependency of
    jaxba) cannot be imported: a broken installation."""
    if not (args.plots or args.report):
        return
    try:
        import matplotlib  # noqa: F401
    except ImportError as error:
        option = "--plots" if args.plots else "--report html"
        raise _UsageError(f"{option}: matplotlib cannot be imported ({error}); reinstall jaxba"
                          " (pip install jaxba) or leave the option out") from None


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _complete(spec, timings=None):
    """Compute the approximations `spec` misses (`complete_project`), saying so and printing
    the initialisation's log (its summary lines) and its suspects (a warning). jax is set
    up. Returns the completed spec and the `Completion`."""
    import contextlib

    import jaxba

    _say(f"computing approximations for {_plural(len(spec.missing_images), 'image')} and"
         f" {_plural(len(spec.missing_points), 'point')} ...")
    phase = timings.phase("initialisation") if timings else contextlib.nullcontext()
    with phase:
        completed, completion = jaxba.complete_project(spec)
    for line in completion.console_lines():
        _say(f"  {line}")
    suspects = completion.suspect_line()
    if suspects:
        _error(suspects, "warning")
    return completed, completion


def _adjust_deferred(completion, project, result, options):
    """Adjust again with the deferred points intersected from the converged `result`
    (`adjust_deferred`), saying what became of them; when `result` did not converge, say
    that they were not added. Returns the project and adjustment to report."""
    import jaxba
    from jaxba import _report

    count = _plural(len(completion.deferred), "deferred point")
    if not result.converged:
        _error(f"the {count} were not added: the adjustment without them did not converge",
               "warning")
        return project, result

    def said(again, deferral):
        for line in deferral.lines():
            _say(f"  {line}")
        _say(f"adjusting again with the {_plural(len(deferral.added), 'deferred point')} ...")
        _say(_report.start_line(again))

    _say(f"intersecting the {count} from the adjusted block ...")
    again, result, _ = jaxba.adjust_deferred(completion, project, result, on_deferral=said,
                                             **options)
    return again, result


def _adjust(args: argparse.Namespace) -> int:
    from jaxba._report import output_lock

    spec, out_dir, read_seconds = _read_checked(args)
    _check_matplotlib(args)
    with output_lock(out_dir):
        return _adjust_locked(args, spec, out_dir, read_seconds)


def _adjust_locked(args, spec, out_dir, read_seconds: float) -> int:
    start = time.perf_counter()
    _setup_jax()
    import jaxba
    from jaxba import _report
    from jaxba._problem._checks import ProblemError
    from jaxba._timing import Phase, Timings

    jaxba.build_project, jaxba.adjust_project, _report.write_reports  # import them now
    if args.own_process:
        from jaxba._gc import freeze_long_lived

        freeze_long_lived()
    timings = Timings(on_compile=lambda name: _say(f"  {name}: compiling..."))
    timings.add(Phase("read", read_seconds, 0.0, 0, 0))
    timings.add(Phase("start-up", time.perf_counter() - start, 0.0, 0, 0))
    try:
        completion = None
        if not spec.complete:
            spec, completion = _complete(spec, timings)
        with timings.phase("read"):
            project = jaxba.build_project(spec)
        if completion is not None:
            project = dataclasses.replace(project, initialisation=completion.summary())
        _say(_report.start_line(project))
        options = dict(on_iteration=lambda it: _say(_report.iteration_line(it)),
                       solver=args.solver, timings=timings)
        result = jaxba.adjust_project(project, **options)
        if completion is not None and completion.deferred:
            project, result = _adjust_deferred(completion, project, result, options)
    except (jaxba.ProjectError, jaxba.DatumError, ProblemError) as error:
        raise _UsageError(str(error)) from None
    except jaxba.NotConvergedError as error:
        _error(f"the adjustment failed: {error}")
        return EXIT_NOT_CONVERGED
    _raise_if_interrupted()  # not a report from a run that was asked to stop
    try:
        with timings.phase("reports"):
            written = _report.write_reports(project, result, out_dir)
            if args.plots or args.report:
                written += _write_figures(project, result, out_dir, plots=args.plots,
                                          html="html" in args.report)
    except (_report.OutputError, OSError) as error:
        raise _UsageError(str(error)) from None

    for line in _report.summary_lines(project, result):
        _say(line)
    _say(timings.text())
    _say("wrote")
    for path in written:
        _say(f"  {path}")
    for line in _report.warning_lines(project, result):
        _error(line, "warning")
    if not result.converged:
        said = result.message.startswith("the adjustment")
        _error(result.message if said else f"the adjustment did not converge: {result.message}",
               "warning")
        return EXIT_NOT_CONVERGED
    return EXIT_OK


# --- jaxba init -----------------------------------------------------------------------------


def _add_init(subparsers) -> None:
    parser = subparsers.add_parser(
        "init",
        help="compute a project's missing approximations and write the completed project",
        description=(
            "Compute the approximations PROJECT.toml leaves out ('-' EOPs, tie points absent"
            " from the points table) and write the completed project, its TOML file and every"
            " table, into DIR; never over an input. Exit codes: 0 written, 2 bad input (or an"
            " output folder that cannot be used), 3 internal error, 130 interrupted."
        ),
        parents=[_common_options()],
    )
    parser.add_argument("project", type=pathlib.Path, help="the project file (TOML)")
    parser.add_argument(
        "--out", type=pathlib.Path, required=True, metavar="DIR",
        help="folder for the completed project (created if needed; not the input's folder)",
    )
    parser.set_defaults(run=_init)


def _init(args: argparse.Namespace) -> int:
    from jaxba._io._project import ProjectError, read_project
    from jaxba._io._project._write import project_paths
    from jaxba._report import OutputError, output_lock

    try:  # before jax: bad input and an unusable folder are reported at once
        spec = read_project(args.project)
        project_paths(spec, args.out)
    except (ProjectError, OutputError) as error:
        raise _UsageError(str(error)) from None
    _warn_unused_cameras(spec)
    with output_lock(args.out):
        return _init_locked(args, spec)


def _init_locked(args: argparse.Namespace, spec) -> int:
    from jaxba._io._project import ProjectError
    from jaxba._io._project._write import write_project

    completed, image_methods, point_methods, deferred = spec, None, None, {}
    if spec.complete:
        _say(f"{spec.path.name}: every image and point has its approximation; nothing to"
             " compute, the project is copied")
    else:
        _setup_jax()
        try:
            completed, completion = _complete(spec)
        except ProjectError as error:
            raise _UsageError(str(error)) from None
        image_methods, point_methods = completion.image_methods, completion.point_methods
        deferred = completion.deferred
        completed = completion.pending or completed  # the deferred points kept, without values
    try:
        written = write_project(completed, args.out, source=spec, image_methods=image_methods,
                                point_methods=point_methods, deferred=deferred)
    except OSError as error:
        raise _UsageError(str(error)) from None
    _say("wrote")
    for path in written:
        _say(f"  {path}")
    if deferred:
        _say(f"the {_plural(len(deferred), 'deferred point')} are written without approximations"
             f" (absent from {spec.file_names.get('points', 'the points table')}): jaxba adjust"
             " intersects them from the adjusted block")
    return EXIT_OK


# --- jaxba import ---------------------------------------------------------------------------

_IMPORT_SOURCES = {
    "dbat": "a DBAT XML script",
    "colmap": "a COLMAP text model folder (cameras.txt, images.txt, points3D.txt)",
    "zhang": "Zhang's data folder (Model.txt, data1.txt .. data5.txt)",
    "bal": "a BAL problem file (plain, .bz2 or .gz)",
}


def _add_import(subparsers) -> None:
    parser = subparsers.add_parser(
        "import",
        help="write a jaxba project from another program's files",
        description=(
            "Write a jaxba project (NAME.toml and its tables) into DIR from SOURCE: "
            + "; ".join(f"{kind}: {what}" for kind, what in _IMPORT_SOURCES.items())
            + ". DIR must be new or empty: nothing is ever written over a file. Exit codes:"
            " 0 written, 2 bad input (or an output folder that cannot be used), 3 internal"
            " error, 130 interrupted."
        ),
        parents=[_common_options()],
    )
    parser.add_argument("kind", choices=tuple(_IMPORT_SOURCES), help="the source's format")
    parser.add_argument("source", type=pathlib.Path, help="the file or folder to import")
    parser.add_argument(
        "--out", type=pathlib.Path, required=True, metavar="DIR",
        help="folder for the project (created if needed; must be empty)",
    )
    parser.add_argument("--name", default=None,
                        help="the project's name (default: the source's name)")
    parser.set_defaults(run=_import)


def _import_folder(out_dir: pathlib.Path) -> None:
    """Refuse an output folder that exists and is not empty, or cannot be written."""
    from jaxba._report import OutputError, check_folder

    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise OutputError(f"{out_dir}: output folder is not empty; jaxba import writes a new"
                          " project into a new or empty folder (--out)")
    check_folder(out_dir)


def _import(args: argparse.Namespace) -> int:
    from jaxba import _io
    from jaxba._io._bal import BalFormatError, write_bal_project

    if not args.source.exists():
        raise _UsageError(f"{args.source}: no such file or folder")
    _import_folder(args.out)
    name = args.name or args.source.name.split(".")[0] or args.kind
    writers = {
        "dbat": lambda out: _io.write_dbat_project(args.source, out, name=name),
        "colmap": lambda out: _io.write_colmap_project(args.source, out, name=name),
        "zhang": lambda out: _io.write_zhang_project(args.source, out, name=name),
        "bal": lambda out: write_bal_project(args.source, out, name=name),
    }
    # Written into a fresh sibling folder, renamed to DIR when complete: a failed import
    # leaves nothing behind.
    args.out.parent.mkdir(parents=True, exist_ok=True)
    staging = pathlib.Path(tempfile.mkdtemp(prefix=f".{args.out.name}.", dir=args.out.parent))
    try:
        written = writers[args.kind](staging)
        if args.out.exists():
            args.out.rmdir()  # empty (`_import_folder`)
        staging.rename(args.out)
    except (OSError, ValueError, BalFormatError) as error:
        raise _UsageError(f"{args.kind} import of {args.source}: {error}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    project_file = args.out / written.project_file.name
    files = sorted(path.name for path in args.out.iterdir())
    _say(f"wrote {args.out}: {', '.join(files)}")
    _say(f"adjust it with: jaxba adjust {project_file}")
    return EXIT_OK


# --- jaxba bal ------------------------------------------------------------------------------


def _add_bal(subparsers) -> None:
    parser = subparsers.add_parser(
        "bal",
        help="solve a BAL problem file (Schur-complement LM) and write results.json",
        description=(
            "Solve a 'Bundle Adjustment in the Large' problem (plain, .bz2 or .gz) with the"
            " Schur-complement Levenberg-Marquardt and write results.json. " + EXIT_CODES
        ),
        parents=[_common_options()],
    )
    parser.add_argument("problem", type=pathlib.Path, help="the BAL problem file")
    parser.add_argument(
        "--out", type=pathlib.Path, default=pathlib.Path("."), metavar="DIR",
        help="folder for results.json (default: the current folder)",
    )
    parser.add_argument("--max-steps", type=int, default=100, metavar="N")
    parser.add_argument(
        "--no-progress", action="store_true",
        help="no per-iteration output: the solve runs as one compiled program instead of one"
        " compiled step at a time",
    )
    parser.set_defaults(run=_bal)


def _bal(args: argparse.Namespace) -> int:
    from jaxba._io._bal import BalFormatError, read_bal
    from jaxba._report import check_folder, check_targets, output_lock

    if args.max_steps < 1:
        raise _UsageError(f"--max-steps {args.max_steps}: must be at least 1")
    check_folder(args.out)
    check_targets([args.out / "results.json"], [args.problem], "the BAL problem")
    try:
        bal = read_bal(args.problem)  # before jax: a bad file is reported at once
    except (OSError, BalFormatError) as error:
        raise _UsageError(str(error)) from None
    residuals, unknowns = 2 * bal.n_observations, 9 * bal.n_cameras + 3 * bal.n_points
    if residuals < unknowns:
        raise _UsageError(
            f"{args.problem}: under-determined: {bal.n_observations} observations give"
            f" {residuals} residuals for {unknowns} unknowns")
    with output_lock(args.out):
        return _bal_locked(args, bal)


def _bal_locked(args: argparse.Namespace, bal) -> int:
    _setup_jax()
    from jaxba._cli._bal import run_bal

    quiet = {"on_iteration": None} if args.no_progress else {}
    try:
        results = run_bal(args.problem, args.out, max_steps=args.max_steps, bal=bal, **quiet)
    except OSError as error:
        raise _UsageError(str(error)) from None
    _say(
        f"final cost {results['final_cost']:.9e} after {results['iterations']} iterations"
        f" ({results['solve_seconds']:.2f} s solve, {results['compile_seconds']:.2f} s compile);"
        f" {args.out / 'results.json'}"
    )
    return EXIT_OK if results["converged"] else EXIT_NOT_CONVERGED


# --- jaxba batch ----------------------------------------------------------------------------


def _add_batch(subparsers) -> None:
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
        parents=[_common_options()],
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
        "--chunk", type=int, default=None, metavar="N",
        help="projects per vmapped solve, one Dask task (default 10); the results do not"
             " depend on where the solves run, only (to rounding) on N")
    parser.add_argument(
        "--resume", action="store_true",
        help="skip projects whose reports are all in DIR already (an earlier, interrupted"
             " run); their summary rows are read from their results.json")
    parser.set_defaults(run=_batch)


def _batch(args: argparse.Namespace) -> int:
    from jaxba._dask import SchedulerError, check_scheduler
    from jaxba._io._project._batch_read import read_batch
    from jaxba._report import output_lock

    if args.chunk is not None and args.chunk < 1:
        raise _UsageError(f"--chunk {args.chunk}: must be at least 1")
    try:
        if args.scheduler is not None:  # before anything is read: Dask installed?
            check_scheduler(args.scheduler)
    except SchedulerError as error:
        raise _UsageError(str(error)) from None
    entries = read_batch(args.projects, args.out)  # checks every report against every input
    with output_lock(args.out):
        _setup_jax()
        from jaxba._cli._progress_bar import project_progress
        from jaxba._io._project._batch_run import run_batch

        if args.own_process:
            from jaxba import _report
            from jaxba._gc import freeze_long_lived

            _report.write_reports  # imported now, frozen with the rest
            freeze_long_lived()  # the modules and the projects read live until the end

        with project_progress(len(args.projects), _say, bar=args.progress) as progress:
            try:
                rows = run_batch(args.projects, args.out, progress=progress.say,
                                 advance=progress.advance, entries=entries,
                                 scheduler=args.scheduler, chunk_size=args.chunk,
                                 resume=args.resume)
            except SchedulerError as error:
                raise _UsageError(str(error)) from None
    ok = sum(row["status"] == "ok" for row in rows)
    _say(f"{ok} of {len(rows)} projects converged")
    return EXIT_OK if ok == len(rows) else EXIT_NOT_CONVERGED


# --- entry point ----------------------------------------------------------------------------


def _common_options() -> argparse.ArgumentParser:
    """Options of every subcommand (also accepted before it)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS,
        help="on an internal error, print the traceback",
    )
    return common


def _version() -> str:
    from jaxba import __version__  # the package's metadata: no jax

    return __version__


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxba", description="Self-calibrating photogrammetric bundle adjustment in JAX.",
        epilog=EXIT_CODES, parents=[_common_options()],
    )
    parser.add_argument("--version", action="version", version=f"jaxba {_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_adjust(subparsers)
    _add_init(subparsers)
    _add_import(subparsers)
    _add_bal(subparsers)
    _add_batch(subparsers)
    return parser


def main(argv: Sequence[str] | None = None, *, own_process: bool = False) -> int:
    """Run the command line; returns the exit code: 0 ok, 1 not converged, 2 bad input,
    3 internal error, 130 interrupted. `own_process`: the process ends after it (`entry`),
    so what it imports may be frozen for the garbage collector (`jaxba._gc`)."""
    from jaxba._report import OutputError

    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # --help, or a usage error already printed by argparse
        return exit_.code if isinstance(exit_.code, int) else EXIT_BAD_INPUT
    args.own_process = own_process
    try:
        with _remembered_interrupts():
            return args.run(args)
    except (_UsageError, OutputError) as error:
        _error(str(error))
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("jaxba: interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    except Exception as error:  # a bug: one line, the traceback only when asked for
        if getattr(args, "debug", False):
            traceback.print_exc()
        lines = str(error).strip().splitlines()
        what = type(error).__name__ + (f": {lines[0]}" if lines else "")
        hint = "" if getattr(args, "debug", False) else "; run with --debug for the traceback"
        _error(f"{what}. This is a bug in jaxba: please report it with the command and its"
               f" input{hint}", "internal error")
        return EXIT_INTERNAL


def entry() -> None:
    """The `jaxba` program: `main`, then exit with its code.

    After Ctrl-C the process ends at once (`os._exit`), without the interpreter's clean-up:
    an interrupt during compilation left XLA's threads running while the interpreter shut
    down, which ended in a segmentation fault.
    """
    code = main(own_process=True)
    if code == EXIT_INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
