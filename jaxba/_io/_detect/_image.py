"""One image: read, the board found, a thumbnail drawn; what a worker process returns.

Whatever is wrong with the file or the view ends as a reason, never as an exception: one
broken file does not stop the others.
"""

import dataclasses
import pathlib

import numpy as np

from ._board import Board
from ._find import NotFound, find_board
from ._opencv import import_cv2
from ._read import ImageError, read_grey

THUMBNAIL_WIDTH = 200  # pixels
_POINT, _FIRST, _FAILED = (0, 200, 0), (0, 0, 255), (0, 0, 255)  # BGR


@dataclasses.dataclass(frozen=True)
class ImageDetection:
    """What was found in one image file.

    `size`: (columns, rows) in pixels, None when the file gave no image; `ids` (n,) indices
    into `Board.points()` and `pixels` (n, 2) of the points seen (empty when none);
    `reason`: "" when they are used, else why not (no board, or `left_out`); `thumbnail`:
    (h, THUMBNAIL_WIDTH, 3) uint8 BGR with the points drawn, None when the file gave no image.
    """

    path: pathlib.Path
    size: tuple[int, int] | None
    ids: np.ndarray
    pixels: np.ndarray
    reason: str
    thumbnail: np.ndarray | None = dataclasses.field(default=None, repr=False)

    @property
    def found(self) -> bool:
        return not self.reason

    def left_out(self, reason: str) -> "ImageDetection":
        """This detection not used, for `reason` (the points found kept, for the record)."""
        return dataclasses.replace(self, reason=reason)


def _thumbnail(grey: np.ndarray, pixels: np.ndarray, failed: bool) -> np.ndarray:
    """`grey` scaled to THUMBNAIL_WIDTH columns with `pixels` drawn (the first in red), or a
    red cross over it when `failed`."""
    cv2 = import_cv2()
    scale = THUMBNAIL_WIDTH / grey.shape[1]
    height = max(1, round(grey.shape[0] * scale))
    image = cv2.cvtColor(cv2.resize(grey, (THUMBNAIL_WIDTH, height),
                                    interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
    if failed:
        cv2.line(image, (0, 0), (THUMBNAIL_WIDTH - 1, height - 1), _FAILED, 2)
        cv2.line(image, (0, height - 1), (THUMBNAIL_WIDTH - 1, 0), _FAILED, 2)
    for k, (u, v) in enumerate((pixels + 0.5) * scale - 0.5):
        cv2.circle(image, (round(u), round(v)), 3 if k == 0 else 2, _FIRST if k == 0 else _POINT,
                   -1 if k == 0 else 1, cv2.LINE_AA)
    return image


def detect_image(path: pathlib.Path, board: Board) -> ImageDetection:
    """Read `path`, find `board` in it and draw its thumbnail (`ImageDetection`)."""
    cv2 = import_cv2()
    empty = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    try:
        grey = read_grey(path)
    except ImageError as error:
        return ImageDetection(path, None, *empty, str(error))
    size = (int(grey.shape[1]), int(grey.shape[0]))
    try:
        found = find_board(grey, board)
        ids, pixels, reason = found.ids, found.pixels, ""
    except NotFound as error:
        (ids, pixels), reason = empty, str(error)
    except cv2.error as error:
        (ids, pixels), reason = empty, f"OpenCV failed: {str(error).strip().splitlines()[-1]}"
    return ImageDetection(path, size, ids, pixels, reason,
                          _thumbnail(grey, pixels, failed=bool(reason)))
