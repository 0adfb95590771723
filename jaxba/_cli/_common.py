"""What every `jaxba` command shares: exit codes, the usage error, printing, Ctrl-C handling,
the options every command takes and jax's set-up."""

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 3
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report a Ctrl-C
EXIT_CODES = (
    "Exit codes: 0 converged, 1 not converged (reports written), 2 bad input, 3 internal"
    " error, 130 interrupted."
)


class UsageError(Exception):
    """Bad input from the user: printed as `jaxba: error: ...`, exit code 2."""


_interrupted = threading.Event()


def remember_interrupt(signum, frame) -> None:
    _interrupted.set()
    raise KeyboardInterrupt


@contextlib.contextmanager
def remembered_interrupts() -> Iterator[None]:
    """While a command runs, a Ctrl-C is also remembered (`raise_if_interrupted`).

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
    signal.signal(signal.SIGINT, remember_interrupt)
    report_unraisable = sys.unraisablehook

    def drop_interrupts(unraisable) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            report_unraisable(unraisable)

    sys.unraisablehook = drop_interrupts
    try:
        yield
        raise_if_interrupted()
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.unraisablehook = report_unraisable
        _interrupted.clear()  # a later command in this process starts uninterrupted


def raise_if_interrupted() -> None:
    """KeyboardInterrupt if a Ctrl-C came (and was lost) since the command started."""
    if _interrupted.is_set():
        raise KeyboardInterrupt


def print_error(message: str, kind: str = "error") -> None:
    print(f"jaxba: {kind}: {message}", file=sys.stderr, flush=True)


def say(message: str = "") -> None:
    """`message` on stdout at once. Where its reader has gone (`jaxba adjust ... | head`),
    the rest of the run goes on silently: its files are still written."""
    try:
        print(message, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # what is left in stdout's buffer goes nowhere
        os.close(devnull)


def setup_jax() -> None:
    """jax as every jaxba command runs it (`jaxba._jax_setup.setup_jax`)."""
    from jaxba._jax_setup import setup_jax

    setup_jax()


def plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def common_options() -> argparse.ArgumentParser:
    """Options of every subcommand (also accepted before it)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS,
        help="on an internal error, print the traceback",
    )
    return common
