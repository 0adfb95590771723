"""Pose models: how an image's six values place its camera in object space.

`POSE_MODELS` names them (`"opk"`, `"rodrigues"`), as `CAMERA_MODELS` names the cameras.
"""

from ._abstract import (
    AbstractPose as AbstractPose,
    MatrixPose as MatrixPose,
    image_frames as image_frames,
    image_row_inputs as image_row_inputs,
)
from ._composed import ComposedPose as ComposedPose
from ._opk import OpkPose as OpkPose
from ._registry import POSE_MODELS as POSE_MODELS
from ._rodrigues import RodriguesPose as RodriguesPose, rotate_point as rotate_point
