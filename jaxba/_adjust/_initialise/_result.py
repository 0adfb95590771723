"""The result of a block initialisation: `BlockInitialisation`."""

import dataclasses

import numpy as np

from ..._approximations import Similarity

IMAGE_METHODS = ("given", "control resection", "relative orientation", "resection")
POINT_METHODS = ("control", "intersection")


@dataclasses.dataclass(frozen=True)
class BlockInitialisation:
    """The result of `initialise_block`.

    - `eops` (n_images, 6): X0, Y0, Z0 (object units), omega, phi, kappa (radians), jaxba's
      images rows; NaN rows for images that could not be initialised;
    - `points` (n_points, 3): X, Y, Z (object units); NaN rows for points not determined;
    - `image_method`, `point_method`: per image / point how it was found (IMAGE_METHODS:
      "given", "control resection", "relative orientation", "resection"; POINT_METHODS:
      "control", "intersection"), None where not initialised;
    - `frame`: "control" (the control points' and given EOPs' object frame), or "model"
      (no control or EOPs to define it: the first image of the initial pair at the origin
      with M = I, the base to the second image of length 1, or scaled by the distances);
    - `similarity`: the `Similarity` (model -> object frame) applied, or None;
    - `blunders` (n_observations,): image points flagged as blunders (reprojection error over
      `blunder_threshold` robust σ); `unusable` (n_observations,): image points that were not
      used at all (duplicate, non-finite, image index unknown, no ray: see the log);
    - `residuals` (n_observations, 2): v = measured - computed in the camera's image units
      at the initialised EOPs and points (NaN where one of them is missing);
    - `judged` (n_observations,): what the blunders are judged by, in σ: |v| less the field
      an approximate camera leaves, scaled for the point's rays (`_blunders`); NaN where v is;
    - `sigma` (n_images,): the robust σ of an image coordinate of each image's camera
      (image units) that the blunders are judged by;
    - `failed_images`, `failed_points`: index -> why it could not be initialised;
    - `log`: what was done, one step a line.
    """

    eops: np.ndarray
    points: np.ndarray
    image_method: tuple[str | None, ...]
    point_method: tuple[str | None, ...]
    frame: str
    similarity: Similarity | None
    blunders: np.ndarray
    unusable: np.ndarray
    residuals: np.ndarray
    judged: np.ndarray
    sigma: np.ndarray
    failed_images: dict[int, str]
    failed_points: dict[int, str]
    log: tuple[str, ...]

    @property
    def initialised_images(self) -> np.ndarray:
        """(n_images,) bool: images with EOPs."""
        return np.all(np.isfinite(self.eops), axis=1)

    @property
    def initialised_points(self) -> np.ndarray:
        """(n_points,) bool: points with coordinates."""
        return np.all(np.isfinite(self.points), axis=1)
