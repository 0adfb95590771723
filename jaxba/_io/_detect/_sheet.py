"""The contact sheet: every image's thumbnail with the points found, failures marked, in one
PNG; each tile captioned with the camera, the image id and the points found or the reason."""

import numpy as np

from ._image import THUMBNAIL_WIDTH
from ._opencv import import_cv2
from ._project import DetectedImage

COLUMNS = 6
_CAPTION = 30  # pixels under each thumbnail: two lines of text
_MARGIN = 4
_OK, _FAILED, _BACKGROUND, _EMPTY = (0, 120, 0), (0, 0, 200), (255, 255, 255), (200, 200, 200)


def _fit(cv2, text: str, width: int, scale: float) -> str:
    """`text` shortened (ending in ~) to fit `width` pixels at font `scale`."""
    while len(text) > 1 and cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width:
        text = text[:-2] + "~"
    return text


def contact_sheet(images: list[DetectedImage]) -> bytes:
    """The contact sheet of `images` as PNG bytes (module docstring)."""
    cv2 = import_cv2()
    heights = [image.detection.thumbnail.shape[0] for image in images
               if image.detection.thumbnail is not None]
    tile_h = max(heights, default=THUMBNAIL_WIDTH * 3 // 4)
    rows = max(1, -(-len(images) // COLUMNS))
    cell_w, cell_h = THUMBNAIL_WIDTH + _MARGIN, tile_h + _CAPTION + _MARGIN
    sheet = np.full((rows * cell_h + _MARGIN, min(len(images), COLUMNS) * cell_w + _MARGIN, 3),
                    _BACKGROUND, dtype=np.uint8)
    for k, image in enumerate(images):
        top, left = _MARGIN + (k // COLUMNS) * cell_h, _MARGIN + (k % COLUMNS) * cell_w
        thumbnail = image.detection.thumbnail
        if thumbnail is None:
            sheet[top:top + tile_h, left:left + THUMBNAIL_WIDTH] = _EMPTY
        else:
            sheet[top:top + thumbnail.shape[0], left:left + THUMBNAIL_WIDTH] = thumbnail
        detection = image.detection
        colour = _OK if detection.found else _FAILED
        if not detection.found:
            cv2.rectangle(sheet, (left, top), (left + THUMBNAIL_WIDTH - 1, top + tile_h - 1),
                          _FAILED, 2)
        second = f"{len(detection.ids)} points" if detection.found else detection.reason
        for line, text in enumerate((f"{image.camera} {image.id}", second)):
            text = _fit(cv2, text, THUMBNAIL_WIDTH, 0.38)
            cv2.putText(sheet, text, (left, top + tile_h + 12 + 13 * line),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.38, colour, 1, cv2.LINE_AA)
    return cv2.imencode(".png", sheet)[1].tobytes()
