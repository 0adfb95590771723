"""Converters from published data sets to jaxba project files (docs/project-files.md).

Imported from their modules when first used (`jaxba._lazy`): reading a project
(`jaxba._io._project`) loads none of the converters.
"""

from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._colmap": (
        "ColmapModel", "ColmapProject", "project_to_colmap", "read_colmap_model", "write_colmap",
        "write_colmap_model", "write_colmap_project",
    ),
    "._dbat": ("DbatProject", "write_dbat_project"),
    "._opencv_yaml": ("write_opencv_yaml", "write_project_camera_yaml"),
    "._zhang": ("ZhangProject", "write_zhang_project"),
})
