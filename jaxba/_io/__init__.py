"""Converters from published data sets to jaxba project files (docs/project-files.md)."""

from ._colmap import (
    ColmapModel,
    ColmapProject,
    project_to_colmap,
    read_colmap_model,
    write_colmap,
    write_colmap_model,
    write_colmap_project,
)
from ._dbat import DbatProject, write_dbat_project
from ._opencv_yaml import write_opencv_yaml, write_project_camera_yaml
from ._zhang import ZhangProject, write_zhang_project

__all__ = [
    "ColmapModel", "ColmapProject", "DbatProject", "ZhangProject", "project_to_colmap",
    "read_colmap_model", "write_colmap", "write_colmap_model", "write_colmap_project",
    "write_dbat_project", "write_opencv_yaml", "write_project_camera_yaml", "write_zhang_project",
]
