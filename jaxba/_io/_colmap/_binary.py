"""COLMAP's binary model (cameras.bin, images.bin, points3D.bin; rigs.bin and frames.bin in
COLMAP 3.12 and later), read: the records of the text files in little-endian numbers.

Each file starts with its record count (uint64). cameras: id (uint32), model (int32), width,
height (uint64), the parameters (float64). images: id (uint32), q, t (7 float64), camera id
(uint32), the NUL-terminated name, the 2D point count (uint64), then (x, y (float64),
point3D id (uint64; all bits set: none)). points3D: id (uint64), xyz (3 float64), rgb (3
uint8), error (float64), track length (uint64), then (image id, point2D index (uint32)).
rigs: id (uint32), sensor count (uint32), the reference (type int32, id uint32), then per
other sensor its type, id, has_pose (uint8) and, where 1, q, t (7 float64). frames: id, rig
id (uint32), q, t (7 float64), data count (uint32), then (sensor type (int32), sensor id
(uint32), data id (uint64)). Sensor types: 0 camera, 1 IMU.
"""

import pathlib
import struct

import numpy as np

from ._model import (
    COLMAP_CAMERA_MODELS,
    SENSOR_TYPES,
    ColmapCamera,
    ColmapFrame,
    ColmapImage,
    ColmapModel,
    ColmapPoint,
    ColmapRig,
)

BINARY_FILES = ("cameras.bin", "images.bin", "points3D.bin")
RIG_FILES = ("rigs.bin", "frames.bin")
# COLMAP's numbers of the camera models jaxba reads (src/colmap/sensor/models.h)
MODEL_NUMBERS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3,
                 "OPENCV": 4, "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6}
_MODEL_NAMES = {number: name for name, number in MODEL_NUMBERS.items()}
_NO_POINT3D = 2**64 - 1
_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("point3d", "<u8")])
_TRACK = np.dtype([("image", "<u4"), ("index", "<u4")])


class _Reader:
    """Little-endian fields of one file, read in order; running out names the file and the
    record."""

    def __init__(self, path: pathlib.Path):
        if not path.is_file():
            raise ValueError(f"{path}: no such COLMAP file")
        self.path, self.data, self.offset, self.record = path, path.read_bytes(), 0, "the count"

    def _take(self, size: int) -> bytes:
        if self.offset + size > len(self.data):
            raise ValueError(f"{self.path}: ends inside {self.record} (byte {self.offset}); "
                             "not a complete COLMAP binary file")
        self.offset += size
        return self.data[self.offset - size:self.offset]

    def fields(self, layout: str) -> tuple:
        return struct.unpack("<" + layout, self._take(struct.calcsize("<" + layout)))

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        return np.frombuffer(self._take(dtype.itemsize * count), dtype=dtype)

    def name(self) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise ValueError(f"{self.path}: ends inside {self.record}'s name")
        text = self._take(end - self.offset + 1)[:-1]
        try:
            return text.decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{self.path}: {self.record}: its name is not UTF-8") from None

    def sensor_type(self) -> str:
        (number,) = self.fields("i")
        if not 0 <= number < len(SENSOR_TYPES):
            raise ValueError(f"{self.path}: {self.record}: unknown sensor type {number}")
        return SENSOR_TYPES[number]

    def end(self) -> None:
        if self.offset != len(self.data):
            raise ValueError(f"{self.path}: {len(self.data) - self.offset} bytes after the last"
                             " record")


def _read_cameras(path: pathlib.Path) -> dict[int, ColmapCamera]:
    file = _Reader(path)
    cameras = {}
    for k in range(file.fields("Q")[0]):
        file.record = f"camera record {k + 1}"
        camera_id, number, width, height = file.fields("IiQQ")
        if number not in _MODEL_NAMES:
            raise ValueError(f"{path}: camera {camera_id}: unsupported camera model number "
                             f"{number}; supported: "
                             f"{', '.join(f'{n} {m}' for m, n in MODEL_NUMBERS.items())}")
        model = _MODEL_NAMES[number]
        params = file.fields("d" * len(COLMAP_CAMERA_MODELS[model][1]))
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    file.end()
    return cameras


def _read_images(path: pathlib.Path, cameras) -> dict[int, ColmapImage]:
    file = _Reader(path)
    images = {}
    for k in range(file.fields("Q")[0]):
        file.record = f"image record {k + 1}"
        image_id, *pose, camera_id = file.fields("I7dI")
        if camera_id not in cameras:
            raise ValueError(f"{path}: image {image_id}: unknown camera {camera_id}")
        name = file.name()
        points = file.array(_POINT2D, file.fields("Q")[0])
        ids = np.where(points["point3d"] == _NO_POINT3D, -1, points["point3d"].astype(np.int64))
        points2d = tuple(zip(points["x"].tolist(), points["y"].tolist(), ids.tolist()))
        images[image_id] = ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id,
                                       name, points2d)
    file.end()
    return images


def _read_points(path: pathlib.Path, images) -> dict[int, ColmapPoint]:
    file = _Reader(path)
    points = {}
    for k in range(file.fields("Q")[0]):
        file.record = f"point record {k + 1}"
        point_id, x, y, z, r, g, b, error = file.fields("Q3d3Bd")
        track = file.array(_TRACK, file.fields("Q")[0])
        pairs = tuple(zip(track["image"].tolist(), track["index"].tolist()))
        for image_id, index in pairs:
            if image_id not in images or index >= len(images[image_id].points2d):
                raise ValueError(f"{path}: point {point_id}: track entry ({image_id}, {index}) "
                                 "names no 2D point of images.bin")
        points[point_id] = ColmapPoint(point_id, (x, y, z), (r, g, b), error, pairs)
    file.end()
    return points


def _read_rigs(path: pathlib.Path) -> dict[int, ColmapRig]:
    file = _Reader(path)
    rigs = {}
    for k in range(file.fields("Q")[0]):
        file.record = f"rig record {k + 1}"
        rig_id, n_sensors = file.fields("II")
        if n_sensors < 1:
            raise ValueError(f"{path}: rig {rig_id} has no sensor")
        reference = (file.sensor_type(), *file.fields("I"))
        sensors = []
        for _ in range(n_sensors - 1):
            sensor = (file.sensor_type(), *file.fields("I"))
            pose = file.fields("7d") if file.fields("B")[0] else None
            sensors.append((sensor, None if pose is None else (pose[:4], pose[4:])))
        rigs[rig_id] = ColmapRig(rig_id, reference, tuple(sensors))
    file.end()
    return rigs


def _read_frames(path: pathlib.Path) -> dict[int, ColmapFrame]:
    file = _Reader(path)
    frames = {}
    for k in range(file.fields("Q")[0]):
        file.record = f"frame record {k + 1}"
        frame_id, rig_id, *pose, n_data = file.fields("II7dI")
        data = tuple((file.sensor_type(), *file.fields("IQ")) for _ in range(n_data))
        frames[frame_id] = ColmapFrame(frame_id, rig_id, tuple(pose[:4]), tuple(pose[4:]), data)
    file.end()
    return frames


def read_binary_model(directory: pathlib.Path) -> ColmapModel:
    """The binary model in `directory`: cameras.bin, images.bin, points3D.bin, and rigs.bin
    and frames.bin where both are there. Raises `ValueError` naming the file and record of
    anything malformed or unsupported."""
    cameras = _read_cameras(directory / "cameras.bin")
    images = _read_images(directory / "images.bin", cameras)
    points = _read_points(directory / "points3D.bin", images)
    if not all((directory / name).is_file() for name in RIG_FILES):
        return ColmapModel(cameras, images, points)
    return ColmapModel(cameras, images, points, _read_rigs(directory / "rigs.bin"),
                       _read_frames(directory / "frames.bin"))
