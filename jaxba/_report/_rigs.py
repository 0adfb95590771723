"""Rigs in the reports: the frames' poses, every rig camera's pose in its rig with the baseline
and their σ and correlations, and every image's pose composed from its frame's and its
camera's (σ propagated from their covariance, `jaxba._statistics._rigs`)."""

import numpy as np

from .._problem._parameters import (
    ANGLE_NAMES,
    IMAGE_PARAMETER_NAMES,
    positions_of,
)
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._derived import correlation
from .._statistics._rigs import baseline
from ._collect import ParameterTable, frame_sigma, shared, status_table

_ANGLES = [IMAGE_PARAMETER_NAMES.index(name) for name in ANGLE_NAMES]


def _in_degrees(values: np.ndarray) -> np.ndarray:
    values = np.array(values, dtype=float).reshape(-1, 6)
    values[:, _ANGLES] = np.degrees(values[:, _ANGLES])
    return values


@shared
def frame_table(project: Project, result: Adjustment) -> ParameterTable:
    """The poses of the images block's rows (the frames; the images without rigs), angles
    and their σ in decimal degrees."""
    status = status_table(project.problem.free.images, frame_sigma(project))
    return ParameterTable(IMAGE_PARAMETER_NAMES, list(project.frame_ids),
                          _in_degrees(result.parameters.images),
                          _in_degrees(result.precision.std.images), status)


@shared
def mount_table(project: Project, result: Adjustment) -> ParameterTable:
    """Every rig camera's pose in its rig's frame (rows "<rig>/<camera>"; the reference's
    identity left out), angles and σ in decimal degrees."""
    rigs = project.rigs
    sigma = np.where(np.isfinite(rigs.mount_sigma), rigs.mount_sigma, np.nan)
    status = status_table(project.problem.free.mounts, sigma.tolist())[1:]
    return ParameterTable(IMAGE_PARAMETER_NAMES, rigs.mount_ids[1:],
                          _in_degrees(result.parameters.mounts)[1:],
                          _in_degrees(result.precision.std.mounts)[1:], status)


@shared
def rig_baselines(project: Project, result: Adjustment) -> dict[str, tuple[float, float]]:
    """"<rig>/<camera>" -> (baseline, σ) in object units (`jaxba._statistics._rigs.baseline`)."""
    return {mid: baseline(result.parameters, result.precision, row)
            for row, mid in enumerate(project.rigs.mount_ids) if row > 0}


@shared
def mount_correlations(project: Project, result: Adjustment) -> dict[str, tuple[list, np.ndarray]]:
    """"<rig>/<camera>" -> the names of its estimated relative-pose parameters and their
    correlation matrix ρ."""
    params = result.parameters
    positions = np.asarray(positions_of(params).mounts)
    free = np.asarray(project.problem.free.mounts)
    out = {}
    for row, mid in enumerate(project.rigs.mount_ids):
        if row == 0 or not free[row].any():
            continue
        chosen = positions[row][free[row]]
        names = [n for n, f in zip(IMAGE_PARAMETER_NAMES, free[row]) if f]
        out[mid] = (names, correlation(np.asarray(result.precision.covariance_of(chosen))))
    return out


def rigs_tree(project: Project, result: Adjustment, entries) -> dict:
    """results.json "rigs": {rig: {"reference": the camera whose frame is the rig frame,
    camera: {X0 .. kappa: entry, "baseline": {value, std}}}} (`entries(table, row)` makes a
    parameter's entries as for cameras and images)."""
    table = mount_table(project, result)
    baselines = rig_baselines(project, result)
    tree: dict[str, dict] = {rig: {"reference": spec.reference}
                             for rig, spec in project.spec.rigs.items()}
    for k, mid in enumerate(table.ids):
        rig, camera = project.rigs.mount_cameras[k + 1]
        if rig not in tree:  # a camera on a GNSS/INS platform: `mounts_tree`
            continue
        length, sigma = baselines[mid]
        tree[rig][camera] = {**entries(table, k), "baseline": {"value": length, "std": sigma}}
    return tree


def mounts_tree(project: Project, result: Adjustment) -> dict:
    """results.json "mounts": {camera: {"lever_arm", "boresight": {"value": [3], "std": [3],
    "status": [3]}}} of the cameras on GNSS/INS platforms (boresight in degrees)."""
    table = mount_table(project, result)
    tree = {}
    for k, mid in enumerate(table.ids):
        rig, camera = project.rigs.mount_cameras[k + 1]
        if rig in project.spec.rigs:
            continue
        tree[camera] = {
            part: {"value": table.values[k, columns].tolist(),
                   "std": table.stds[k, columns].tolist(),
                   "status": [table.status[k][j] for j in range(columns.start, columns.stop)]}
            for part, columns in (("lever_arm", slice(0, 3)), ("boresight", slice(3, 6)))}
    return tree
