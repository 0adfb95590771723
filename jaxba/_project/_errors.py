"""The exception raised for bad project files."""


class ProjectError(ValueError):
    """A project file or table is malformed; the message names the file, line and field."""
