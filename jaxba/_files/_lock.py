"""One run at a time per output folder: an exclusive lock held for the whole run."""

import contextlib
import fcntl
import os
import pathlib
from collections.abc import Iterator

from ._paths import OutputError


@contextlib.contextmanager
def output_lock(folder) -> Iterator[pathlib.Path]:
    """Create `folder` if needed and hold an exclusive lock on it until the block ends.

    The lock is `flock` on the folder itself (no lock file is left behind); the system
    releases it when the process ends, however it ends. Raises `OutputError` naming the
    folder when another run holds it or when the folder cannot be made.
    """
    folder = pathlib.Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as error:
        raise OutputError(
            f"{folder}: cannot use as the output folder: {error.strerror or error}") from None
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputError(
                f"{folder}: another jaxba run is writing into this output folder (it holds"
                " the folder's lock); wait for it to finish or choose another --out"
            ) from None
        except OSError as error:
            raise OutputError(f"{folder}: cannot lock the output folder: {error}") from None
        yield folder
    finally:
        os.close(descriptor)
