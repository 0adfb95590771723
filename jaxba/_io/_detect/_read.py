"""An image file as a grey array, or why it cannot be one.

OpenCV's decoders accept a truncated JPEG (the missing rows grey, a warning on stderr), so
the end of JPEG and PNG files is checked first: a file cut short is "truncated", not
detected on a partly grey image. The end marker is looked for in the last `_TAIL` bytes:
some cameras append data after a JPEG's end. An EXIF orientation is ignored: a calibration
is of the sensor's pixels, however the camera was held.
"""

import pathlib

import numpy as np

from ._opencv import import_cv2

_JPEG_START, _JPEG_END = b"\xff\xd8\xff", b"\xff\xd9"
_PNG_START, _PNG_END = b"\x89PNG\r\n\x1a\n", b"IEND\xaeB`\x82"
_TAIL = 4096


class ImageError(ValueError):
    """A file that gives no image; its message is the reason listed in detections.csv."""


def _truncated(data: bytes) -> str | None:
    """The format of a JPEG or PNG file whose end marker is missing, else None."""
    if data.startswith(_JPEG_START) and _JPEG_END not in data[-_TAIL:]:
        return "JPEG"
    if data.startswith(_PNG_START) and _PNG_END not in data[-_TAIL:]:
        return "PNG"
    return None


def read_grey(path: pathlib.Path) -> np.ndarray:
    """The image at `path` as a (rows, cols) uint8 grey array.

    Raises `ImageError` with the reason: "missing" (no such file, a dangling link),
    "unreadable: ..." (a folder, no permission, an I/O error), "empty file", "truncated
    JPEG/PNG" or "not an image" (no decoder takes it).
    """
    cv2 = import_cv2()
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ImageError("missing") from None
    except OSError as error:
        raise ImageError(f"unreadable: {error.strerror or error}") from None
    if not data:
        raise ImageError("empty file")
    truncated = _truncated(data)
    if truncated:
        raise ImageError(f"truncated {truncated} (its end marker is missing)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8),
                         cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None or image.size == 0:
        raise ImageError("not an image")
    return image
