"""Compute a project's missing approximations: `complete_project`.

A project may leave approximations out (`ProjectSpec`): `-` in an image's six EOP columns, or a
tie point measured but absent from the points table. `complete_project` turns the spec into
the plain arrays of `initialise_block` (the image points in each camera model's units, one
camera instance per camera of cameras.toml, the given EOPs in radians, every given point
coordinate, the distances), runs it and fills in what was missing; given values are never
changed. Every value the files give, control and approximation alike, places the computed
ones in the files' frame: a computed point must agree with the given ones around it.

Images that cannot be initialised are refused with the reason (`ProjectError`): the user
decides whether to drop them. Points that cannot be intersected from the initialised images
(rays under `min_angle`, or rays that an approximate camera bends too far to meet) are
*deferred*: left out of the completed spec with their image points, and intersected again from
the adjusted block (`adjust_deferred`). Image points the initialisation flags as blunders
are suspects only: they are reported, not removed.
"""

import collections
import dataclasses
import math
import re

import jax.numpy as jnp
import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._project._build import measurements, pixel_grid, used_points
from .._project._errors import ProjectError
from .._project._spec import ProjectSpec
from ._initialise import BlockInitialisation, initialise_block

LISTED = 10
"""The most images, points or suspects a message names."""
_ANGLES = slice(3, 6)


@dataclasses.dataclass(frozen=True)
class Suspect:
    """An image point flagged as a blunder by the initialisation: its IDs, its line in the
    image-points table and its residual at the approximations in robust σ of its camera, the
    field of an approximate camera taken out (`BlockInitialisation.judged`)."""

    image: str
    point: str
    line: int
    sigmas: float


@dataclasses.dataclass(frozen=True)
class Completion:
    """What `complete_project` did.

    `spec`: the completed project; `initialisation`: the `BlockInitialisation` (its rows are
    `image_ids` and `point_ids`: every image, and the points used by image points or
    distances); `computed_images`, `computed_points`: the IDs whose approximations were
    computed; `image_methods`, `point_methods`: per ID how it was found ("given" for the
    files' values, else `jaxba.IMAGE_METHODS` / `jaxba.POINT_METHODS`); `log`: the
    initialisation's log with IDs for indices; `suspects`: the flagged image points;
    `deferred`: point ID -> why it could not be intersected yet (left out of `spec` with
    its image points and distances); `pending`: `spec` with the deferred points still in,
    without approximations (what `adjust_deferred` completes).
    """

    spec: ProjectSpec
    initialisation: BlockInitialisation
    image_ids: tuple[str, ...]
    point_ids: tuple[str, ...]
    computed_images: tuple[str, ...]
    computed_points: tuple[str, ...]
    image_methods: dict[str, str]
    point_methods: dict[str, str]
    log: tuple[str, ...]
    suspects: tuple[Suspect, ...]
    deferred: dict[str, str] = dataclasses.field(default_factory=dict)
    pending: ProjectSpec | None = None

    def summary(self) -> dict:
        """The `initialisation` section of results.json (plain Python, JSON-ready)."""
        return {
            "computed_images": list(self.computed_images),
            "computed_points": [p for p in self.computed_points if p not in self.deferred],
            "deferred_points": dict(self.deferred),
            "image_methods": dict(collections.Counter(self.image_methods.values())),
            "point_methods": dict(collections.Counter(self.point_methods.values())),
            "frame": self.initialisation.frame,
            "log": list(self.log),
            "suspects": [
                {"image": s.image, "point": s.point, "line": s.line,
                 "sigmas": round(s.sigmas, 2) if math.isfinite(s.sigmas) else None}
                for s in self.suspects
            ],
        }

    def console_lines(self) -> list[str]:
        """The log without its lines per image pair and per oriented image (failures kept),
        and a line on the deferred points."""
        lines = [line for line in self.log if not _detail(line)
                 and not (self.deferred and line.startswith("not initialised: points"))]
        deferred = self.deferred_line()
        return lines + [deferred] if deferred else lines

    def deferred_line(self) -> str | None:
        """One line naming the first deferred points and why, or None when there are none."""
        if not self.deferred:
            return None
        kinds = collections.Counter(_kind(reason) for reason in self.deferred.values())
        named = "; ".join(f"{pid!r}: {reason}" for pid, reason in
                          list(self.deferred.items())[:LISTED])
        return (f"deferred {len(self.deferred)} point{'s' * (len(self.deferred) != 1)} until"
                " the block is adjusted (" + ", ".join(f"{n} {kind}" for kind, n in
                                                       kinds.items()) + f"): {named}"
                + _more(list(self.deferred)))

    def suspect_line(self) -> str | None:
        """One warning naming the first suspects, or None when there are none."""
        if not self.suspects:
            return None
        named = ", ".join(f"point {s.point} in {s.image} (line {s.line})"
                          for s in self.suspects[:LISTED])
        more = f" and {len(self.suspects) - LISTED} more" if len(self.suspects) > LISTED else ""
        file = self.spec.file_names.get("image_points", "the image points")
        return (f"{len(self.suspects)} image points of {file} are far from the computed"
                f" approximations (suspect blunders, kept; judge them by the adjustment's"
                f" residuals): {named}{more}")


def _kind(reason: str) -> str:
    """A deferred point's reason in a few words."""
    if "do not meet" in reason:
        return "whose rays do not meet"
    if "meet at" in reason:
        return "whose rays meet at a small angle"
    return "other"


def _detail(line: str) -> bool:
    """A log line about one image pair or one oriented image (not a failure)."""
    if "fail" in line or " no " in line:
        return False
    return line.startswith("pair ") or bool(
        re.match(r"image \S+: (resection on|relative orientation to)", line))


def complete_project(spec: ProjectSpec, *, seed: int = 0) -> tuple[ProjectSpec, Completion]:
    """Compute the approximations `spec` misses (module docstring) with `initialise_block`.

    Returns the completed spec (the given values untouched; computed EOPs in degrees, as
    the files; the deferred points left out, `Completion.deferred`) and the `Completion`.
    A spec that misses nothing is returned as it is, with a `Completion` of nothing
    computed. Needs jax in float64.

    Raises `ProjectError` naming the images (and points seen by fewer than 2 initialised
    images) that could not be initialised and why, or when the given values cannot place
    the computed ones in their frame.
    """
    image_ids = list(spec.images)
    point_ids = used_points(spec)
    if spec.complete:
        nothing = _nothing(len(image_ids), len(point_ids))
        return spec, Completion(
            spec, nothing, tuple(image_ids), tuple(point_ids), (), (),
            dict.fromkeys(image_ids, "given"), dict.fromkeys(point_ids, "given"), (), ())
    observations = block_observations(spec, image_ids, point_ids)
    result = initialise_block(
        observations, _cameras(spec, image_ids),
        eops=_given_eops(spec, image_ids), control=_given_points(spec, point_ids),
        distances=block_distances(spec, point_ids), n_points=len(point_ids), seed=seed,
        camera_names=[spec.images[iid].camera for iid in image_ids])
    log = tuple(named(line, image_ids, point_ids) for line in result.log)
    # A point on 2 or more initialised images that could not be intersected waits for the
    # adjusted block.
    image, point = observations[:, 0].astype(int), observations[:, 1].astype(int)
    rays = np.bincount(point[result.initialised_images[image]], minlength=len(point_ids))
    deferred = {point_ids[k]: named(reason, image_ids, point_ids)
                for k, reason in result.failed_points.items()
                if rays[k] >= 2 and spec.points[point_ids[k]].xyz is None}
    _check(spec, result, image_ids, point_ids, deferred)

    image_row = {iid: k for k, iid in enumerate(image_ids)}
    point_row = {pid: k for k, pid in enumerate(point_ids)}
    images = dict(spec.images)
    for iid in spec.missing_images:
        eop = result.eops[image_row[iid]].copy()
        eop[_ANGLES] = np.degrees(eop[_ANGLES])
        images[iid] = dataclasses.replace(images[iid], eop=tuple(eop.tolist()))
    points = dict(spec.points)
    for pid in spec.missing_points:
        if pid not in deferred:
            points[pid] = dataclasses.replace(points[pid],
                                              xyz=tuple(result.points[point_row[pid]].tolist()))
    pending = dataclasses.replace(spec, images=images, points=points)
    completed = without_points(pending, deferred)
    image_methods = {iid: "given" if spec.images[iid].eop is not None
                     else result.image_method[k] for k, iid in enumerate(image_ids)}
    point_methods = {pid: "given" if spec.points[pid].xyz is not None
                     else result.point_method[k] for k, pid in enumerate(point_ids)
                     if pid not in deferred}
    return completed, Completion(
        completed, result, tuple(image_ids), tuple(point_ids), tuple(spec.missing_images),
        tuple(spec.missing_points), image_methods, point_methods, log,
        _suspects(spec, result, image_ids), deferred, pending if deferred else None)


def without_points(spec: ProjectSpec, ids) -> ProjectSpec:
    """`spec` without the points `ids`, their image points and the distances that use them."""
    if not ids:
        return spec
    ids = set(ids)
    table = spec.image_points
    keep = np.array([pid not in ids for pid in table.point], dtype=bool)
    rows = np.flatnonzero(keep)
    image_points = type(table)(
        image=[table.image[k] for k in rows], point=[table.point[k] for k in rows],
        xy=table.xy[keep], sigma=table.sigma[keep], line=table.line[keep])
    return dataclasses.replace(
        spec, points={pid: p for pid, p in spec.points.items() if pid not in ids},
        image_points=image_points,
        distances=[d for d in spec.distances if d.a not in ids and d.b not in ids])


def _nothing(n_images: int, n_points: int) -> BlockInitialisation:
    """The `BlockInitialisation` of a run that computed nothing."""
    return BlockInitialisation(
        eops=np.full((n_images, 6), np.nan), points=np.full((n_points, 3), np.nan),
        image_method=(None,) * n_images, point_method=(None,) * n_points, frame="control",
        similarity=None, blunders=np.zeros(0, dtype=bool), unusable=np.zeros(0, dtype=bool),
        residuals=np.zeros((0, 2)), judged=np.zeros(0), sigma=np.full(n_images, np.nan),
        failed_images={}, failed_points={}, log=())


# --- the arrays of initialise_block ---------------------------------------------------------


def block_observations(spec: ProjectSpec, image_ids, point_ids) -> np.ndarray:
    """(n, 4) image index, point index, x, y in the camera model's units; the table's rows."""
    table = spec.image_points
    image_row = {iid: k for k, iid in enumerate(image_ids)}
    point_row = {pid: k for k, pid in enumerate(point_ids)}
    observations = np.empty((len(table), 4))
    observations[:, 0] = [image_row[iid] for iid in table.image]
    observations[:, 1] = [point_row[pid] for pid in table.point]
    camera_of = np.array([spec.images[iid].camera for iid in table.image], dtype=object)
    for camera_id in dict.fromkeys(camera_of.tolist()):
        rows = np.flatnonzero(camera_of == camera_id)
        grid = pixel_grid(spec.cameras[camera_id])
        observations[rows, 2:], _ = measurements(spec, camera_id, rows, grid)
    return observations


def _cameras(spec: ProjectSpec, image_ids) -> list:
    """Per image its camera's model instance at the values of cameras.toml (shared by the
    images of one camera)."""
    instances = {}
    for camera_id in dict.fromkeys(spec.images[iid].camera for iid in image_ids):
        camera = spec.cameras[camera_id]
        model = CAMERA_MODELS[camera.model]
        values = jnp.asarray([camera.values.get(n, 0.0) for n in model.parameter_names],
                             dtype=float)
        instances[camera_id] = model.from_parameters(values, **camera.constants)
    return [instances[spec.images[iid].camera] for iid in image_ids]


def _given_eops(spec: ProjectSpec, image_ids) -> np.ndarray:
    """(n_images, 6) the files' EOPs, angles in radians; NaN rows where missing."""
    eops = np.full((len(image_ids), 6), np.nan)
    for k, iid in enumerate(image_ids):
        if spec.images[iid].eop is not None:
            eops[k] = spec.images[iid].eop
    eops[:, _ANGLES] = np.radians(eops[:, _ANGLES])
    return eops


def _given_points(spec: ProjectSpec, point_ids) -> np.ndarray:
    """(n_points, 3) every coordinate the points table gives (control and approximations:
    the computed points must fit them); NaN rows for the tie points without one."""
    xyz = np.full((len(point_ids), 3), np.nan)
    for k, pid in enumerate(point_ids):
        if spec.points[pid].xyz is not None:
            xyz[k] = spec.points[pid].xyz
    return xyz


def block_distances(spec: ProjectSpec, point_ids) -> np.ndarray | None:
    """(m, 3) point index a, point index b, length of the distances; None without any."""
    if not spec.distances:
        return None
    point_row = {pid: k for k, pid in enumerate(point_ids)}
    return np.array([[point_row[d.a], point_row[d.b], d.distance] for d in spec.distances],
                    dtype=float)


# --- the outcome ----------------------------------------------------------------------------


def named(text: str, image_ids, point_ids) -> str:
    """The initialisation's text with image and point IDs for its indices (an index out of
    range is left as it is)."""
    def name(names, index: str) -> str:
        return names[int(index)] if int(index) < len(names) else index

    def ids(names, listed: str) -> str:
        return ", ".join(name(names, k) for k in re.findall(r"\d+", listed))

    text = re.sub(r"\bimages \[([\d, ]*)\]",
                  lambda m: "images " + ids(image_ids, m.group(1)), text)
    text = re.sub(r"\bpoints \[([\d, ]*)\]",
                  lambda m: "points " + ids(point_ids, m.group(1)), text)
    text = re.sub(r"\bpair (\d+)-(\d+)", lambda m: (
        f"pair {name(image_ids, m.group(1))}-{name(image_ids, m.group(2))}"), text)
    text = re.sub(r"\bimage (\d+)\b", lambda m: f"image {name(image_ids, m.group(1))}", text)
    return re.sub(r"\bpoint (\d+)\b", lambda m: f"point {name(point_ids, m.group(1))}", text)


def _check(spec: ProjectSpec, result: BlockInitialisation, image_ids, point_ids,
           deferred) -> None:
    """Refuse missing approximations that were not computed nor `deferred` (naming them and
    why), and computed ones that are not in the frame of the given values."""
    names = spec.file_names
    problems = []
    kinds = (
        ("image", image_ids, spec.images, "eop", result.failed_images, names.get("images")),
        ("point", point_ids, spec.points, "xyz", result.failed_points,
         names.get("image_points")),
    )
    for kind, ids, rows, value, reasons, file in kinds:
        failed = [(k, i) for k, i in enumerate(ids)
                  if getattr(rows[i], value) is None and k in reasons and i not in deferred]
        if failed:
            problems.append(f"{len(failed)} {kind}{'s' * (len(failed) != 1)}: " + "; ".join(
                f"{i!r} ({file}:{rows[i].line}): {named(reasons[k], image_ids, point_ids)}"
                for k, i in failed[:LISTED]) + _more(failed))
    if problems:
        raise ProjectError(
            "cannot compute the approximations of " + "; and of ".join(problems)
            + ". Give their approximations in the tables, or remove them (and their image"
            " points)")
    given = sum(spec.points[pid].xyz is not None for pid in point_ids)
    given += sum(image.eop is not None for image in spec.images.values())
    if result.frame == "model" and given:
        raise ProjectError(
            f"cannot place the computed approximations in the frame of the {given} given"
            " images and points: that takes 3 points with all coordinates in"
            f" {names.get('points')}, 7 coordinates (6 with distances), or an image with its"
            " EOPs"
            " (the initialisation's log: " + "; ".join(
                named(line, image_ids, point_ids) for line in result.log
                if line.startswith("frame")) + ")")


def _more(listed) -> str:
    return f"; and {len(listed) - LISTED} more" if len(listed) > LISTED else ""


def _suspects(spec: ProjectSpec, result: BlockInitialisation, image_ids) -> tuple:
    """The image points flagged as blunders, the largest residual first."""
    table = spec.image_points
    suspects = []
    for k in np.flatnonzero(result.blunders):
        sigmas = float(result.judged[k]) if np.isfinite(result.judged[k]) else math.inf
        suspects.append(Suspect(table.image[k], table.point[k], int(table.line[k]), sigmas))
    return tuple(sorted(suspects, key=lambda s: -s.sigmas))  # the largest first
