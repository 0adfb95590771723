"""Plain-Python description of a project as read from its files (docs/project-files.md).

Nothing here touches jax: the readers fill these records, `_build.py` turns them into a
`BundleProblem`. Angles are kept in decimal degrees, as in the files. A σ entry is
`None` (free / no observation), `0.0` (fixed) or a positive number (weighted).

A missing approximation is explicit: an image whose six EOP columns are `-` has `eop`
None, and a tie point that is measured but absent from the points table is a `PointSpec`
with `xyz` None. `complete_project` (`jaxba._adjust._complete`) computes them;
`build_project` refuses a spec that still misses some.
"""

import dataclasses
import math
import pathlib
import sys
from collections.abc import Sequence

import numpy as np

from .._models._cameras._names import REFRACTION_SEPARATOR


@dataclasses.dataclass(frozen=True)
class InputFile:
    """A file named in the project's `[files]` table: its resolved path and the name used in
    messages (as written there)."""

    path: pathlib.Path
    name: str


@dataclasses.dataclass(frozen=True)
class AdjustmentSettings:
    """The `[adjustment]` table of a project file."""

    sigma0: float = 1.0
    image_sigma: float = 0.002
    max_iterations: int = 50
    variance_components: bool = False
    rtol: float = 1e-8
    atol: float = 1e-8
    # Where the solve stops: "statistical" (the next Gauss-Newton step would move every
    # unknown by less than 1e-5 of its σ) or "cost" (Ceres': an accepted step lowered the
    # cost by at most 1e-6 of it, guarded by the statistical test with 1e-3; what `jaxba
    # import bal` writes).
    stop: str = "statistical"
    refraction: bool = False
    # Refraction needs heights above sea level in km: height_km = (Z + z_offset) * unit_km.
    object_unit_km: float = 0.001
    height_offset: float = 0.0
    # Reliability: Baarda data snooping at significance `snooping_alpha` (two-sided), of
    # the whole set of w-tests (family-wise, Šidák) or, with `snooping_familywise = false`,
    # of each test.
    data_snooping: bool = False
    snooping_alpha: float = 0.05
    snooping_familywise: bool = True
    # Robust loss on image observations: "none", "huber" or "cauchy", scale k in σ.
    robust: str = "none"
    robust_scale: float = 3.0
    # Datum: "control" (fixed/weighted coordinates in the points table), "free" (inner
    # constraints over `datum_points`, default all points; point σ are then ignored) or
    # "dependent" (dependent relative orientation: the six EOPs of `datum_image`, default the
    # first image, fixed, and without distances one station coordinate of the image farthest
    # from it; point and EOP σ are then ignored).
    datum: str = "control"
    datum_points: tuple[str, ...] = ()
    datum_image: str = ""
    # Solver: "dense" (normal equations of all unknowns), "schur" (object points
    # eliminated, covariance in blocks) or "auto" (schur above 2000 unknowns).
    solver: str = "auto"
    # Board warp: the points table is one calibration board in the plane Z = 0 (all points
    # fixed) whose warp kx, ky (`jaxba._models._board_warp`) is estimated; false: flat.
    board_warp: bool = False


@dataclasses.dataclass(frozen=True)
class CameraSpec:
    """One table of cameras.toml."""

    id: str
    model: str
    values: dict[str, float]
    free: frozenset[str]
    sigma: dict[str, float]
    pixel_size: tuple[float, float] | None = None
    sensor: tuple[int, int] | None = None
    # The model's constants (CAMERA_CONSTANT_NAMES), e.g. {"r0": 12.5} for "metrology".
    constants: dict[str, float] = dataclasses.field(default_factory=dict)
    # The ray refraction model of `[ID.refraction]` ("flat_port") or None; its parameters
    # are in `values`, `free` and `sigma` with the camera's.
    refraction: str | None = None
    # Ties (`_ties.py`): parameter -> (camera, parameter) of its source, the chain's first
    # (a tied parameter is its source's unknown); `per_image`: the parameters each image of
    # the camera estimates on its own (the reader expands them into per-image cameras).
    ties: dict[str, tuple[str, str]] = dataclasses.field(default_factory=dict)
    per_image: tuple[str, ...] = ()
    # `[ID.mount]`: the camera on a GNSS/INS platform, its lever arm (X0 Y0 Z0) and
    # boresight (omega phi kappa) as a pose in the body frame; None: no platform.
    mount: "MountSpec | None" = None

    @property
    def model_key(self) -> str:
        """The camera model of the problem's parameter block: `model`, or with a ray
        refraction "<model>+<refraction>" (e.g. "smac+flat_port", `CAMERA_MODELS`)."""
        if self.refraction is None:
            return self.model
        return f"{self.model}{REFRACTION_SEPARATOR}{self.refraction}"


@dataclasses.dataclass(frozen=True)
class ImageSpec:
    """One row of the images table: approximate EOPs (degrees) and GNSS/INS σ; `eop` None
    where the row has `-` in all six EOP columns (no approximation: to be computed)."""

    id: str
    camera: str
    eop: tuple[float, float, float, float, float, float] | None
    eop_sigma: tuple[float | None, ...]
    line: int


@dataclasses.dataclass(frozen=True)
class PointSpec:
    """One row of the points table: approximation or control coordinates and their σ.

    A tie point that is measured but absent from the points table has `xyz` None (no
    approximation: to be computed), σ all None (free), and `line` the line of its first
    measurement in the image-points table.
    """

    id: str
    xyz: tuple[float, float, float] | None
    sigma: tuple[float | None, float | None, float | None]
    line: int


@dataclasses.dataclass(frozen=True)
class ImagePointSpec:
    """One image measurement, in the project's image units."""

    image: str
    point: str
    xy: tuple[float, float]
    sigma: tuple[float, float] | None
    line: int


@dataclasses.dataclass(frozen=True, eq=False)
class ImagePointTable(Sequence):
    """The image points of a project as columns (one row per measurement, in file order); a
    sequence of `ImagePointSpec` records to its readers.

    `image`, `point`: the IDs (n,) as lists of str; `xy` (n, 2) in the project's image units;
    `sigma` (n, 2), NaN where the file gave none (the project's `image_sigma`); `line` (n,)
    the line numbers. The IDs are interned: each is one string object however many times it
    was measured (a batch holds thousands of tables).
    """

    image: list[str]
    point: list[str]
    xy: np.ndarray
    sigma: np.ndarray
    line: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "image", list(map(sys.intern, self.image)))
        object.__setattr__(self, "point", list(map(sys.intern, self.point)))

    def __len__(self) -> int:
        return len(self.image)

    def _record(self, k: int) -> ImagePointSpec:
        sigma = None if math.isnan(self.sigma[k, 0]) else tuple(self.sigma[k].tolist())
        return ImagePointSpec(self.image[k], self.point[k], tuple(self.xy[k].tolist()), sigma,
                              int(self.line[k]))

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self._record(k) for k in range(len(self))[index]]
        return self._record(range(len(self))[index])

    def __eq__(self, other) -> bool:
        if not isinstance(other, Sequence) or len(other) != len(self):
            return False
        return list(self) == list(other)


@dataclasses.dataclass(frozen=True)
class DistanceSpec:
    """A measured distance between two points, object units."""

    a: str
    b: str
    distance: float
    sigma: float
    line: int


MOUNT_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
"""The six values of a rig camera's pose in its rig (`MountSpec.values`), in order."""


@dataclasses.dataclass(frozen=True)
class MountSpec:
    """A rig camera's pose in its rig's frame (rigs.toml `[RIG.CAMERA]`): `values` by name
    (X0, Y0, Z0 object units, omega, phi, kappa degrees; a name left out is None: its
    approximation comes from the images'), the names `free`, and `sigma` the weighted
    ones' σ (degrees for angles)."""

    camera: str
    values: dict[str, float | None]
    free: frozenset[str]
    sigma: dict[str, float]


@dataclasses.dataclass(frozen=True)
class RigSpec:
    """One table of rigs.toml: the rig's `id`, its `reference` camera (whose frame is the
    rig frame) and every other camera's `MountSpec`, in file order."""

    id: str
    reference: str
    mounts: dict[str, MountSpec]

    @property
    def cameras(self) -> tuple[str, ...]:
        return (self.reference, *self.mounts)


@dataclasses.dataclass(frozen=True)
class ProjectSpec:
    """Everything one project file describes, validated."""

    path: pathlib.Path
    name: str
    image_units: str
    settings: AdjustmentSettings
    cameras: dict[str, CameraSpec]
    images: dict[str, ImageSpec]
    points: dict[str, PointSpec]
    image_points: ImagePointTable
    distances: list[DistanceSpec]
    input_files: tuple[pathlib.Path, ...]
    # The `[files]` table: key ("cameras", "images", ...) -> the resolved path, and the
    # names as written there (for messages).
    files: dict[str, pathlib.Path] = dataclasses.field(default_factory=dict)
    file_names: dict[str, str] = dataclasses.field(default_factory=dict)
    # Rigs (rigs.toml) by ID, and the frames table (frames.txt): image ID -> frame ID; an
    # image in no frame is a frame of its own.
    rigs: dict[str, RigSpec] = dataclasses.field(default_factory=dict)
    frames: dict[str, str] = dataclasses.field(default_factory=dict)

    @property
    def missing_images(self) -> list[str]:
        """The images without approximate EOPs (`-` in the images table), in file order."""
        return [image.id for image in self.images.values() if image.eop is None]

    @property
    def missing_points(self) -> list[str]:
        """The measured tie points absent from the points table (no approximation)."""
        return [point.id for point in self.points.values() if point.xyz is None]

    @property
    def complete(self) -> bool:
        """Whether every image and point has an approximation."""
        return not (self.missing_images or self.missing_points)

    @property
    def unused_cameras(self) -> list[str]:
        """The cameras of cameras.toml that no image uses: left out of the adjustment (a
        cameras file shared by several projects lists them; `unused_camera_warning`)."""
        used = {image.camera for image in self.images.values()}
        return [cid for cid in self.cameras if cid not in used]

    def unused_camera_warning(self) -> str | None:
        """One line naming the `unused_cameras` and the files, or None when there are none."""
        unused = self.unused_cameras
        if not unused:
            return None
        cameras = self.file_names.get("cameras", "cameras.toml")
        images = self.file_names.get("images", "the images table")
        named = ", ".join(f"[{cid}]" for cid in unused)
        return (f"{cameras}: camera{'s' * (len(unused) > 1)} {named} used by no image of "
                f"{images}: left out of the adjustment (not adjusted, not reported)")
