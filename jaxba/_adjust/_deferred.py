"""The points `complete_project` deferred, intersected from the adjusted block: `adjust_deferred`.

A point whose rays meet under the initialisation's `min_angle` (2°), or miss each other by
more than its robust σ before the camera is calibrated, is deferred: the block is adjusted
without it. From the adjusted EOPs, points and cameras, `initialise_block` intersects it again
(every image given, every adjusted point control, the cameras adjusted), now down to
DEFERRED_MIN_ANGLE, its rays judged by the adjusted block's σ with a cut raised to the
familywise bound of the block's number of image points (clean rays miss by chance: a far
2-ray point of the close-range block, 10,813 image points, has |w| = 4.06 in the adjustment
from the truth, where the bound of 3.5 σ left it out); the block is
adjusted again with those that could be intersected, starting from the first adjustment's
solution. A deferred point that still cannot be intersected is left out, named with the
reason (`Deferral`).
"""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._project._build import Project, build_project
from .._project._spec import ProjectSpec
from .._statistics._adjustment import Adjustment
from ._adjust_project import adjust_project
from ._complete import (
    LISTED,
    Completion,
    block_distances,
    block_observations,
    named,
    without_points,
)
from ._initialise import initialise_block
from ._initialise._blunders import familywise
from ._initialise._state import INLIER_K

DEFERRED_MIN_ANGLE = np.radians(0.1)
"""The smallest intersection angle of a deferred point's rays in the adjusted block: with
0.25 px of noise on a 2300 px principal distance, rays 0.1° apart fix the point's depth to
about 10 %."""


@dataclasses.dataclass(frozen=True)
class Deferral:
    """What became of the deferred points: `added`, point ID -> why it was deferred (now
    intersected from the adjusted block and adjusted); `left_out`, point ID -> why it still
    cannot be intersected (left out of the adjustment with its image points)."""

    added: dict[str, str]
    left_out: dict[str, str]

    def summary(self) -> dict:
        """The `deferred` part of results.json's `initialisation` section."""
        return {"added_points": list(self.added), "left_out_points": dict(self.left_out)}

    def lines(self) -> list[str]:
        """What became of the deferred points, for the console."""
        lines = [f"intersected {len(self.added)} of the {len(self.added) + len(self.left_out)}"
                 " deferred points from the adjusted block"]
        if self.left_out:
            named = "; ".join(f"{pid!r}: {reason}" for pid, reason in
                              list(self.left_out.items())[:LISTED])
            more = (f"; and {len(self.left_out) - LISTED} more"
                    if len(self.left_out) > LISTED else "")
            lines.append(f"left out {len(self.left_out)} deferred point"
                         f"{'s' * (len(self.left_out) != 1)} that the adjusted block cannot"
                         f" intersect either (with their image points): {named}{more}")
        return lines


def _adjusted_cameras(project: Project, result: Adjustment, image_ids) -> list:
    """Per image its camera's lens model at the adjusted values (shared per camera)."""
    spec = project.spec
    instances = {}
    for camera_id in dict.fromkeys(spec.images[iid].camera for iid in image_ids):
        camera = spec.cameras[camera_id]
        key, row = project.camera_rows[camera_id]
        adjusted = dict(zip(CAMERA_MODELS[key].parameter_names,
                            np.asarray(result.parameters.cameras[key])[row].tolist()))
        model = CAMERA_MODELS[camera.model]
        values = jnp.asarray([adjusted[n] for n in model.parameter_names], dtype=float)
        instances[camera_id] = model.from_parameters(values, **camera.constants)
    return [instances[spec.images[iid].camera] for iid in image_ids]


def intersect_deferred(completion: Completion, project: Project,
                       result: Adjustment) -> tuple[ProjectSpec, Deferral]:
    """The deferred points of `completion` intersected from the adjusted `project`'s
    `result` (module docstring). Returns the spec to adjust next (`completion.pending` with
    the points intersected, the others left out) and the `Deferral`."""
    pending = completion.pending
    image_ids = list(pending.images)
    point_ids = list(completion.point_ids)
    image_row = {iid: k for k, iid in enumerate(project.image_ids)}
    point_row = {pid: k for k, pid in enumerate(project.point_ids)}
    eops = np.asarray(result.parameters.images, dtype=float)[[image_row[i] for i in image_ids]]
    adjusted = np.asarray(result.parameters.points, dtype=float)
    control = np.array([adjusted[point_row[pid]] if pid in point_row else np.full(3, np.nan)
                        for pid in point_ids]).reshape(-1, 3)
    again = initialise_block(
        block_observations(pending, image_ids, point_ids),
        _adjusted_cameras(project, result, image_ids), eops=eops, control=control,
        distances=block_distances(pending, point_ids), n_points=len(point_ids),
        min_angle=DEFERRED_MIN_ANGLE, polish_rounds=0, unknown_distortion=0.0,
        inlier_k=familywise(len(pending.image_points), INLIER_K),
        camera_names=[pending.images[iid].camera for iid in image_ids])
    row = {pid: k for k, pid in enumerate(point_ids)}
    added, left_out, points = {}, {}, dict(pending.points)
    for pid, reason in completion.deferred.items():
        k = row[pid]
        if k in again.failed_points:
            left_out[pid] = named(again.failed_points[k], image_ids, point_ids)
        else:
            added[pid] = reason
            points[pid] = dataclasses.replace(points[pid], xyz=tuple(again.points[k].tolist()))
    spec = without_points(dataclasses.replace(pending, points=points), left_out)
    return spec, Deferral(added, left_out)


def _started_from(project: Project, before: Project, result: Adjustment) -> Project:
    """`project` with the adjusted values of `before`'s `result` as its approximations
    (cameras, images, and the points both have); fixed values are the files' in both."""
    initial = project.problem.initial
    row = {pid: k for k, pid in enumerate(before.point_ids)}
    shared = [k for k, pid in enumerate(project.point_ids) if pid in row]
    points = np.asarray(initial.points, dtype=float).copy()
    points[shared] = np.asarray(result.parameters.points, dtype=float)[
        [row[project.point_ids[k]] for k in shared]]
    image_row = {iid: k for k, iid in enumerate(before.image_ids)}
    images = np.asarray(result.parameters.images, dtype=float)[
        [image_row[iid] for iid in project.image_ids]]
    start = eqx.tree_at(lambda p: (p.cameras, p.images, p.points), initial,
                        (result.parameters.cameras, jnp.asarray(images),
                         jnp.asarray(points)))
    return dataclasses.replace(
        project, problem=eqx.tree_at(lambda p: p.initial, project.problem, start))


def adjust_deferred(
    completion: Completion,
    project: Project,
    result: Adjustment,
    *,
    on_deferral: Callable[[Project, Deferral], None] | None = None,
    **options,
) -> tuple[Project, Adjustment, Deferral]:
    """Adjust the block again with the points `complete_project` deferred (module
    docstring): intersected from `project`'s adjusted `result`, the block is built, started
    from `result` and adjusted by `adjust_project(**options)` (`on_deferral(new project,
    deferral)` is called before). Returns the new project (its `initialisation` section says
    what was deferred, added and left out), its adjustment and the `Deferral`. Needs jax in
    float64; `result` should have converged (its values start the next adjustment)."""
    spec, deferral = intersect_deferred(completion, project, result)
    again = build_project(spec)
    section = dict(project.initialisation or completion.summary())
    section |= deferral.summary()
    again = dataclasses.replace(_started_from(again, project, result), initialisation=section)
    if on_deferral is not None:
        on_deferral(again, deferral)
    return again, adjust_project(again, **options), deferral
