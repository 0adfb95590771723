"""The `jaxba` command line: its parser, assembled from one module per command (`_adjust`,
`_init`, `_import`, `_bal_command`, `_batch`, `_export`, `_detect`, `_compare`), and the
entry point.

Thin: reading, adjusting and reporting live in the library and `jaxba._report`; the command
modules parse arguments, set up jax (float64, persistent compilation cache), hold the output
folder's lock for the run and print progress; `main` maps outcomes to exit codes: 0 success,
1 not converged (reports still written), 2 bad input (or an output folder that cannot be
used), 3 internal error (a bug: one line, the traceback with --debug), 130 interrupted
(Ctrl-C). Each command module has an `add_<name>(subparsers)` that registers its parser and
its `run` function; importing one loads neither jax nor NumPy.
"""

import argparse
import os
import sys
import traceback
from collections.abc import Sequence

from ._adjust import add_adjust
from ._bal_command import add_bal
from ._batch import add_batch
from ._common import (
    EXIT_BAD_INPUT,
    EXIT_CODES,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    UsageError,
    common_options,
    print_error,
    remembered_interrupts,
)
from ._compare import add_compare
from ._detect import add_detect
from ._export import add_export
from ._import import add_import
from ._init import add_init

__all__ = ["EXIT_INTERNAL", "EXIT_INTERRUPTED", "entry", "main"]


def _version() -> str:
    from jaxba import __version__  # the package's metadata: no jax

    return __version__


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxba", description="Self-calibrating photogrammetric bundle adjustment in JAX.",
        epilog=EXIT_CODES, parents=[common_options()],
    )
    parser.add_argument("--version", action="version", version=f"jaxba {_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (add_adjust, add_init, add_import, add_bal, add_batch, add_export, add_detect,
                add_compare):
        add(subparsers)
    return parser


def main(argv: Sequence[str] | None = None, *, own_process: bool = False) -> int:
    """Run the command line; returns the exit code: 0 ok, 1 not converged, 2 bad input,
    3 internal error, 130 interrupted. `own_process`: the process ends after it (`entry`),
    so what it imports may be frozen for the garbage collector (`jaxba._gc`)."""
    from jaxba._files import OutputError

    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # --help, or a usage error already printed by argparse
        return exit_.code if isinstance(exit_.code, int) else EXIT_BAD_INPUT
    args.own_process = own_process
    try:
        with remembered_interrupts():
            return args.run(args)
    except (UsageError, OutputError) as error:
        print_error(str(error))
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
        print_error(f"{what}. This is a bug in jaxba: please report it with the command and its"
                    f" input{hint}", "internal error")
        return EXIT_INTERNAL


def entry() -> None:
    """The `jaxba` program: `main`, then exit with its code.

    The process ends at once (`os._exit`, after flushing stdout and stderr), without the
    interpreter's clean-up: every command has closed its files, pools and clients by then,
    and the clean-up only frees what the process held (jax's, XLA's and the reports' objects:
    0.2-0.4 s after a 60-image block). After Ctrl-C it also kept XLA's threads running while
    the interpreter shut down, which ended in a segmentation fault.
    """
    code = main(own_process=True)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except OSError:  # a closed pipe (`jaxba ... | head`): nothing more can be said
            pass
    os._exit(code)


if __name__ == "__main__":
    entry()
