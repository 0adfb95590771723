"""A COLMAP model folder, binary or text, read as COLMAP reads it; its rigs and frames checked
against its cameras and images."""

import os
import pathlib

from ._binary import BINARY_FILES, read_binary_model
from ._model import CAMERA, SENSOR_TYPES, ColmapModel
from ._text import read_text_model


def read_colmap_model(directory: str | os.PathLike) -> ColmapModel:
    """The COLMAP model in `directory`: binary where cameras.bin, images.bin and points3D.bin
    are all there (as COLMAP chooses), else text (cameras.txt, images.txt, points3D.txt);
    rigs and frames (rigs.bin/frames.bin, rigs.txt/frames.txt) where both files are there.

    Raises `ValueError` naming the file and line (or record) of anything malformed or
    unsupported, and of rigs and frames that do not fit the cameras and images.
    """
    directory = pathlib.Path(directory)
    binary = all((directory / name).is_file() for name in BINARY_FILES)
    model = read_binary_model(directory) if binary else read_text_model(directory)
    if model.rigs or model.frames:
        _check_rigs(model, *(f"{name}.{'bin' if binary else 'txt'}"
                             for name in ("rigs", "frames", "images")))
    return model


def _check_rigs(model: ColmapModel, rigs_file: str, frames_file: str, images_file: str) -> None:
    """Every sensor of a known type, every rig camera a camera, every frame a known rig's with
    its own sensors and images of their cameras, every image in one frame."""
    for rig in model.rigs.values():
        for kind, sensor in (rig.reference, *(s for s, _ in rig.sensors)):
            if kind not in SENSOR_TYPES:
                raise ValueError(f"{rigs_file}: rig {rig.id}: unknown sensor type {kind!r}; "
                                 f"known: {', '.join(SENSOR_TYPES)}")
            if kind == CAMERA and sensor not in model.cameras:
                raise ValueError(f"{rigs_file}: rig {rig.id}: unknown camera {sensor}")
    frame_of: dict[int, int] = {}
    for frame in model.frames.values():
        where = f"{frames_file}: frame {frame.id}"
        if frame.rig_id not in model.rigs:
            raise ValueError(f"{where}: unknown rig {frame.rig_id}")
        rig = model.rigs[frame.rig_id]
        sensors = {rig.reference, *(s for s, _ in rig.sensors)}
        for kind, sensor, data in frame.data:
            if (kind, sensor) not in sensors:
                raise ValueError(f"{where}: sensor {kind} {sensor} is not in rig {rig.id}")
            if kind != CAMERA:
                continue
            image = model.images.get(data)
            if image is None:
                raise ValueError(f"{where}: image {data} is not in {images_file}")
            if image.camera_id != sensor:
                raise ValueError(f"{where}: image {data} was taken with camera "
                                 f"{image.camera_id}, not {sensor}")
            if data in frame_of:
                raise ValueError(f"{where}: image {data} is also in frame {frame_of[data]}")
            frame_of[data] = frame.id
    missing = sorted(set(model.images) - set(frame_of))
    if missing:
        raise ValueError(f"{images_file}: image {missing[0]} is in no frame of {frames_file}")
