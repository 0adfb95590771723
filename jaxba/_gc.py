"""Pause Python's cyclic garbage collector around bulk work.

Reading 90,000 table rows or formatting them creates hundreds of thousands of lists and
tuples; every few hundred allocations the collector runs, and its older generations walk every
object of the process (jax's included). None of these objects form cycles, so the collector
finds nothing: paused, the reader of a 90,000-row table takes about half the time.
"""

import contextlib
import gc
from collections.abc import Iterator


def freeze_long_lived() -> None:
    """Move every object alive now to the collector's permanent generation, for a process
    that has just imported what it will use (jax's and jaxba's modules live until it ends):
    the full passes that tracing and lowering programs trigger stop walking them (a warm
    60-image block, 12 s of CPU: ~0.8 s less). Only in a process of its own (the command
    line), never in a library call: frozen objects are never collected."""
    gc.freeze()


@contextlib.contextmanager
def paused_gc() -> Iterator[None]:
    """Disable the cyclic collector inside the block (restored after, also on errors; nested
    blocks leave it to the outermost)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
