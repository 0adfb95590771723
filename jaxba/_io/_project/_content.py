"""What a project's small files say, kept by their content: a batch's projects often share a
file's text (one cameras.toml, one calibration board's points), read and checked once per
process. The records kept are never changed in place; their readers return fresh containers.
"""

from collections.abc import Callable
from typing import TypeVar

Read = TypeVar("Read")

KEPT_BYTES = 1 << 18  # a file larger than this is read each time (a block's tables)
_KEPT: dict[tuple, object] = {}  # (reader, the file's bytes, ...) -> what it read
_SIZE = 64


def once(key: tuple, data: bytes, read: Callable[[], Read],
         keep: Callable[[Read], bool] = lambda _: True) -> Read:
    """`read()`, or what it returned before for `key` (the reader, the file's bytes `data` and
    everything else the reading depends on): kept for a small file where `keep(result)`.
    Errors are raised each time, never kept."""
    if len(data) > KEPT_BYTES:
        return read()
    result = _KEPT.get(key)
    if result is None:
        result = read()
        if keep(result):
            if len(_KEPT) >= _SIZE:
                _KEPT.pop(next(iter(_KEPT)))
            _KEPT[key] = result
    return result
