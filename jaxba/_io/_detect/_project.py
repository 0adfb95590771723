"""The detections of every camera made into a calibration: which images are used, the cameras'
and images' approximations, a rig's frames and relative poses. Plain NumPy."""

import collections
import dataclasses

import numpy as np

from ._board import Board
from ._frames import frame_number, image_ids
from ._image import ImageDetection
from ._rig import relative_pose
from ._start import CameraStart, camera_start, spread_enough


class DetectError(ValueError):
    """The detections do not make a project (no image of the rig's reference camera, ...);
    `project` has every image with its reason, and no camera."""

    def __init__(self, message: str, project: "DetectedProject"):
        super().__init__(message)
        self.project = project


@dataclasses.dataclass(frozen=True)
class DetectedImage:
    """One image file: its `camera`, `id` and `detection` (with the reason it is left out,
    if it is)."""

    camera: str
    id: str
    detection: ImageDetection


@dataclasses.dataclass(frozen=True)
class DetectedProject:
    """A calibration from detections.

    `images`: every image file in input order; `sizes` and `starts`: (columns, rows) and the
    approximations (`CameraStart`, one EOP per used image in `images` order) of each camera
    with at least one used image; `rig`: its name or None; `frames`: image id -> frame id of
    the used images (rig only); `relative`: camera -> (X0, Y0, Z0, omega, phi, kappa) in the
    rig frame, every rig camera but the reference (the first camera).
    """

    board: Board
    images: list[DetectedImage]
    sizes: dict[str, tuple[int, int]]
    starts: dict[str, CameraStart]
    rig: str | None = None
    frames: dict[str, str] = dataclasses.field(default_factory=dict)
    relative: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def used(self, camera: str | None = None) -> list[DetectedImage]:
        """The images whose points are used (of `camera`, or of all)."""
        return [image for image in self.images if image.detection.found
                and (camera is None or image.camera == camera)]


def _left_out(images: list[DetectedImage], k: int, reason: str) -> None:
    image = images[k]
    images[k] = dataclasses.replace(image, detection=image.detection.left_out(reason))


def _check_sizes(images: list[DetectedImage], camera: str) -> tuple[int, int] | None:
    """The camera's image size (the most common one); images of another size left out."""
    sizes = collections.Counter(image.detection.size for image in images
                                if image.camera == camera and image.detection.size)
    if not sizes:
        return None
    size = sizes.most_common(1)[0][0]
    for k, image in enumerate(images):
        if image.camera == camera and image.detection.found and image.detection.size != size:
            _left_out(images, k, "size {}x{}, not the camera's {}x{}".format(
                *image.detection.size, *size))
    return size


def _frames(images: list[DetectedImage], rig: str) -> dict[str, str]:
    """Image id -> frame id (the number its file name ends in) of the used images; an image
    without a number, or with one another image of its camera has, is left out."""
    frames, taken = {}, {}
    for k, image in enumerate(images):
        if not image.detection.found:
            continue
        number = frame_number(image.detection.path)
        if number is None:
            _left_out(images, k, f"no number at the end of its file name: no frame of rig {rig}")
        elif (image.camera, number) in taken:
            _left_out(images, k, f"frame {number}: {taken[image.camera, number]} of this camera"
                                 " has the same number")
        else:
            taken[image.camera, number] = image.id
            frames[image.id] = str(number)
    return frames


def _relative_poses(project: DetectedProject, cameras: list[str]) -> dict[str, np.ndarray]:
    reference = cameras[0]
    failed = dataclasses.replace(project, sizes={}, starts={})
    if reference not in project.starts:
        raise DetectError(f"rig {project.rig}: its reference camera {reference} (the first"
                          " --camera) has no image with the board", failed)
    eops = {camera: {project.frames[image.id]: eop for image, eop in
                     zip(project.used(camera), project.starts[camera].eops)}
            for camera in project.starts}
    relative = {}
    for camera in cameras[1:]:
        if camera not in project.starts:
            continue
        shared = [frame for frame in eops[camera] if frame in eops[reference]]
        if not shared:
            raise DetectError(f"rig {project.rig}: camera {camera} and the reference camera"
                              f" {reference} saw the board in no common frame (images whose"
                              " file names end in the same number)", failed)
        relative[camera] = relative_pose([eops[reference][f] for f in shared],
                                         [eops[camera][f] for f in shared])
    return relative


def detected_project(
    board: Board, detections: dict[str, list[ImageDetection]], *, rig: str | None = None,
) -> DetectedProject:
    """The calibration of the cameras (name -> their images' detections, the first camera the
    rig's reference) from the images where the board was found.

    An image is left out (its reason set) when its size differs from its camera's (the most
    common one), when the points seen lie on a line, or, in a rig, when its file name ends in
    no number or in one that another image of its camera ends in.
    """
    cameras = list(detections)
    files = [(camera, detection.path) for camera in cameras for detection in detections[camera]]
    ids = iter(image_ids(files))
    images = [DetectedImage(camera, next(ids), detection)
              for camera in cameras for detection in detections[camera]]
    points = board.points()
    for k, image in enumerate(images):
        if image.detection.found and not spread_enough(points[image.detection.ids, :2]):
            _left_out(images, k, "the points seen lie on a line: no pose")
    sizes = {camera: size for camera in cameras
             if (size := _check_sizes(images, camera)) is not None}
    frames = _frames(images, rig) if rig is not None else {}
    project = DetectedProject(board, images, {}, {}, rig, frames)
    starts = {}
    for camera in cameras:
        used = project.used(camera)
        if used:
            starts[camera] = camera_start(
                [points[image.detection.ids, :2] for image in used],
                [image.detection.pixels for image in used], sizes[camera])
    project = dataclasses.replace(
        project, sizes={camera: sizes[camera] for camera in starts}, starts=starts)
    if rig is not None:
        project = dataclasses.replace(project, relative=_relative_poses(project, cameras))
    return project

