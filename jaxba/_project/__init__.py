"""Project files (FORMATS.md) in, BundleProblem out; plain Python around the jitted core."""

from ._adjust import adjust_project
from ._build import Project, build_project
from ._errors import ProjectError
from ._readers import read_project
from ._spec import AdjustmentSettings, ProjectSpec

__all__ = [
    "AdjustmentSettings", "Project", "ProjectError", "ProjectSpec", "adjust_project",
    "build_project", "read_project",
]
