"""Initial approximations by closed forms and small least-squares problems: DLT,
space resection, forward intersection, relative and absolute orientation, stereo parallax.

Each tool is a plain function of NumPy arrays, usable on its own, in jaxba's conventions
(docs/conventions.md: image frame x right, y up, camera looking along -z; M = R3(kappa) R2(phi)
R1(omega); angles in radians), so that its EOPs and points start a jaxba adjustment.
"""

from ._absolute_orientation import (
    SIMILARITY_PARAMETERS as SIMILARITY_PARAMETERS,
    Similarity as Similarity,
    absolute_orientation as absolute_orientation,
)
from ._dlt import (
    Dlt as Dlt,
    DltOrientation as DltOrientation,
    decompose_dlt as decompose_dlt,
    dlt as dlt,
)
from ._intersection import (
    Intersection as Intersection,
    forward_intersection as forward_intersection,
)
from ._parallax import (
    air_base_from_parallax as air_base_from_parallax,
    elevation_from_parallax as elevation_from_parallax,
    elevation_from_parallax_difference as elevation_from_parallax_difference,
    flying_height_from_parallax as flying_height_from_parallax,
    ground_from_parallax as ground_from_parallax,
    stereo_parallax as stereo_parallax,
)
from ._relative_orientation import (
    RELATIVE_ORIENTATION_PARAMETERS as RELATIVE_ORIENTATION_PARAMETERS,
    EssentialMatrix as EssentialMatrix,
    RelativeOrientation as RelativeOrientation,
    essential_matrix as essential_matrix,
    relative_orientation as relative_orientation,
)
from ._resection import Resection as Resection, space_resection as space_resection
