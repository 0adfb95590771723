"""Replace files all together: each written in full under a temporary name, then renamed."""

import contextlib
import os
import pathlib
import signal
import tempfile
import threading
from collections.abc import Mapping


def replace_files(texts: Mapping[pathlib.Path, str | bytes], *, durable: bool = True) -> None:
    """Write every text (UTF-8) or bytes to its path, the folders existing.

    Every file is first written in full, and with `durable` flushed to disk (fsync), under
    a temporary name beside its target; only then are they renamed over the targets, with
    Ctrl-C held back until the last rename. A failure while writing (a full disk, an
    interrupt) removes the temporary files and leaves the old files as they were, never a
    partial one. Without `durable` that holds for everything but a crash of the system
    itself (power loss), after which a renamed file may be empty: for reports that a run
    can write again (`jaxba batch`, whose `--resume` checks them), at a fraction of the
    cost. The files get the usual permissions (0o666 less the umask).
    """
    mode = 0o666 & ~_umask()
    temporary: dict[pathlib.Path, pathlib.Path] = {}
    try:
        for path, text in texts.items():
            handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
            temporary[path] = pathlib.Path(name)
            with os.fdopen(handle, "wb") as file:
                file.write(text if isinstance(text, bytes) else text.encode("utf-8"))
                file.flush()
                os.fchmod(file.fileno(), mode)
                if durable:
                    os.fsync(file.fileno())
    except BaseException:
        for name in temporary.values():
            name.unlink(missing_ok=True)
        raise
    with _interrupts_held():
        for path, name in temporary.items():
            os.replace(name, path)


def _umask() -> int:
    """The process's umask, read from /proc where it can be: setting it to read it (the
    fallback) would, for an instant, give files and folders that another thread makes
    meanwhile (the batch's writer threads) the permissions of umask 0."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _interrupts_held():
    """Ctrl-C (SIGINT) waits until the block is done, then acts as it would have.

    Only in the main thread (where Python runs signal handlers); elsewhere a no-op.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if received:
        signal.raise_signal(signal.SIGINT)
