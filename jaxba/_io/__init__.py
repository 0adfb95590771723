"""Converters from published data sets to jaxba project files (FORMATS.md)."""

from ._dbat import DbatProject, write_dbat_project
from ._zhang import ZhangProject, write_zhang_project

__all__ = ["DbatProject", "ZhangProject", "write_dbat_project", "write_zhang_project"]
