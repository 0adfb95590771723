"""Project files: read into the project model (`read_project` -> `jaxba._project`'s
`ProjectSpec`) and written (`write_project`: `jaxba init`'s output); no jax.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._readers": ("ProjectFile", "read_project", "read_project_file", "read_project_tables"),
    "._write": ("write_project",),
})
