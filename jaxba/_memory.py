"""Give freed C heap memory back to the operating system between the phases of a run.

XLA's compiler and the programs it runs allocate and free hundreds of MB through the C
library's malloc; glibc keeps what is freed for reuse (up to a dynamic threshold per
allocation size, in one arena per thread), so a process's resident memory stays at the
high-water mark of everything compiled so far. On block A (60 images, 26,200 points) the
compilations of the datum check, the solve and the statistics left ~400 MB of free heap
resident after the solve, and each later phase's own peak came on top of it.

`release_free_memory` (glibc's `malloc_trim(0)`) returns the free pages at the end of every
timed phase that compiled a program (`jaxba._timing.Timings.phase`); `tune_allocator` (the
CLI, once at start-up) also makes free() return large blocks at once (`mallopt`: blocks of
256 KiB and more mapped on their own, the heap trimmed when 1 MiB is free at its top). Both
are no-ops where the C library is not glibc.
"""

import ctypes
import functools

_M_TRIM_THRESHOLD = -1  # glibc malloc.h
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 256 * 1024
TRIM_THRESHOLD = 1024 * 1024


@functools.cache
def _glibc():
    """glibc, or None (another C library, or none). The C library the process runs on,
    through its global symbols (`CDLL(None)`; `ctypes.util.find_library` would spawn
    `ldconfig -p`, ~3 ms at every start); Windows has no such handle (TypeError)."""
    try:
        libc = ctypes.CDLL(None)
        libc.malloc_trim.argtypes, libc.mallopt.argtypes = [ctypes.c_size_t], [ctypes.c_int] * 2
        return libc
    except (OSError, AttributeError, TypeError):
        return None


def release_free_memory() -> None:
    """Return the C heap's free pages to the system (`malloc_trim(0)`: it walks the heap, a
    few ms in a fresh process, 20-40 ms in one that has compiled many programs)."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


def tune_allocator() -> None:
    """Map large blocks on their own and trim the heap early (see the module docstring);
    for a process that runs one adjustment, such as the CLI's."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
