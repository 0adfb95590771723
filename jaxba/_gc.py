"""Pause Python's cyclic garbage collector around bulk work.

Reading 90,000 table rows or formatting them creates hundreds of thousands of lists and
tuples; every few hundred allocations the collector runs, and its older generations walk every
object of the process (jax's included). None of these objects form cycles, so the collector
finds nothing: paused, the reader of a 90,000-row table takes about half the time.
"""

import contextlib
import gc
from collections.abc import Iterator


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
