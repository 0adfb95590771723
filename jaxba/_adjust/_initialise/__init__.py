"""Block initialisation: approximations of every EOP and object point from image
points, approximate cameras and whatever control, distances or EOPs exist, robust against
blunders (`initialise_block`), and the rays of measured points for any camera model
(`ideal_coordinates`). Orchestration over `jaxba._approximations`; it reads no project files.
"""

from ._block import initialise_block as initialise_block
from ._ideal import (
    IdealCoordinates as IdealCoordinates,
    ideal_coordinates as ideal_coordinates,
    image_residuals as image_residuals,
)
from ._result import (
    IMAGE_METHODS as IMAGE_METHODS,
    POINT_METHODS as POINT_METHODS,
    BlockInitialisation as BlockInitialisation,
)
