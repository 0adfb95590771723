"""The projection-uncertainty files of `jaxba adjust --uncertainty`: per camera
uncertainty_CAMERA.csv (u v sigma_worst sigma_rms cov_uu cov_uv cov_vv, pixels), a heat map
of σ in the worst direction over the sensor (uncertainty_CAMERA.png, the observed points
overlaid) and σ along the ray of the sensor's centre against distance
(uncertainty_distance_CAMERA.png)."""

import dataclasses
import math
import pathlib
from collections.abc import Callable

import jax
import numpy as np

from .._files._atomic import replace_files
from .._files._paths import check_targets
from .._models._cameras import CAMERA_MODELS
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._projection import (
    ProjectionUncertainty,
    camera_frame,
    camera_ref,
    camera_rows,
    projection_uncertainty,
    sensor_grid,
)

COLUMNS = ("u", "v", "sigma_worst", "sigma_rms", "cov_uu", "cov_uv", "cov_vv")


@dataclasses.dataclass(frozen=True)
class CameraUncertainty:
    """One camera's map (`uncertainty` over its sensor's grid), σ along the centre pixel's
    ray (`along_ray` at `distances`), the observed points (pixels) and their distances from
    the camera (object units)."""

    camera_id: str
    sensor: tuple[int, int]
    uncertainty: ProjectionUncertainty
    distances: np.ndarray
    along_ray: ProjectionUncertainty
    observed: np.ndarray
    observed_distances: np.ndarray


def _file_part(camera_id: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in camera_id)


def _observed(project: Project, result: Adjustment, camera_id: str, grid):
    """The camera's observed image points (pixels) and their distances from the station."""
    ref = camera_ref(result, camera_id)
    pixels, distances = [], []
    for k in ref.groups:
        group = result.problem.groups[k]
        rows = np.flatnonzero((np.asarray(group.camera) == ref.row)
                              & np.all(np.asarray(group.mask()), axis=1))
        measured = np.asarray(group.measured)[rows]
        pixels.append(measured if grid is None else np.asarray(grid.image_to_pixel(measured)))
        stations = np.asarray(jax.vmap(
            lambda e, pose=group.pose: camera_frame(pose, e).station())(
                jax.device_put(camera_rows(result.parameters, group, rows))))
        points = np.asarray(result.parameters.points)[np.asarray(group.point)[rows]]
        distances.append(np.linalg.norm(points - stations, axis=1))
    if not pixels:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(pixels), np.concatenate(distances)


def camera_uncertainties(project: Project, result: Adjustment, *, distance: float = math.inf,
                         frame: str = "object") -> tuple[list[CameraUncertainty], list[str]]:
    """The maps of every camera with an image size (`sensor`; a mm model also its pixel
    size), and a note for each camera left out."""
    maps, notes = [], []
    for cid, (model, _) in project.camera_rows.items():
        spec = project.spec.cameras[cid]
        pixel_model = CAMERA_MODELS[model].image_units == "pixel"
        grid = None if pixel_model else project.pixel_grids.get(cid)
        if spec.sensor is None or (grid is None and not pixel_model):
            notes.append(f"camera {cid}: no projection uncertainty without its sensor"
                         " (and pixel_size) in cameras.toml")
            continue
        sensor = tuple(int(v) for v in spec.sensor)
        uncertainty = projection_uncertainty(result, cid, sensor_grid(sensor), distance,
                                             frame=frame, grid=grid)
        observed, observed_distances = _observed(project, result, cid, grid)
        near = observed_distances.min() if observed_distances.size else 1.0
        far = observed_distances.max() if observed_distances.size else 1.0
        distances = np.geomspace(near / 10, far * 100, 60)
        centre = np.array([(sensor[0] - 1) / 2, (sensor[1] - 1) / 2])
        along = projection_uncertainty(result, cid, np.tile(centre, (distances.size, 1)),
                                       distances, frame=frame, grid=grid)
        maps.append(CameraUncertainty(cid, sensor, uncertainty, distances, along, observed,
                                      observed_distances))
    return maps, notes


def uncertainty_csv(uncertainty: ProjectionUncertainty) -> str:
    """The CSV text of one camera's map (`COLUMNS`, pixels and pixels²)."""
    c = uncertainty.covariance
    table = np.column_stack([uncertainty.pixels, uncertainty.sigma_worst, uncertainty.sigma_rms,
                             c[:, 0, 0], c[:, 0, 1], c[:, 1, 1]])
    lines = [",".join(COLUMNS)] + [",".join(f"{v:.10g}" for v in row) for row in table]
    return "\n".join(lines) + "\n"


def uncertainty_files(maps: list[CameraUncertainty], out_dir, *, frame: str,
                      distance: float) -> dict[pathlib.Path, str | bytes]:
    """{path: content} of the CSV and both figures of every camera in `maps`."""
    from ._html import png_bytes
    from ._plots._uncertainty import plot_sensor_map, plot_sigma_along_ray

    out_dir, files = pathlib.Path(out_dir), {}
    where = "at infinity" if math.isinf(distance) else f"at distance {distance:g}"
    for m in maps:
        name = _file_part(m.camera_id)
        files[out_dir / f"uncertainty_{name}.csv"] = uncertainty_csv(m.uncertainty)
        files[out_dir / f"uncertainty_{name}.png"] = png_bytes(plot_sensor_map(
            m.uncertainty.pixels, m.uncertainty.sigma_worst, m.sensor, observed=m.observed,
            title=f"camera {m.camera_id}: projection σ (worst direction) {where},"
                  f" {frame} frame", label="σ worst (px)"))
        files[out_dir / f"uncertainty_distance_{name}.png"] = png_bytes(plot_sigma_along_ray(
            m.distances, m.along_ray.sigma_worst, m.along_ray.sigma_rms,
            observed=m.observed_distances,
            title=f"camera {m.camera_id}: σ along the centre pixel's ray, {frame} frame"))
    return files


def write_uncertainty(project: Project, result: Adjustment, out_dir, *, distance: float,
                      frame: str, warn: Callable[[str], None]) -> dict[pathlib.Path, str | bytes]:
    """uncertainty_CAMERA.csv and its figures of every camera with a sensor in `out_dir`
    (`camera_uncertainties`, `uncertainty_files`), never over an input file, replaced
    together; `warn` hears why a camera is left out. Returns the files by path."""
    maps, notes = camera_uncertainties(project, result, distance=distance, frame=frame)
    for note in notes:
        warn(note)
    files = uncertainty_files(maps, out_dir, frame=frame, distance=distance)
    check_targets(files, project.spec.input_files, f"project {project.spec.name!r}")
    replace_files(files)
    return files
