"""Project files: read into the project model (`read_project` -> `jaxba._project`'s
`ProjectSpec`) and written (`write_project`: `jaxba init`'s output); no jax.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._readers": ("read_project", "read_project_inputs"),
    "._write": ("write_project",),
})
