"""The pose models an image group names (`ImagePoints.pose`)."""

from ._abstract import AbstractPose
from ._opk import OpkPose
from ._rodrigues import RodriguesPose

POSE_MODELS: dict[str, type[AbstractPose]] = {"opk": OpkPose, "rodrigues": RodriguesPose}
