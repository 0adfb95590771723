"""`jaxba init PROJECT.toml --out DIR`: the project with every missing approximation computed;
`complete`, the computation with its log, is shared with `jaxba adjust`."""

import argparse
import pathlib

from ._common import EXIT_OK, UsageError, common_options, plural, print_error, say, setup_jax


def add_init(subparsers) -> None:
    parser = subparsers.add_parser(
        "init",
        help="compute a project's missing approximations and write the completed project",
        description=(
            "Compute the approximations PROJECT.toml leaves out ('-' EOPs, tie points absent"
            " from the points table) and write the completed project, its TOML file and every"
            " table, into DIR; never over an input. Exit codes: 0 written, 2 bad input (or an"
            " output folder that cannot be used), 3 internal error, 130 interrupted."
        ),
        parents=[common_options()],
    )
    parser.add_argument("project", type=pathlib.Path, help="the project file (TOML)")
    parser.add_argument(
        "--out", type=pathlib.Path, required=True, metavar="DIR",
        help="folder for the completed project (created if needed; not the input's folder)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from jaxba._files import OutputError, output_lock
    from jaxba._io._project import read_project
    from jaxba._io._project._write import project_paths
    from jaxba._project import ProjectError

    try:  # before jax: bad input and an unusable folder are reported at once
        spec = read_project(args.project)
        project_paths(spec, args.out)
    except (ProjectError, OutputError) as error:
        raise UsageError(str(error)) from None
    warn_unused_cameras(spec)
    with output_lock(args.out):
        return _run_locked(args, spec)


def _run_locked(args: argparse.Namespace, spec) -> int:
    from jaxba._io._project._write import write_project
    from jaxba._project import ProjectError

    completed, image_methods, point_methods, deferred = spec, None, None, {}
    if spec.complete:
        say(f"{spec.path.name}: every image and point has its approximation; nothing to"
            " compute, the project is copied")
    else:
        setup_jax()
        try:
            completed, completion = complete(spec)
        except ProjectError as error:
            raise UsageError(str(error)) from None
        image_methods, point_methods = completion.image_methods, completion.point_methods
        deferred = completion.deferred
        completed = completion.pending or completed  # the deferred points kept, without values
    try:
        written = write_project(completed, args.out, source=spec, image_methods=image_methods,
                                point_methods=point_methods, deferred=deferred)
    except OSError as error:
        raise UsageError(str(error)) from None
    say("wrote")
    for path in written:
        say(f"  {path}")
    if deferred:
        say(f"the {plural(len(deferred), 'deferred point')} are written without approximations"
            f" (absent from {spec.file_names.get('points', 'the points table')}): jaxba adjust"
            " intersects them from the adjusted block")
    return EXIT_OK


def complete(spec, timings=None):
    """Compute the approximations `spec` misses (`complete_project`), saying so and printing
    the initialisation's log (its summary lines) and its suspects (a warning). jax is set
    up. Returns the completed spec and the `Completion`."""
    import contextlib

    import jaxba

    say(f"computing approximations for {plural(len(spec.missing_images), 'image')} and"
        f" {plural(len(spec.missing_points), 'point')} ...")
    phase = timings.phase("initialisation") if timings else contextlib.nullcontext()
    with phase:
        completed, completion = jaxba.complete_project(spec)
    for line in completion.console_lines():
        say(f"  {line}")
    suspects = completion.suspect_line()
    if suspects:
        print_error(suspects, "warning")
    return completed, completion


def warn_unused_cameras(spec) -> None:
    """A warning naming the cameras of cameras.toml that no image uses (they are left out)."""
    warning = spec.unused_camera_warning()
    if warning:
        print_error(warning, "warning")
