"""`jaxba detect`: a calibration target found in images (OpenCV, the optional extra
`jaxba[images]`), written as a project. Only this package and the exporters import cv2, and
only when called."""

from ._board import Board, BoardError, parse_board
from ._find import charuco_board
from ._image import ImageDetection
from ._opencv import INSTALL_HINT, OpenCVMissingError, import_cv2
from ._project import DetectedProject, DetectError, detected_project
from ._run import detect_images
from ._write import write_detected

__all__ = [
    "INSTALL_HINT", "Board", "BoardError", "DetectError", "DetectedProject",
    "ImageDetection", "OpenCVMissingError", "charuco_board", "detect_images",
    "detected_project", "import_cv2", "parse_board", "write_detected",
]
