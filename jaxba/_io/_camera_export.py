"""A calibrated camera of any central model as OpenCV's camera (and COLMAP's): the camera
matrix K and the distortion coefficients fitted over the sensor.

The fit: a grid of pixels over the whole sensor (edges included) is mapped to the rays the
calibrated camera sees there (for each pixel m, the ray (a, b, -1) of the camera frame whose
image point is m, by Newton's method on the camera's own model, so any central model works,
the photogrammetric ones that correct the *measured* point included). OpenCV's normalised
point of that ray is (x', y') = (a, -b). Then fx, fy, cx, cy and the distortion coefficients
are fitted by least squares so that OpenCV's forward model maps (x', y') to the pixels
(skew and thin prism held at 0: `cv2.projectPoints` has neither skew nor, by default, thin
prism). The largest distance between the fitted model's pixels and the grid is reported: the
exported camera agrees with the calibrated one to that many pixels over the sensor.
"""

import dataclasses
import os
import pathlib
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._approximations._common import levenberg_marquardt
from .._models._cameras import (
    CAMERA_MODELS,
    AbstractCamera,
    BalCamera,
    PixelGrid,
    RefractedCamera,
)
from .._models._cameras._names import CAMERA_PARAMETER_NAMES
from ._colmap import ColmapCamera, camera_to_colmap
from ._opencv_yaml import write_opencv_yaml

COEFFICIENTS = {  # OpenCV's number of distortion coefficients -> (jaxba model, fitted terms)
    4: ("opencv", ("k1", "k2", "p1", "p2")),  # COLMAP's OPENCV
    5: ("opencv", ("k1", "k2", "p1", "p2", "k3")),  # OpenCV's default
    8: ("opencv_full", ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),  # rational
}
_NEWTON_STEPS = 30  # per ray; quadratic convergence, the photogrammetric models need one
_RAY_TOL = 1e-9  # largest |image_point(ray) - m| after Newton, relative to the sensor's size
_FIT_TOLERANCE = 1e-12  # levenberg_marquardt's step test
_FIT_ITERATIONS = 200


@dataclasses.dataclass(frozen=True)
class OpenCVExport:
    """A camera as OpenCV's: `values` are the parameters of the jaxba `model` ("opencv" or
    "opencv_full", OpenCV's pixel convention: the centre of the top-left pixel is (0, 0)),
    fitted over a sensor of `image_size` = (width, height) pixels; the fitted model misses
    the calibrated camera by at most `max_misfit_px` (RMS `rms_misfit_px`) over the sensor."""

    model: str
    values: dict[str, float]
    coefficients: int
    image_size: tuple[int, int]
    max_misfit_px: float
    rms_misfit_px: float

    @property
    def camera_matrix(self) -> np.ndarray:
        """K (3, 3): [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels."""
        v = self.values
        return np.array([[v["fx"], 0.0, v["cx"]], [0.0, v["fy"], v["cy"]], [0.0, 0.0, 1.0]])

    @property
    def distortion(self) -> np.ndarray:
        """OpenCV's distCoeffs (`coefficients`,): k1 k2 p1 p2 [k3 [k4 k5 k6]]."""
        return np.array([self.values[name] for name in COEFFICIENTS[self.coefficients][1]])

    def colmap_camera(self, camera_id: int = 1) -> ColmapCamera:
        """The smallest COLMAP camera that holds it (OPENCV, FULL_OPENCV, ...; COLMAP pixels)."""
        model, params = camera_to_colmap(self.model, self.values)
        return ColmapCamera(camera_id, model, *self.image_size, params)

    def colmap_line(self, camera_id: int = 1) -> str:
        """Its line of COLMAP's cameras.txt: CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]."""
        camera = self.colmap_camera(camera_id)
        return " ".join([str(camera.id), camera.model, str(camera.width), str(camera.height),
                         *(repr(float(v)) for v in camera.params)])

    def write_yaml(self, path: str | os.PathLike) -> pathlib.Path:
        """Write it as an OpenCV YAML file (`write_opencv_yaml`)."""
        return write_opencv_yaml(path, self.model, self.values, self.image_size)


def _pixel_grid_points(image_size: tuple[int, int], samples: int) -> np.ndarray:
    """(n, 2) (col, row) on a grid over the sensor, its edges (-0.5 and size - 0.5) included,
    `samples` points along the longer side."""
    width, height = image_size
    step = max(width, height) / (samples - 1)
    cols = np.linspace(-0.5, width - 0.5, max(2, round(width / step) + 1))
    rows = np.linspace(-0.5, height - 0.5, max(2, round(height / step) + 1))
    return np.stack(np.meshgrid(cols, rows), axis=-1).reshape(-1, 2)


@eqx.filter_jit
def _rays(camera: AbstractCamera, points: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Per image point m (n, 2) (the camera's units) the ray (a, b) with image_point((a, b,
    -1), m, 0) = m, by Newton's method from the axis, and |image_point - m| (n,) there."""

    def one(m):
        def misfit(ab):
            return camera.image_point(jnp.stack([ab[0], ab[1], -1.0]), m, 0.0) - m

        def step(ab, _):
            return ab - jnp.linalg.solve(jax.jacfwd(misfit)(ab), misfit(ab)), None

        ab, _ = jax.lax.scan(step, jnp.zeros(2), None, length=_NEWTON_STEPS)
        return ab, jnp.linalg.norm(misfit(ab))

    return jax.vmap(one)(points)


@eqx.filter_jit
def _opencv_pixels(model: type[AbstractCamera], index: jax.Array, theta: jax.Array,
                   rays: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Pixels (2n,) (col, row per ray) of the rays (n, 2) = (a, b) through the camera `model`
    whose parameters `index` are `theta` (the rest 0), and their Jacobian (2n, len(theta))."""
    points = jnp.concatenate([rays, -jnp.ones((rays.shape[0], 1))], axis=1)

    def computed(theta):
        values = jnp.zeros(len(model.parameter_names)).at[index].set(theta)
        camera = model.from_parameters(values)
        return jax.vmap(lambda p: camera.image_point(p, jnp.zeros(2), 0.0))(points).ravel()

    return computed(theta), jax.jacfwd(computed)(theta)


def _fit(rays: np.ndarray, pixels: np.ndarray, coefficients: int,
         start: dict[str, float]) -> tuple[dict[str, float], np.ndarray]:
    """OpenCV's model with `coefficients` distortion terms fitted to map `rays` (n, 2) to
    `pixels` (n, 2), from `start` (missing terms 0): (the model's values, misfits (n,) px)."""
    model_name, terms = COEFFICIENTS[coefficients]
    model = CAMERA_MODELS[model_name]
    names = CAMERA_PARAMETER_NAMES[model_name]
    fitted = ("fx", "fy", "cx", "cy", *terms)
    index = jnp.array([names.index(n) for n in fitted])
    jax_rays = jnp.asarray(rays)

    def residuals(theta):
        computed, jacobian = _opencv_pixels(model, index, jnp.asarray(theta), jax_rays)
        return pixels.ravel() - np.asarray(computed), np.asarray(jacobian)

    fit = levenberg_marquardt(residuals, np.array([start.get(n, 0.0) for n in fitted]),
                              max_iterations=_FIT_ITERATIONS, tolerance=_FIT_TOLERANCE)
    values = dict.fromkeys(names, 0.0) | dict(zip(fitted, map(float, fit.x)))
    return values, np.hypot(*fit.residuals.reshape(-1, 2).T)


def fit_opencv(
    camera: AbstractCamera,
    image_size: Sequence[int],
    pixel_grid: PixelGrid | None = None,
    *,
    coefficients: int = 5,
    samples: int = 41,
) -> OpenCVExport:
    """Fit OpenCV's camera to `camera` over its sensor (module docstring).

    **Arguments:**

    - `camera`: a camera model instance (any central model: "smac", "photomodeler",
      "metrology", "opencv", "fisheye", user models; not "bal", whose image frame is not
      OpenCV's, nor a camera behind a flat port, which is not central).
    - `image_size`: (width, height) of the sensor, pixels.
    - `pixel_grid`: the sensor's `PixelGrid` for a mm model (pixels -> mm); None for a pixel
      model, whose image points are OpenCV's pixels.
    - `coefficients`: OpenCV's number of distortion coefficients: 4 (k1 k2 p1 p2, COLMAP's
      OPENCV), 5 (+ k3, OpenCV's default) or 8 (+ k4 k5 k6, the rational model).
    - `samples`: grid points along the sensor's longer side.

    Raises `ValueError` for a camera it cannot export and where some pixel of the sensor has
    no ray (a distortion that folds the image over).
    """
    if coefficients not in COEFFICIENTS:
        raise ValueError(f"coefficients: expected one of {sorted(COEFFICIENTS)}, got "
                         f"{coefficients!r}")
    if isinstance(camera, BalCamera):
        raise ValueError("a bal camera has no OpenCV export: its image frame is centred with y"
                         " up and its principal point unknown")
    if isinstance(camera, RefractedCamera):
        raise ValueError("a camera behind a flat port is not central: no OpenCV export")
    mm = camera.image_units == "mm"
    if mm and pixel_grid is None:
        raise ValueError(f"a {type(camera).__name__} works in mm: give its pixel_grid")
    width, height = (int(v) for v in image_size)
    pixels = _pixel_grid_points((width, height), samples)
    points = np.asarray(pixel_grid.pixel_to_image(pixels)) if mm else pixels
    rays, missed = (np.asarray(a) for a in _rays(camera, jnp.asarray(points)))
    scale = float(np.max(np.abs(points)))
    if not np.all(np.isfinite(rays)) or not np.all(missed <= _RAY_TOL * scale):
        raise ValueError(f"the {type(camera).__name__}'s distortion has no single ray for some "
                         "pixels of the sensor (it folds the image over): no OpenCV export")

    x, y = rays[:, 0], -rays[:, 1]  # OpenCV's normalised point
    (fx, cx), (fy, cy) = (np.linalg.lstsq(np.c_[t, np.ones_like(t)], p, rcond=None)[0]
                          for t, p in ((x, pixels[:, 0]), (y, pixels[:, 1])))
    start = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
    if coefficients == 8:  # the rational terms nearly repeat k1..k3: start from their fit
        start, _ = _fit(rays, pixels, 5, start)
    values, misfit = _fit(rays, pixels, coefficients, start)
    return OpenCVExport(COEFFICIENTS[coefficients][0], values, coefficients, (width, height),
                        float(misfit.max()), float(np.sqrt(np.mean(misfit**2))))


def export_camera_opencv(project, camera_id: str, parameters=None, *,
                         coefficients: int = 5, samples: int = 41) -> OpenCVExport:
    """Camera `camera_id` of a `Project` with `parameters` (default: its starting values; e.g.
    `adjust_project(project).parameters` for the calibrated ones) as OpenCV's camera
    (`fit_opencv`), over its cameras.toml `sensor` (and `pixel_size` for a mm model)."""
    parameters = project.problem.initial if parameters is None else parameters
    if camera_id not in project.camera_rows:
        raise ValueError(f"{project.spec.name}: no camera {camera_id!r} used by an image")
    spec = project.spec.cameras[camera_id]
    if spec.sensor is None:
        raise ValueError(f"camera {camera_id!r}: no sensor size (columns, rows) in cameras.toml")
    model, row = project.camera_rows[camera_id]
    camera = CAMERA_MODELS[model].from_parameters(
        jnp.asarray(parameters.cameras[model][row]), **spec.constants)
    try:
        return fit_opencv(camera, spec.sensor, project.pixel_grids.get(camera_id),
                          coefficients=coefficients, samples=samples)
    except ValueError as error:
        raise ValueError(f"camera {camera_id!r}: {error}") from None
