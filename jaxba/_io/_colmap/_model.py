"""A COLMAP reconstruction as records: cameras, images, points and (COLMAP 3.12 and later)
rigs and frames, in COLMAP's own conventions (pixels, quaternions, world-to-camera poses)."""

import dataclasses

# COLMAP model -> (jaxba model, COLMAP parameter names, default free parameters),
# "f" stands for fx and fy.
COLMAP_CAMERA_MODELS: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": ("opencv", ("f", "cx", "cy"), ("f",)),
    "PINHOLE": ("opencv", ("fx", "fy", "cx", "cy"), ("fx", "fy")),
    "SIMPLE_RADIAL": ("opencv", ("f", "cx", "cy", "k1"), ("f", "k1")),
    "RADIAL": ("opencv", ("f", "cx", "cy", "k1", "k2"), ("f", "k1", "k2")),
    "OPENCV": ("opencv", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
               ("fx", "fy", "k1", "k2", "p1", "p2")),
    "FULL_OPENCV": ("opencv_full", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4",
                                    "k5", "k6"),
                    ("fx", "fy", "k1", "k2", "p1", "p2", "k3")),
    "OPENCV_FISHEYE": ("fisheye", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
                       ("fx", "fy", "k1", "k2", "k3", "k4")),
}
CAMERA = "CAMERA"  # COLMAP's sensor type of a camera; its others (IMU) have no images
SENSOR_TYPES = ("CAMERA", "IMU")  # by their number in the binary files

Pose = tuple[tuple[float, float, float, float], tuple[float, float, float]]  # (q wxyz, t)
Sensor = tuple[str, int]  # (sensor type, sensor id): a camera's id is its CAMERA_ID


@dataclasses.dataclass(frozen=True)
class ColmapCamera:
    """One line of cameras.txt (COLMAP's pixel convention)."""

    id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class ColmapImage:
    """One image of images.txt: world-to-camera pose and its 2D points (COLMAP pixels).

    `points2d`: (x, y, point3d_id) in POINT2D_IDX order, point3d_id -1 where untriangulated.
    """

    id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str
    points2d: tuple[tuple[float, float, int], ...]


@dataclasses.dataclass(frozen=True)
class ColmapPoint:
    """One line of points3D.txt; `track`: (image_id, point2d_idx) pairs."""

    id: int
    xyz: tuple[float, float, float]
    rgb: tuple[int, int, int]
    error: float
    track: tuple[tuple[int, int], ...]


@dataclasses.dataclass(frozen=True)
class ColmapRig:
    """One line of rigs.txt: the `reference` sensor (its frame is the rig frame) and every
    other sensor with its sensor_from_rig pose (q, t), None where COLMAP does not know it."""

    id: int
    reference: Sensor
    sensors: tuple[tuple[Sensor, Pose | None], ...]


@dataclasses.dataclass(frozen=True)
class ColmapFrame:
    """One line of frames.txt: rig `rig_id` at one instant, its rig_from_world pose (q, t),
    and its data as (sensor type, sensor id, data id): a camera's data id is an IMAGE_ID."""

    id: int
    rig_id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    data: tuple[tuple[str, int, int], ...]


@dataclasses.dataclass(frozen=True)
class ColmapModel:
    """A COLMAP reconstruction: cameras, images and points by id; rigs and frames by id
    where it has them (COLMAP 3.12 and later; empty for an older model)."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: dict[int, ColmapPoint]
    rigs: dict[int, ColmapRig] = dataclasses.field(default_factory=dict)
    frames: dict[int, ColmapFrame] = dataclasses.field(default_factory=dict)
