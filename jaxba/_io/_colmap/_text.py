"""COLMAP's text model (colmap.github.io/format.html, "Text format"), read and written.

- cameras.txt: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`;
- images.txt: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then
  `POINTS2D[] as (X, Y, POINT3D_ID)` (POINT3D_ID -1: not triangulated);
- points3D.txt: `POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)`;
- rigs.txt (COLMAP 3.12 and later): `RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID
  SENSORS[] as (SENSOR_TYPE SENSOR_ID HAS_POSE [QW QX QY QZ TX TY TZ])`, the pose
  sensor_from_rig, given where HAS_POSE is 1;
- frames.txt (the same): `FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS DATA_IDS[] as
  (SENSOR_TYPE SENSOR_ID DATA_ID)`, the pose rig_from_world, a camera's DATA_ID an IMAGE_ID.

Sensor types are written as words (CAMERA, IMU). Plain Python.
"""

import os
import pathlib

from ._model import (
    COLMAP_CAMERA_MODELS,
    ColmapCamera,
    ColmapFrame,
    ColmapImage,
    ColmapModel,
    ColmapPoint,
    ColmapRig,
)

TEXT_FILES = ("cameras.txt", "images.txt", "points3D.txt")
RIG_FILES = ("rigs.txt", "frames.txt")


def _data_lines(path: pathlib.Path):
    """(line number, tokens) of the non-comment lines; blank lines kept (images.txt needs them)."""
    if not path.is_file():
        raise ValueError(f"{path}: no such COLMAP file")
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.lstrip().startswith("#"):
            continue
        yield number, line.split()


def _numbers(path, number, tokens, kind=float):
    try:
        return [kind(token) for token in tokens]
    except ValueError:
        raise ValueError(f"{path}:{number}: expected numbers, got {' '.join(tokens)!r}") from None


def _read_cameras(path: pathlib.Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        if len(tokens) < 4:
            raise ValueError(f"{path}:{number}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        camera_id, width, height = _numbers(path, number, [tokens[0], *tokens[2:4]], int)
        model = tokens[1]
        if model not in COLMAP_CAMERA_MODELS:
            raise ValueError(f"{path}:{number}: unsupported camera model {model!r}; supported: "
                             f"{', '.join(COLMAP_CAMERA_MODELS)}")
        params = tuple(_numbers(path, number, tokens[4:]))
        expected = len(COLMAP_CAMERA_MODELS[model][1])
        if len(params) != expected:
            raise ValueError(f"{path}:{number}: {model} has {expected} parameters, "
                             f"got {len(params)}")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def _read_images(path: pathlib.Path, cameras) -> dict[int, ColmapImage]:
    images = {}
    lines = list(_data_lines(path))
    k = 0
    while k < len(lines):
        number, tokens = lines[k]
        if not tokens:
            k += 1
            continue
        if len(tokens) < 10:
            raise ValueError(f"{path}:{number}: expected IMAGE_ID QW QX QY QZ TX TY TZ "
                             "CAMERA_ID NAME")
        image_id, camera_id = _numbers(path, number, [tokens[0], tokens[8]], int)
        pose = _numbers(path, number, tokens[1:8])
        name = " ".join(tokens[9:])
        if camera_id not in cameras:
            raise ValueError(f"{path}:{number}: unknown CAMERA_ID {camera_id}")
        points2d: list[tuple[float, float, int]] = []
        if k + 1 < len(lines):
            number2, tokens2 = lines[k + 1]
            if len(tokens2) % 3:
                raise ValueError(f"{path}:{number2}: POINTS2D: expected triples X Y POINT3D_ID")
            for j in range(0, len(tokens2), 3):
                x, y = _numbers(path, number2, tokens2[j:j + 2])
                (pid,) = _numbers(path, number2, tokens2[j + 2:j + 3], int)
                points2d.append((x, y, pid))
        images[image_id] = ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id,
                                       name, tuple(points2d))
        k += 2
    return images


def _read_points(path: pathlib.Path, images) -> dict[int, ColmapPoint]:
    points = {}
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        if len(tokens) < 8 or (len(tokens) - 8) % 2:
            raise ValueError(f"{path}:{number}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]")
        (point_id,) = _numbers(path, number, tokens[:1], int)
        xyz = _numbers(path, number, tokens[1:4])
        rgb = _numbers(path, number, tokens[4:7], int)
        (error,) = _numbers(path, number, tokens[7:8])
        track = _numbers(path, number, tokens[8:], int)
        pairs = tuple(zip(track[0::2], track[1::2]))
        for image_id, index in pairs:
            if image_id not in images or not 0 <= index < len(images[image_id].points2d):
                raise ValueError(f"{path}:{number}: track entry ({image_id}, {index}) names no "
                                 "2D point of images.txt")
        points[point_id] = ColmapPoint(point_id, tuple(xyz), tuple(rgb), error, pairs)
    return points


class _Tokens:
    """A line's tokens read one field at a time; running out names the file, line and field."""

    def __init__(self, path, number, tokens, layout: str):
        self.path, self.number, self.tokens, self.layout, self.k = path, number, tokens, layout, 0

    def take(self, n: int, kind=float) -> list:
        if self.k + n > len(self.tokens):
            raise ValueError(f"{self.path}:{self.number}: too few fields; expected {self.layout}")
        self.k += n
        return _numbers(self.path, self.number, self.tokens[self.k - n:self.k], kind)

    def word(self) -> str:
        if self.k >= len(self.tokens):
            raise ValueError(f"{self.path}:{self.number}: too few fields; expected {self.layout}")
        self.k += 1
        return self.tokens[self.k - 1]

    def done(self) -> None:
        if self.k != len(self.tokens):
            raise ValueError(f"{self.path}:{self.number}: {len(self.tokens) - self.k} fields too"
                             f" many; expected {self.layout}")


_RIG_LAYOUT = ("RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID SENSORS[] as (SENSOR_TYPE "
               "SENSOR_ID HAS_POSE [QW QX QY QZ TX TY TZ])")
_FRAME_LAYOUT = ("FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS DATA_IDS[] as (SENSOR_TYPE "
                 "SENSOR_ID DATA_ID)")


def _read_rigs(path: pathlib.Path) -> dict[int, ColmapRig]:
    rigs = {}
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        line = _Tokens(path, number, tokens, _RIG_LAYOUT)
        rig_id, n_sensors = line.take(2, int)
        if n_sensors < 1:
            raise ValueError(f"{path}:{number}: rig {rig_id} has no sensor")
        reference = (line.word(), *line.take(1, int))
        sensors = []
        for _ in range(n_sensors - 1):
            sensor = (line.word(), *line.take(1, int))
            (has_pose,) = line.take(1, int)
            pose = line.take(7) if has_pose else None
            sensors.append((sensor, None if pose is None else (tuple(pose[:4]), tuple(pose[4:]))))
        line.done()
        rigs[rig_id] = ColmapRig(rig_id, reference, tuple(sensors))
    return rigs


def _read_frames(path: pathlib.Path) -> dict[int, ColmapFrame]:
    frames = {}
    for number, tokens in _data_lines(path):
        if not tokens:
            continue
        line = _Tokens(path, number, tokens, _FRAME_LAYOUT)
        frame_id, rig_id = line.take(2, int)
        pose = line.take(7)
        (n_data,) = line.take(1, int)
        data = tuple((line.word(), *line.take(2, int)) for _ in range(n_data))
        line.done()
        frames[frame_id] = ColmapFrame(frame_id, rig_id, tuple(pose[:4]), tuple(pose[4:]), data)
    return frames


def read_text_model(directory: pathlib.Path) -> ColmapModel:
    """The text model in `directory`: cameras.txt, images.txt, points3D.txt, and rigs.txt and
    frames.txt where both are there. Raises `ValueError` naming the file and line of
    anything malformed or unsupported."""
    cameras = _read_cameras(directory / "cameras.txt")
    images = _read_images(directory / "images.txt", cameras)
    points = _read_points(directory / "points3D.txt", images)
    if not all((directory / name).is_file() for name in RIG_FILES):
        return ColmapModel(cameras, images, points)
    return ColmapModel(cameras, images, points, _read_rigs(directory / "rigs.txt"),
                       _read_frames(directory / "frames.txt"))


def _numbers_text(values) -> list[str]:
    return [repr(float(v)) for v in values]


def colmap_model_texts(model: ColmapModel) -> dict[str, str]:
    """`model` as COLMAP text: file name (cameras.txt, images.txt, points3D.txt, and rigs.txt
    and frames.txt where it has rigs) -> text."""
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(model.cameras)}"]
    lines += [" ".join([str(c.id), c.model, str(c.width), str(c.height),
                        *_numbers_text(c.params)]) for c in model.cameras.values()]
    texts = {"cameras.txt": "\n".join(lines) + "\n"}

    n_obs = sum(len(i.points2d) for i in model.images.values())
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(model.images)}, mean observations per image: "
             f"{n_obs / max(len(model.images), 1)}"]
    for image in model.images.values():
        lines.append(" ".join([str(image.id), *_numbers_text(image.qvec),
                               *_numbers_text(image.tvec), str(image.camera_id), image.name]))
        lines.append(" ".join(f"{float(x)!r} {float(y)!r} {pid}" for x, y, pid in image.points2d))
    texts["images.txt"] = "\n".join(lines) + "\n"

    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(model.points)}"]
    lines += [" ".join([str(p.id), *_numbers_text(p.xyz), *(str(v) for v in p.rgb),
                        repr(float(p.error)), *(f"{i} {j}" for i, j in p.track)])
              for p in model.points.values()]
    texts["points3D.txt"] = "\n".join(lines) + "\n"
    if model.rigs:
        texts.update(_rig_texts(model))
    return texts


def _rig_texts(model: ColmapModel) -> dict[str, str]:
    lines = ["# Rig calib list with one line of data per calib:",
             "#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE,"
             " SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])",
             f"# Number of rigs: {len(model.rigs)}"]
    for rig in model.rigs.values():
        fields = [str(rig.id), str(1 + len(rig.sensors)), rig.reference[0], str(rig.reference[1])]
        for (kind, sensor_id), pose in rig.sensors:
            fields += [kind, str(sensor_id), "0" if pose is None else "1"]
            if pose is not None:
                fields += [*_numbers_text(pose[0]), *_numbers_text(pose[1])]
        lines.append(" ".join(fields))
    texts = {"rigs.txt": "\n".join(lines) + "\n"}
    lines = ["# Frame list with one line of data per frame:",
             "#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS,"
             " DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)",
             f"# Number of frames: {len(model.frames)}"]
    lines += [" ".join([str(frame.id), str(frame.rig_id), *_numbers_text(frame.qvec),
                        *_numbers_text(frame.tvec), str(len(frame.data)),
                        *(f"{kind} {sensor} {data}" for kind, sensor, data in frame.data)])
              for frame in model.frames.values()]
    texts["frames.txt"] = "\n".join(lines) + "\n"
    return texts


def write_colmap_model(model: ColmapModel, directory: str | os.PathLike) -> None:
    """Write `model` as COLMAP text (cameras.txt, images.txt, points3D.txt; rigs.txt and
    frames.txt where it has rigs) into `directory`."""
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in colmap_model_texts(model).items():
        (directory / name).write_text(text)
