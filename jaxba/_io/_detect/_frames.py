"""Names of images and frames: an image's id from its file name, a rig's frame from the
number its file name ends in (left07.jpg and right07.jpg: frame 7)."""

import collections
import pathlib
import re
from collections.abc import Sequence

_TRAILING_NUMBER = re.compile(r"([0-9]+)$")


def frame_number(path: pathlib.Path) -> int | None:
    """The number the file name (without its extension) ends in, None if it ends in none."""
    match = _TRAILING_NUMBER.search(path.stem)
    return int(match[1]) if match else None


def _clean(text: str) -> str:
    """`text` as a jaxba id: whitespace and '#' replaced by '_'."""
    return re.sub(r"[\s#]", "_", text) or "_"


def image_ids(paths: Sequence[tuple[str, pathlib.Path]]) -> list[str]:
    """An id for each (camera, path): the file name without its extension, or where two
    images share it `camera/name`, then `camera/name.extension`, then `camera/k` (k its
    position); whitespace and '#' become '_'."""
    ids = [_clean(path.stem) for _, path in paths]
    fallbacks = (lambda camera, path, k: f"{camera}/{path.stem}",
                 lambda camera, path, k: f"{camera}/{path.name}",
                 lambda camera, path, k: f"{camera}/{k}")
    for fallback in fallbacks:
        shared = {i for i, n in collections.Counter(ids).items() if n > 1}
        ids = [_clean(fallback(*paths[k], k)) if i in shared else i for k, i in enumerate(ids)]
    return ids
