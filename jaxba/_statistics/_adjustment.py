"""The outcome of an adjustment: parameters, statistics, residuals and how the solve went."""

import dataclasses
import functools

import jax
import numpy as np

from .._problem._bundle import BundleProblem
from .._problem._parameters import Parameters
from .._solvers._progress import Iteration
from .._timing import Timings
from ._by_id import ById, UnknownTables, observation_table
from ._covariance import Precision
from ._ids import Ids, index_ids
from ._summary import brief_report


@dataclasses.dataclass(frozen=True)
class Adjustment:
    """The outcome of `adjust`.

    - `parameters`: adjusted unknowns (fixed ones at their given values);
    - `precision`: σ̂0², redundancy, covariance and σ of every unknown;
    - `residuals`: per observation group, v = observed - computed in the observation's
      units (masked entries 0), same shapes as the group's residuals;
    - `iterations`: every accepted iterate with its cost ½Σe² and σ̂0² (re-adjustments
      for variance components or data snooping continue the numbering; a batched solve
      keeps the first and the last), `n_iterations` the last one's number;
    - `converged`, `message`, `steps` (solver steps, rejected ones included);
    - `backend`: the normal-equation backend that solved, "dense" or "schur";
    - `timings`: wall seconds per phase ("datum check", "solve", "statistics", ...) with
      the compilations inside each (`jaxba._timing.Timings`);
    - `sigma0_prior`: the a priori σ0 the adjustment used;
    - `ids`: the IDs of the blocks' rows (`Ids`, from the labels `adjust` was given), None
      for row numbers;
    - `no_sigma`: {`flatten` position: why} of the free unknowns without a σ at a converged
      solution where N is singular (`jaxba._statistics._no_sigma`); every other unknown
      has its σ;
    - filled in by `adjust_project` as the project asks: `reliability` (a `Reliability`),
      `variance_components` ({group: VarianceComponent}) with `variance_iterations`, and
      `rejections` (data snooping, in order of removal).

    By ID: `cameras`, `images`, `points` (mappings of `Estimates` and `PointEstimate`),
    `observations` (the image points as a table) and `summary()` (a short text). Arrays are
    NumPy (`parameters` too, whatever the backend).
    """

    problem: BundleProblem
    parameters: Parameters
    precision: Precision
    residuals: tuple[np.ndarray, ...]
    iterations: list[Iteration]
    converged: bool
    message: str
    steps: int
    backend: str = "dense"
    timings: Timings = dataclasses.field(default_factory=Timings)
    reliability: "Reliability | None" = None  # noqa: F821  (defined in _reliability)
    variance_components: dict | None = None
    variance_iterations: int = 0
    rejections: tuple = ()
    sigma0_prior: float = 1.0
    ids: Ids | None = None
    no_sigma: dict[int, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        # The solvers return jax arrays, a batch NumPy: NumPy on every path.
        if not all(isinstance(leaf, np.ndarray) for leaf in jax.tree.leaves(self.parameters)):
            object.__setattr__(self, "parameters", jax.device_get(self.parameters))

    @property
    def sigma0(self) -> float:
        """A posteriori σ̂0."""
        return float(np.sqrt(self.precision.sigma0_squared))

    @property
    def n_iterations(self) -> int:
        """Accepted iterations after the approximations: the last one's number (a batched
        solve keeps only the first and the last iterate, numbered as it counted them)."""
        return self.iterations[-1].iteration if self.iterations else 0

    @functools.cached_property
    def _unknowns(self) -> UnknownTables:
        return UnknownTables(self, self._ids)

    @property
    def _ids(self) -> Ids:
        return self.ids if self.ids is not None else index_ids(self.parameters)

    @property
    def cameras(self) -> ById:
        """Camera ID -> `Estimates`: its parameters by name (`result.cameras["C1"]["c"]`)."""
        return self._unknowns.cameras()

    @property
    def images(self) -> ById:
        """Image ID -> `Estimates`: its pose parameters by name (X0 .. kappa, radians)."""
        return self._unknowns.images()

    @property
    def mounts(self) -> ById:
        """Mount ID -> `Estimates`: a rig camera's pose in its rig's frame (X0 .. kappa,
        radians); empty without rigs. `images` are then the rigs' frames."""
        return self._unknowns.mounts()

    @property
    def boards(self) -> ById:
        """Board ID -> `Estimates`: a warped board's kx, ky (object units, `board_warp`);
        empty without a warp."""
        return self._unknowns.boards()

    @property
    def points(self) -> ById:
        """Point ID -> `PointEstimate`: X, Y, Z with σ, the 3 x 3 covariance and its kind."""
        return self._unknowns.points()

    @property
    def observations(self):
        """The image points as a table (`observation_columns`): a pandas DataFrame where
        pandas is installed, else a dict of NumPy columns."""
        return observation_table(self, self._ids)

    def projection_uncertainty(self, camera, pixels, distance=float("inf"), *,
                               frame: str = "object", grid=None):
        """Σ_q (n, 2, 2) of the image points `pixels` (n, 2) of camera `camera` (its ID) at
        `distance` (object units, inf for a direction), the ray fixed in the world the
        camera saw (`frame="object"`) or in the camera frame (`"camera"`, intrinsics only):
        a `ProjectionUncertainty` with `sigma_worst` and `sigma_rms`. `pixels` in the
        model's image units, or pixels with a mm model's `grid` (`PixelGrid`)
        (`jaxba._statistics._projection`)."""
        from ._projection import projection_uncertainty  # it imports this module

        return projection_uncertainty(self, camera, pixels, distance, frame=frame, grid=grid)

    def summary(self) -> str:
        """A few lines: convergence, σ̂0 and its χ² test, redundancy, datum, backend,
        outliers, timings, then every camera's estimated parameters with σ
        (`jaxba._statistics._summary`)."""
        return brief_report(self, self._ids)
