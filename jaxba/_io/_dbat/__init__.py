"""DBAT (Börlin & Grussenmeyer's Damped Bundle Adjustment Toolbox) script projects for jaxba:
the script and its tables (`_script`, `_tables`, `_camera`), DBAT's starting values
(`_geometry`) and the project writer (`_project`). Plain NumPy; no jax.
"""

from ._camera import DbatCamera, read_cameras
from ._geometry import intersect, planar_resection
from ._project import DbatProject, jaxba_pixels, write_dbat_project
from ._script import DbatScript, read_script
from ._tables import ControlPoint, MarkPoint, read_control_points, read_mark_points

__all__ = [
    "ControlPoint", "DbatCamera", "DbatProject", "DbatScript", "MarkPoint", "intersect",
    "jaxba_pixels", "planar_resection", "read_cameras", "read_control_points", "read_mark_points",
    "read_script", "write_dbat_project",
]
