"""`jaxba bal PROBLEM [--out DIR]`: a BAL problem solved by the Schur backend (`run_bal`),
its results.json written."""

import argparse
import pathlib

from ._common import (
    EXIT_CODES,
    EXIT_NOT_CONVERGED,
    EXIT_OK,
    UsageError,
    common_options,
    say,
    setup_jax,
)


def add_bal(subparsers) -> None:
    parser = subparsers.add_parser(
        "bal",
        help="solve a BAL problem file (Schur-complement LM) and write results.json",
        description=(
            "Solve a 'Bundle Adjustment in the Large' problem (plain, .bz2 or .gz) with the"
            " Schur-complement Levenberg-Marquardt and write results.json. " + EXIT_CODES
        ),
        parents=[common_options()],
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
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from jaxba._files import check_folder, check_targets, output_lock
    from jaxba._io._bal import BalFormatError, read_bal

    if args.max_steps < 1:
        raise UsageError(f"--max-steps {args.max_steps}: must be at least 1")
    check_folder(args.out)
    check_targets([args.out / "results.json"], [args.problem], "the BAL problem")
    try:
        bal = read_bal(args.problem)  # before jax: a bad file is reported at once
    except (OSError, BalFormatError) as error:
        raise UsageError(str(error)) from None
    residuals, unknowns = 2 * bal.n_observations, 9 * bal.n_cameras + 3 * bal.n_points
    if residuals < unknowns:
        raise UsageError(
            f"{args.problem}: under-determined: {bal.n_observations} observations give"
            f" {residuals} residuals for {unknowns} unknowns")
    with output_lock(args.out):
        return _run_locked(args, bal)


def _run_locked(args: argparse.Namespace, bal) -> int:
    setup_jax()
    from jaxba._cli._bal import run_bal

    quiet = {"on_iteration": None} if args.no_progress else {}
    try:
        results = run_bal(args.problem, args.out, max_steps=args.max_steps, bal=bal, **quiet)
    except OSError as error:
        raise UsageError(str(error)) from None
    say(
        f"final cost {results['final_cost']:.9e} after {results['iterations']} iterations"
        f" ({results['solve_seconds']:.2f} s solve, {results['compile_seconds']:.2f} s compile);"
        f" {args.out / 'results.json'}"
    )
    return EXIT_OK if results["converged"] else EXIT_NOT_CONVERGED
