"""The board's points in one grey image, by OpenCV.

- chessboard: `findChessboardCorners` refined by `cornerSubPix` (OpenCV's calibration sample;
  the window half the corner spacing, at most 11 x 11 as there), or where that finds none
  `findChessboardCornersSB` (more robust to blur and noise);
- circles, acircles: `findCirclesGrid` with a blob detector that also takes large circles;
- charuco: `CharucoDetector.detectBoard`, any subset of the corners (at least
  `MIN_CHARUCO_CORNERS`).

A chessboard with an odd number of inner corners one way and an even number the other looks
different turned by 180° (the squares at its two ends differ in colour), but OpenCV returns
either order: its points are put in the order whose first inner square is the dark one, so
that two cameras of a rig name the board's points alike. Other chessboards and symmetric
circle grids look the same both ways: their order is OpenCV's, which a rig cannot rely on
(use such a chessboard, an asymmetric grid or a ChArUco board for a rig).
"""

import dataclasses
import functools

import numpy as np

from ._board import Board, BoardError
from ._opencv import import_cv2

MIN_CHARUCO_CORNERS = 6  # a homography needs 4; a few more keep it away from degeneracy
PARTIAL_CHESSBOARD = (3, 3)  # inner corners that show a chessboard is there, but not all of it


class NotFound(ValueError):
    """No (complete enough) board in the image; the message is the reason."""


@dataclasses.dataclass(frozen=True)
class Found:
    """The board points seen: `ids` (n,) int indices into `Board.points()`, `pixels` (n, 2)
    float64 (column, row) with the centre of the top-left pixel at (0, 0)."""

    ids: np.ndarray
    pixels: np.ndarray


def find_board(grey: np.ndarray, board: Board) -> Found:
    """The points of `board` in `grey` (rows, cols) uint8; `NotFound` says why none."""
    finder = {"chessboard": _chessboard, "circles": _circles, "acircles": _circles,
              "charuco": _charuco}[board.kind]
    return finder(grey, board)


def _all(pixels: np.ndarray, board: Board) -> Found:
    return Found(np.arange(board.n_points), np.asarray(pixels, dtype=np.float64).reshape(-1, 2))


def _dark_first(grey: np.ndarray, pixels: np.ndarray, board: Board) -> np.ndarray:
    """Chessboard corners (n, 2) in the order whose first inner square is darker than the last
    (module docstring); as given where the board looks the same both ways."""
    cols, rows = board.pattern_size
    if (cols + rows) % 2 == 0:
        return pixels
    grid = pixels.reshape(rows, cols, 2)

    def grey_at(square: np.ndarray) -> float:
        u, v = np.clip(np.round(square.mean(axis=(0, 1))).astype(int), 0,
                       np.array(grey.shape[::-1]) - 1)
        return float(grey[v, u])

    if grey_at(grid[:2, :2]) > grey_at(grid[-2:, -2:]):
        return pixels[::-1].copy()
    return pixels


def _subpix_half_window(pixels: np.ndarray, board: Board) -> int:
    """Half the smallest spacing of neighbouring corners (pixels), between 2 and 11."""
    cols, rows = board.pattern_size
    grid = pixels.reshape(rows, cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
    return int(np.clip(spacing / 2 - 1, 2, 11))


def _chessboard(grey: np.ndarray, board: Board) -> Found:
    cv2 = import_cv2()
    size = board.pattern_size
    found, corners = cv2.findChessboardCorners(grey, size)
    if found:
        half = _subpix_half_window(corners.reshape(-1, 2), board)
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
        corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), criteria)
    else:
        found, corners = cv2.findChessboardCornersSB(
            grey, size, cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    if found:
        pixels = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        return _all(_dark_first(grey, pixels, board), board)
    if cv2.findChessboardCornersSB(grey, PARTIAL_CHESSBOARD)[0]:
        raise NotFound(f"partial board: a chessboard, but not all its {size[0]}x{size[1]}"
                       " inner corners")
    raise NotFound("no board")


def _blob_detector(cv2, grey: np.ndarray):
    """OpenCV's blob detector with its largest area raised to a tenth of the image."""
    parameters = cv2.SimpleBlobDetector_Params()
    parameters.minArea = 10.0
    parameters.maxArea = max(parameters.maxArea, grey.size / 10)
    return cv2.SimpleBlobDetector_create(parameters)


def _circles(grey: np.ndarray, board: Board) -> Found:
    cv2 = import_cv2()
    detector = _blob_detector(cv2, grey)
    grid = cv2.CALIB_CB_ASYMMETRIC_GRID if board.kind == "acircles" else cv2.CALIB_CB_SYMMETRIC_GRID
    found, centres = cv2.findCirclesGrid(grey, board.pattern_size, flags=grid,
                                         blobDetector=detector)
    if found:
        return _all(centres, board)
    blobs = len(detector.detect(grey))
    if 4 <= blobs < board.n_points:
        raise NotFound(f"partial board: {blobs} blobs, fewer than the board's"
                       f" {board.n_points} circles")
    raise NotFound("no board" if blobs < 4 else f"no board: {blobs} blobs, not in the grid")


@functools.cache
def charuco_board(board: Board):
    """OpenCV's `CharucoBoard` of `board` (its dictionary checked: `BoardError`)."""
    cv2 = import_cv2()
    name = f"DICT_{board.dictionary}"
    if not hasattr(cv2.aruco, name):
        known = sorted(n[5:] for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise BoardError(f"--board {board.text()}: no ArUco dictionary {board.dictionary!r}"
                         f" in OpenCV; known: {', '.join(known)}")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    last = board.first_id + board.n_markers
    if last > dictionary.bytesList.shape[0]:
        raise BoardError(f"--board {board.text()}: the board's marker ids {board.first_id} to"
                         f" {last - 1} exceed the dictionary's {dictionary.bytesList.shape[0]}")
    ids = np.arange(board.first_id, last, dtype=np.int32)
    charuco = cv2.aruco.CharucoBoard((board.cols, board.rows), board.spacing, board.marker,
                                     dictionary, ids)
    charuco.setLegacyPattern(board.legacy)
    return charuco


@functools.cache
def _charuco_detector(board: Board):
    return import_cv2().aruco.CharucoDetector(charuco_board(board))


def _charuco(grey: np.ndarray, board: Board) -> Found:
    corners, ids, _, marker_ids = _charuco_detector(board).detectBoard(grey)
    n_markers = 0 if marker_ids is None else len(marker_ids)
    n_corners = 0 if ids is None else len(ids)
    if n_corners < MIN_CHARUCO_CORNERS:
        if n_markers == 0:
            raise NotFound("no board")
        raise NotFound(f"partial board: {n_markers} markers, {n_corners} corners (at least"
                       f" {MIN_CHARUCO_CORNERS} needed)")
    order = np.argsort(ids.ravel())
    return Found(ids.ravel()[order].astype(np.int64),
                 corners.reshape(-1, 2)[order].astype(np.float64))
