"""Turn a validated ProjectSpec into a BundleProblem, keeping the IDs for the reports.

The arrays are built in NumPy and put on the device together, in one transfer per project.
"""

import dataclasses
import math

import jax
import numpy as np

from .._models._board_warp import board_extent, warp_shape
from .._models._cameras import CAMERA_MODELS, AtmosphericRefraction, NoRefraction, PixelGrid
from .._models._robust import RobustLoss
from .._problem._bundle import BundleProblem
from .._problem._observations import Distances, ImagePoints, ParameterObservations
from .._problem._parameters import Parameters, parameter_labels, positions_of
from .._statistics._free_network import inner_constraints
from ._errors import ProjectError
from ._frames import RigLayout, rig_layout
from ._spec import ProjectSpec

_ANGLE_COLUMNS = slice(3, 6)


@dataclasses.dataclass(frozen=True)
class Project:
    """A project ready to adjust: the problem plus what maps its rows back to IDs.

    `camera_rows[camera_id] = (model, row)`; `image_ids` every image of the images table
    (the row order of the image block, unless there are rigs: `frame_ids`), `point_ids` the
    row order of the point block; `labels` names every scalar unknown;
    `initialisation`: what `complete_project` computed (`Completion.summary()`, the
    `initialisation` section of results.json), None when the files held every approximation.
    `datum`: how the datum is defined (`datum_summary`; the `datum` section of the reports).
    `rigs`: the frames and mounts (`RigLayout`) of a project with rigs, None without: the
    image block's rows are then `rigs.frame_ids`, not `image_ids` (`frame_ids`).
    `board_ids`: the rows of the warp block (`Parameters.warp`; `BOARD_ID`), () without.
    """

    spec: ProjectSpec
    problem: BundleProblem
    camera_rows: dict[str, tuple[str, int]]
    image_ids: list[str]
    point_ids: list[str]
    pixel_grids: dict[str, PixelGrid | None]
    labels: list[str]
    initialisation: dict | None = None
    datum: dict = dataclasses.field(default_factory=lambda: {"kind": "control"})
    rigs: RigLayout | None = None
    board_ids: tuple[str, ...] = ()

    @property
    def frame_ids(self) -> list[str]:
        """The IDs of the image block's rows: the frames with rigs, else the images."""
        return self.image_ids if self.rigs is None else self.rigs.frame_ids


def _sigma_to_free_and_observed(sigma) -> tuple[bool, float]:
    """File σ (None free, 0 fixed, > 0 weighted) -> (estimated?, σ of a prior or inf)."""
    if sigma is None:
        return True, math.inf
    if sigma == 0:
        return False, math.inf
    return True, float(sigma)


def _cameras(spec: ProjectSpec):
    """IOP blocks per camera model, cameras used by no image left out."""
    rows, values, free, prior_sigma = {}, {}, {}, {}
    used = {image.camera for image in spec.images.values()}
    for camera in (c for c in spec.cameras.values() if c.id in used):
        model = camera.model_key  # with a ray refraction, its parameters follow the camera's
        names = CAMERA_MODELS[model].parameter_names
        rows[camera.id] = (model, len(values.setdefault(model, [])))
        values[model].append([camera.values.get(n, 0.0) for n in names])
        free.setdefault(model, []).append([n in camera.free or n in camera.sigma for n in names])
        prior_sigma.setdefault(model, []).append([camera.sigma.get(n, math.inf) for n in names])
    priors = [
        ParameterObservations(
            name="camera_priors" if len(values) == 1 else f"camera_priors:{model}",
            block=f"cameras/{model}",
            rows=np.arange(len(values[model])),
            observed=np.asarray(values[model], dtype=float),
            stddev=np.asarray(prior_sigma[model], dtype=float),
        )
        for model in values
        if np.isfinite(prior_sigma[model]).any()
    ]
    as_arrays = {m: np.asarray(v, dtype=float) for m, v in values.items()}
    return rows, as_arrays, {m: np.asarray(f) for m, f in free.items()}, priors


def _ties(spec: ProjectSpec, camera_rows: dict, iop: dict) -> tuple[tuple[int, int], ...]:
    """The cameras' ties (`CameraSpec.ties`, resolved by the reader) as `flatten` positions
    of the IOP blocks `iop` (cameras by sorted model name, row-major): `BundleProblem.ties`."""
    offsets, start = {}, 0
    for model in sorted(iop):
        offsets[model] = start
        start += int(np.size(iop[model]))

    def position(camera_id: str, name: str) -> int:
        model, row = camera_rows[camera_id]
        names = CAMERA_MODELS[model].parameter_names
        return offsets[model] + row * len(names) + names.index(name)

    return tuple((position(cid, name), position(*source))
                 for cid in camera_rows for name, source in spec.cameras[cid].ties.items())


def _images(spec: ProjectSpec):
    """EOP block (radians), free mask and GNSS/INS σ (radians; inf: none); a dependent datum
    frees every EOP (`_dependent_datum` then fixes its own)."""
    eop, free, sigma = [], [], []
    ignore_sigma = spec.settings.datum == "dependent"
    for image in spec.images.values():
        values = np.asarray(image.eop, dtype=float)
        values[_ANGLE_COLUMNS] = np.radians(values[_ANGLE_COLUMNS])
        flags = [_sigma_to_free_and_observed(None if ignore_sigma else s)
                 for s in image.eop_sigma]
        observed_sigma = np.array([s for _, s in flags])
        observed_sigma[_ANGLE_COLUMNS] = np.radians(observed_sigma[_ANGLE_COLUMNS])
        eop.append(values)
        free.append([f for f, _ in flags])
        sigma.append(observed_sigma)
    return np.asarray(eop).reshape(-1, 6), np.asarray(free), np.asarray(sigma).reshape(-1, 6)


def _weighted_rows(name: str, block: str, values: np.ndarray, sigma: np.ndarray) -> list:
    """The rows of a block with any finite σ as one `ParameterObservations` group (a list of
    it, empty where no row is weighted); `values`, `sigma`: (n_rows, width)."""
    rows = np.flatnonzero(np.isfinite(sigma).any(axis=1))
    if rows.size == 0:
        return []
    return [ParameterObservations(
        name=name, block=block, rows=rows, observed=values[rows],
        stddev=sigma[rows])]


def used_points(spec: ProjectSpec) -> list[str]:
    used = set(spec.image_points.point)
    used.update(p for d in spec.distances for p in (d.a, d.b))
    return [pid for pid in spec.points if pid in used]


def _points(spec: ProjectSpec, point_ids: list[str]):
    """Point block, free mask and control observations; a free network frees them all."""
    rows = [spec.points[pid] for pid in point_ids]
    xyz = np.array([point.xyz for point in rows], dtype=float).reshape(-1, 3)
    if spec.settings.datum in ("free", "dependent"):  # the datum frees them all
        given = np.full(xyz.shape, np.nan)
    else:  # the file's σ: None (NaN here) free, 0 fixed, > 0 weighted
        given = np.array([point.sigma for point in rows], dtype=float).reshape(-1, 3)
    free = ~(given == 0)
    sigma = np.where(given > 0, given, np.inf)
    groups = _weighted_rows("control", "points", xyz, sigma)
    return xyz, free, groups


BOARD_ID = "board"  # the one board of a project's points table


def _board_warp(spec: ProjectSpec, point_ids: list[str], xyz: np.ndarray,
                xyz_free: np.ndarray) -> np.ndarray | None:
    """(n_points, 2) (1 - x², 1 - y²) of every point of the point block (`warp_shape`), x
    and y normalised over the extent of the whole points table (the board's, also where
    some of its points are never measured); None without `board_warp`. The board's points
    must be fixed and lie in one plane Z = const."""
    if not spec.settings.board_warp:
        return None
    where = f"{spec.path.name}: [adjustment] board_warp"
    if spec.settings.datum != "control":
        raise ProjectError(f"{where} needs datum = \"control\": the board's points fixed")
    free = np.flatnonzero(np.any(xyz_free, axis=1))
    if free.size:
        raise ProjectError(f"{where}: point {point_ids[free[0]]!r} is not fixed (σ 0): a "
                           "warped board's points are its fixed design coordinates")
    table = np.array([p.xyz for p in spec.points.values() if p.xyz is not None], dtype=float)
    if np.ptp(table[:, 2]) > 0:
        raise ProjectError(f"{where}: the points table's Z are not all equal: the board "
                           "lies in a plane Z = const of its own frame")
    try:
        extent = board_extent(table[:, :2])
    except ValueError as error:
        raise ProjectError(f"{where}: {error}") from None
    return warp_shape(xyz[:, :2], extent)


def pixel_grid(camera) -> PixelGrid | None:
    if camera.pixel_size is None or camera.sensor is None:
        return None
    return PixelGrid(tuple(camera.pixel_size), tuple(camera.sensor))


def measurements(spec: ProjectSpec, camera_id: str, rows: np.ndarray | slice,
                 grid: PixelGrid | None) -> tuple[np.ndarray, np.ndarray]:
    """The image points `rows` (indices or a slice) of the table (all of camera `camera_id`)
    and their σ in its model's units: pixels -> mm for a mm-model in a pixel project
    (`grid`); a pixel model in a mm project is refused."""
    table = spec.image_points
    model = spec.cameras[camera_id].model
    model_units = CAMERA_MODELS[model].image_units
    if spec.image_units != model_units and model_units != "mm":
        raise ProjectError(
            f"camera {camera_id!r}: model {model!r} works in {model_units} units, but the "
            f'project has image_units = "{spec.image_units}"'
        )
    xy = table.xy[rows]
    sigma = np.where(np.isnan(table.sigma[rows]), spec.settings.image_sigma, table.sigma[rows])
    if spec.image_units == "pixel" and model_units == "mm":
        xy = np.asarray(grid.pixel_to_image(xy))
        sigma = sigma * np.asarray(grid.pixel_size)
    return xy, sigma


def _image_point_groups(spec, camera_rows, image_rows, point_index, grids, image_mounts=None,
                        point_warp=None):
    """One ImagePoints group per camera model and constants (`per_camera`: reports and
    variance components still part it by camera), each row's camera its row of the model's
    block; pixels -> mm per row's camera for mm-models. Named "image_points" where there is
    one group, else "image_points:<model>" (and ":<k>" for a model's cameras with different
    constants). `image_rows` (n_images,): every image's row of the images block (its frame's
    with rigs), in the images table's order; `image_mounts` (n_images,): its camera's mounts
    row (None: no rigs); `point_index`: point ID -> its row of the points block; `point_warp`:
    (n_points, 2) every point's `warp_shape` on the board (warp row 0; None: flat)."""
    table = spec.image_points
    n_rows = len(table)
    position = {iid: k for k, iid in enumerate(spec.images)}
    of_image = np.fromiter(map(position.__getitem__, table.image), dtype=int, count=n_rows)
    # The cameras in order of first use (their codes), each image's camera's code, each row's.
    seen, first = np.unique(of_image, return_index=True)
    images = list(spec.images.values())
    codes = {cid: k for k, cid in enumerate(dict.fromkeys(
        images[k].camera for k in seen[np.argsort(first)].tolist()))}
    camera_code = np.array([codes.get(image.camera, -1) for image in images],
                           dtype=int)[of_image]
    image = np.asarray(image_rows)[of_image]
    point = np.fromiter(map(point_index.__getitem__, table.point), dtype=int, count=n_rows)
    mount = None if image_mounts is None else np.asarray(image_mounts)[of_image]
    xy, sigma = np.zeros((n_rows, 2)), np.zeros((n_rows, 2))
    row = np.zeros(n_rows, dtype=int)
    kinds: dict[tuple, list[int]] = {}
    everything = slice(None)  # one camera, one kind: no copies
    by_camera = [everything] if len(codes) == 1 else _split(camera_code, len(codes))
    for camera_id, rows in zip(codes, by_camera):
        model, row[rows] = camera_rows[camera_id][0], camera_rows[camera_id][1]
        xy[rows], sigma[rows] = measurements(spec, camera_id, rows, grids[camera_id])
        constants = spec.cameras[camera_id].constants
        key = (model, tuple((n, constants[n]) for n in CAMERA_MODELS[model].constant_names))
        kinds.setdefault(key, []).append(codes[camera_id])
    models = [model for model, _ in kinds]
    groups = []
    for k, ((model, constants), members) in enumerate(kinds.items()):
        rows = (everything if len(kinds) == 1
                else np.flatnonzero(np.isin(camera_code, members)))
        name = ("image_points" if len(kinds) == 1 else f"image_points:{model}"
                if models.count(model) == 1 else f"image_points:{model}:{k}")
        groups.append(ImagePoints(
            name=name,
            model=model,
            camera=row[rows],
            image=image[rows],
            point=point[rows],
            measured=xy[rows],
            stddev=sigma[rows],
            constants=constants,
            per_camera=True,
            mount=None if mount is None else mount[rows],
            board=None if point_warp is None else np.zeros(len(point[rows]), dtype=int),
            warp_shape=None if point_warp is None else point_warp[point[rows]],
        ))
    return groups


def _split(codes: np.ndarray, n: int) -> list[np.ndarray]:
    """The rows of each code 0 .. n-1 of `codes` (n_rows,), each in row order."""
    order = np.argsort(codes, kind="stable")
    return np.split(order, np.cumsum(np.bincount(codes, minlength=n))[:-1])


def _datum_rows(spec: ProjectSpec, point_index: dict[str, int]) -> list[int] | None:
    """Rows of the free network's datum points; None for all points."""
    names = spec.settings.datum_points
    unknown = [p for p in names if p not in point_index]
    if unknown:
        raise ProjectError(
            f"{spec.path.name}: [adjustment] datum_points: no measured point {unknown[0]!r}"
        )
    return [point_index[p] for p in names] or None


EOP_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


def _dependent_datum(spec: ProjectSpec, image_ids: list[str], eop: np.ndarray,
                     eop_free: np.ndarray) -> tuple[np.ndarray, dict]:
    """Fix a dependent relative orientation in `eop_free` (n_images, 6; a copy is returned).

    The six EOPs of `datum_image` (default the first image) are fixed; without distances the
    scale is fixed too, by the station coordinate of the longest base (from the datum image
    to the image farthest from it) with the largest absolute value. Returns the mask and the
    summary of `datum_summary`."""
    name = spec.settings.datum_image or image_ids[0]
    if name not in image_ids:
        raise ProjectError(
            f"{spec.path.name}: [adjustment] datum_image: no image {name!r} in the images table")
    if len(image_ids) < 2:
        raise ProjectError(f"{spec.path.name}: [adjustment] datum = \"dependent\" needs two "
                           "images or more")
    free = np.array(eop_free, dtype=bool)
    reference = image_ids.index(name)
    free[reference] = False
    summary = {"kind": "dependent", "image": name, "fixed": list(EOP_NAMES), "scale": "distances",
               "base_image": None, "base_coordinate": None}
    if not spec.distances:
        bases = eop[:, :3] - eop[reference, :3]
        far = int(np.argmax(np.linalg.norm(bases, axis=1)))
        axis = int(np.argmax(np.abs(bases[far])))
        free[far, axis] = False
        summary.update(scale="base", base_image=image_ids[far], base_coordinate=EOP_NAMES[axis])
    return free, summary


def _gauge_positions(initial: Parameters, images: np.ndarray) -> tuple[int, ...]:
    """The `flatten` positions of the EOPs `images` (n_images, 6) marks: the dependent
    datum's unknowns (`BundleProblem.gauge`)."""
    if not images.any():
        return ()
    positions = positions_of(initial).images
    return tuple(np.asarray(positions)[images].tolist())


def datum_summary(spec: ProjectSpec) -> dict:
    """The datum as the reports give it: {"kind": "control"}; {"kind": "free", "points": the
    datum points or "all"}; dependent: see `_dependent_datum` ({"kind", "image", "fixed",
    "scale": "distances" or "base", "base_image", "base_coordinate"}). A datum key of another
    kind of datum is refused."""
    settings = spec.settings
    for key, kind in (("datum_points", "free"), ("datum_image", "dependent")):
        if getattr(settings, key) and settings.datum != kind:
            raise ProjectError(f'{spec.path.name}: [adjustment] {key} needs datum = "{kind}", '
                               f'not "{settings.datum}"')
    if settings.datum == "free":
        return {"kind": "free", "points": list(settings.datum_points) or "all"}
    return {"kind": settings.datum}


def missing_approximations(spec: ProjectSpec) -> str:
    """What a spec misses, e.g. "2 images (img01, orientation.txt:2; ...) and 77 points
    (2, image_coordinates.txt:3; ...) have no approximations"."""
    images = [spec.images[i] for i in spec.missing_images]
    points = [spec.points[p] for p in spec.missing_points]
    names = spec.file_names

    def listed(records, what, file):
        where = [f"{r.id!r} ({names.get(file, file)}:{r.line})" for r in records[:3]]
        more = f" and {len(records) - 3} more" if len(records) > 3 else ""
        return f"{len(records)} {what}{'s' if len(records) != 1 else ''} ({', '.join(where)}{more})"

    parts = [listed(images, "image", "images")] if images else []
    parts += [listed(points, "point", "image_points")] if points else []
    return " and ".join(parts) + " have no approximations"


def put_on_device(project: Project) -> Project:
    """`project` with its problem's NumPy arrays put on the device in one transfer (that of
    `build_project(spec, on_device=False)`)."""
    return dataclasses.replace(project, problem=_on_device(project.problem))


def _on_device(problem: BundleProblem) -> BundleProblem:
    """`problem` with its NumPy arrays put on the device in one transfer."""
    leaves, treedef = jax.tree.flatten(problem)
    host = [k for k, leaf in enumerate(leaves) if isinstance(leaf, np.ndarray)]
    for k, leaf in zip(host, jax.device_put([leaves[k] for k in host])):
        leaves[k] = leaf
    return jax.tree.unflatten(treedef, leaves)


def _labels(initial: Parameters, camera_ids: dict[str, list[str]], frame_ids: list[str],
            point_ids: list[str], mount_ids: list[str] | None, board_ids: list[str]
            ) -> list[str]:
    """`parameter_labels` of a project (every block's rows named), made once for each set of
    IDs: a batch's projects often have the same cameras, images and points."""
    key = (tuple((model, CAMERA_MODELS[model].parameter_names, tuple(ids))
                 for model, ids in camera_ids.items()), tuple(frame_ids),
           tuple(point_ids), None if mount_ids is None else tuple(mount_ids), tuple(board_ids))
    labels = _LABELS.get(key)
    if labels is None:
        labels = parameter_labels(initial, camera_ids, frame_ids, point_ids, mount_ids,
                                  board_ids)
        if len(_LABELS) >= _LABELS_SIZE:
            _LABELS.pop(next(iter(_LABELS)))
        _LABELS[key] = labels
    return list(labels)


_LABELS: dict[tuple, list[str]] = {}  # the IDs of `_labels` -> their labels
_LABELS_SIZE = 16


def build_project(spec: ProjectSpec, *, on_device: bool = True) -> Project:
    """The BundleProblem of a project, in mm (image) and object units; angles in radians.

    Every image and point needs its approximation: a spec with missing ones (`-` EOPs, tie
    points absent from the points table) is refused (`ProjectError`); `complete_project`
    computes them.

    The problem's arrays are put on the device in one transfer; `on_device=False` leaves
    them NumPy arrays (`jaxba batch` pads and stacks its projects in NumPy and transfers each
    chunk at once; `put_on_device` transfers one later)."""
    if not spec.complete:
        raise ProjectError(
            f"{spec.path.name}: {missing_approximations(spec)}; `jaxba adjust` and `jaxba"
            " init` compute them (in Python: jaxba.complete_project)")
    camera_rows, iop, iop_free, camera_priors = _cameras(spec)
    image_ids = list(spec.images)
    point_ids = used_points(spec)
    eop, eop_free, eop_sigma = _images(spec)
    frame_ids, rigs = image_ids, None
    image_rows, image_mounts = np.arange(len(image_ids)), None
    mounts = mounts_free = None
    if spec.rigs or any(camera.mount is not None for camera in spec.cameras.values()):
        rigs = rig_layout(spec, image_ids, eop, eop_free, eop_sigma)
        frame_ids, eop, eop_free, eop_sigma = (rigs.frame_ids, rigs.frames, rigs.frame_free,
                                               rigs.frame_sigma)
        image_rows, image_mounts = rigs.image_frame, rigs.image_mount
        mounts, mounts_free = rigs.mounts, rigs.mount_free
    gnss = _weighted_rows("gnss_ins", "images", eop, eop_sigma)
    if rigs is not None:
        gnss += _weighted_rows("mount_priors", "mounts", rigs.mounts, rigs.mount_sigma)
    datum = datum_summary(spec)
    gauge = np.zeros(np.shape(eop_free), dtype=bool)
    if spec.settings.datum == "dependent":
        held, datum = _dependent_datum(spec, frame_ids, np.asarray(eop), eop_free)
        gauge = np.asarray(eop_free) & ~held
        eop_free = np.asarray(held)
    xyz, xyz_free, control = _points(spec, point_ids)
    point_warp = _board_warp(spec, point_ids, xyz, xyz_free)
    grids = {cid: pixel_grid(camera) for cid, camera in spec.cameras.items()}
    point_index = {pid: k for k, pid in enumerate(point_ids)}
    groups = _image_point_groups(spec, camera_rows, image_rows, point_index, grids,
                                 image_mounts, point_warp)
    groups += control + gnss + camera_priors
    if spec.distances:
        groups.append(Distances(
            name="distances",
            a=np.asarray([point_index[d.a] for d in spec.distances]),
            b=np.asarray([point_index[d.b] for d in spec.distances]),
            observed=np.asarray([[d.distance] for d in spec.distances], dtype=float),
            stddev=np.asarray([[d.sigma] for d in spec.distances], dtype=float),
        ))
    settings = spec.settings
    for camera_id, (model, _) in camera_rows.items():
        if settings.refraction and CAMERA_MODELS[model].image_units != "mm":
            raise ProjectError(
                f"camera {camera_id!r}: model {model!r} has no atmospheric refraction; "
                "set refraction = false in [adjustment]"
            )
    refraction = (
        AtmosphericRefraction(settings.object_unit_km, settings.height_offset)
        if settings.refraction else NoRefraction()
    )
    if not settings.snooping_alpha < 1:
        raise ProjectError(f"{spec.path.name}: [adjustment] snooping_alpha must be < 1")
    robust = (
        None if settings.robust == "none" else RobustLoss(settings.robust, settings.robust_scale)
    )
    warped = point_warp is not None
    initial = Parameters(iop, eop, xyz, mounts, np.zeros((1, 2)) if warped else None)
    problem = BundleProblem(
        initial=initial,
        free=Parameters(iop_free, eop_free, xyz_free, mounts_free,
                        np.ones((1, 2), dtype=bool) if warped else None),
        groups=tuple(groups),
        refraction=refraction,
        robust=robust,
        ties=_ties(spec, camera_rows, iop),
        gauge=_gauge_positions(initial, gauge),
    )
    if on_device:
        problem = _on_device(problem)
    camera_ids: dict[str, list[str]] = {}
    for cid, (model, _) in camera_rows.items():
        camera_ids.setdefault(model, []).append(cid)
    board_ids = (BOARD_ID,) if warped else ()
    labels = _labels(initial, camera_ids, frame_ids, point_ids,
                     None if rigs is None else rigs.mount_ids, list(board_ids))
    if settings.datum == "free":
        problem = inner_constraints(problem, datum_points=_datum_rows(spec, point_index))
    return Project(spec, problem, camera_rows, image_ids, point_ids, grids, labels, datum=datum,
                   rigs=rigs, board_ids=board_ids)

