"""`jaxba adjust PROJECT.toml [--out DIR]`: adjust a project and write its reports (and, when
asked, its figures and HTML page)."""

import argparse
import dataclasses
import math
import pathlib
import time

from ._common import (
    EXIT_CODES,
    EXIT_NOT_CONVERGED,
    EXIT_OK,
    UsageError,
    common_options,
    plural,
    print_error,
    raise_if_interrupted,
    say,
    setup_jax,
)
from ._init import complete, warn_unused_cameras


def add_adjust(subparsers) -> None:
    parser = subparsers.add_parser(
        "adjust",
        help="adjust a project and write its reports",
        description=(
            "Adjust the bundle of PROJECT.toml and write NAME.out, NAME.res, NAME.sigma,"
            " results.json and observations.csv (NAME = the project name). " + EXIT_CODES
        ),
        parents=[common_options()],
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
        "--uncertainty", type=float, nargs="?", const=math.inf, default=None,
        metavar="DISTANCE",
        help="also write each camera's projection uncertainty over its sensor at DISTANCE"
             " (object units; default infinity): uncertainty_CAMERA.csv and figures",
    )
    parser.add_argument(
        "--uncertainty-frame", choices=("object", "camera"), default="object",
        help="object (default): the ray fixed in the world the camera saw, its pose carried"
             " along; camera: fixed in the camera frame (intrinsics only)",
    )
    parser.add_argument(
        "--solver", choices=("auto", "dense", "schur"), default=None,
        help="dense normal equations, or object points eliminated (Schur complement); auto:"
             " schur above 2000 unknowns (default: the project's solver setting, auto)",
    )
    parser.set_defaults(run=run)


def _adjust_deferred(completion, project, result, options):
    """Adjust again with the deferred points intersected from the converged `result`
    (`adjust_deferred`), saying what became of them; when `result` did not converge, say
    that they were not added. Returns the project and adjustment to report."""
    import jaxba
    from jaxba import _report

    count = plural(len(completion.deferred), "deferred point")
    if not result.converged:
        print_error(f"the {count} were not added: the adjustment without them did not converge",
                    "warning")
        return project, result

    def said(again, deferral):
        for line in deferral.lines():
            say(f"  {line}")
        say(f"adjusting again with the {plural(len(deferral.added), 'deferred point')} ...")
        say(_report.start_line(again))

    say(f"intersecting the {count} from the adjusted block ...")
    again, result, _ = jaxba.adjust_deferred(completion, project, result, on_deferral=said,
                                             **options)
    return again, result


def _read_checked(args: argparse.Namespace):
    """Read the project and check the output folder, without jax: bad input is reported
    within a fraction of a second. Returns the spec, the output folder and the seconds."""
    from jaxba._files import OutputError, check_targets
    from jaxba._io._project import read_project
    from jaxba._project import ProjectError
    from jaxba._report import check_outputs, html_path

    start = time.perf_counter()
    try:
        spec = read_project(args.project)
        out_dir = args.out if args.out is not None else spec.path.parent
        check_outputs(spec, out_dir)
        if "html" in args.report:
            check_targets([html_path(spec, out_dir)], spec.input_files, f"project {spec.name!r}")
    except (ProjectError, OutputError) as error:
        raise UsageError(str(error)) from None
    warn_unused_cameras(spec)
    return spec, out_dir, time.perf_counter() - start


def _check_matplotlib(args: argparse.Namespace) -> None:
    """Refuse --plots and --report html before the run where matplotlib (a dependency of
    jaxba) cannot be imported: a broken installation."""
    if not (args.plots or args.report):
        return
    try:
        import matplotlib  # noqa: F401
    except ImportError as error:
        option = "--plots" if args.plots else "--report html"
        raise UsageError(f"{option}: matplotlib cannot be imported ({error}); reinstall jaxba"
                         " (pip install jaxba) or leave the option out") from None


def run(args: argparse.Namespace) -> int:
    from jaxba._files import output_lock

    if args.uncertainty is not None and not args.uncertainty > 0:
        raise UsageError(f"--uncertainty {args.uncertainty}: the distance must be > 0")
    spec, out_dir, read_seconds = _read_checked(args)
    _check_matplotlib(args)
    with output_lock(out_dir):
        return _run_locked(args, spec, out_dir, read_seconds)


def _run_locked(args, spec, out_dir, read_seconds: float) -> int:
    from jaxba._gc import freeze_long_lived, paused_gc

    start = time.perf_counter()
    with paused_gc():  # imports leave almost no garbage: no full passes of the collector
        setup_jax()
        import jaxba
        from jaxba import _report
        from jaxba._problem._checks import ProblemError
        from jaxba._timing import Phase, Timings

        jaxba.build_project, jaxba.adjust_project, _report.write_reports  # import them now
    if args.own_process:
        freeze_long_lived()
    timings = Timings(on_compile=lambda name: say(f"  {name}: compiling..."))
    timings.add(Phase("read", read_seconds, 0.0, 0, 0))
    timings.add(Phase("start-up", time.perf_counter() - start, 0.0, 0, 0))
    try:
        completion = None
        if not spec.complete:
            spec, completion = complete(spec, timings)
        with timings.phase("read"):
            project = jaxba.build_project(spec)
        if completion is not None:
            project = dataclasses.replace(project, initialisation=completion.summary())
        say(_report.start_line(project))
        options = dict(on_iteration=lambda it: say(_report.iteration_line(it)),
                       solver=args.solver, timings=timings)
        result = jaxba.adjust_project(project, **options)
        if completion is not None and completion.deferred:
            project, result = _adjust_deferred(completion, project, result, options)
    except (jaxba.ProjectError, jaxba.DatumError, ProblemError) as error:
        raise UsageError(str(error)) from None
    except jaxba.NotConvergedError as error:
        print_error(f"the adjustment failed: {error}")
        return EXIT_NOT_CONVERGED
    raise_if_interrupted()  # not a report from a run that was asked to stop
    try:
        with timings.phase("reports"):
            written = _report.write_reports(project, result, out_dir)
            uncertainty = {}
            if args.uncertainty is not None:
                uncertainty = _report.write_uncertainty(
                    project, result, out_dir, distance=args.uncertainty,
                    frame=args.uncertainty_frame,
                    warn=lambda message: print_error(message, "warning"))
                written += list(uncertainty)
            if args.plots or args.report:
                written += _report.write_figures(
                    project, result, out_dir, plots=args.plots, html="html" in args.report,
                    uncertainty=uncertainty, warn=lambda message: print_error(message, "warning"))
    except (jaxba.OutputError, OSError) as error:
        raise UsageError(str(error)) from None

    for line in _report.summary_lines(project, result):
        say(line)
    say(timings.text())
    say("wrote")
    for path in written:
        say(f"  {path}")
    for line in _report.warning_lines(project, result):
        print_error(line, "warning")
    if not result.converged:
        said = result.message.startswith("the adjustment")
        message = result.message if said else f"the adjustment did not converge: {result.message}"
        print_error(message, "warning")
        return EXIT_NOT_CONVERGED
    return EXIT_OK
