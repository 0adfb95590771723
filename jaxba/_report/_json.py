"""results.json: the machine-readable report (FORMATS.md "results.json")."""

import json
import math

import numpy as np

from .._project import Project
from .._solve import Adjustment
from ._collect import (
    ParameterTable,
    camera_tables,
    group_summaries,
    image_residuals,
    image_table,
    point_table,
    residual_summaries,
)


def _number(value) -> float | None:
    """A JSON number, or None (null) for NaN and infinities."""
    value = float(value)
    return value if math.isfinite(value) else None


def _entries(table: ParameterTable, row: int) -> dict[str, dict]:
    return {
        name: {
            "value": _number(table.values[row, k]),
            "std": _number(table.stds[row, k]),
            "status": table.status[row][k],
        }
        for k, name in enumerate(table.names)
    }


def _nulls(tree):
    """Replace non-finite floats anywhere in a nested dict by None."""
    if isinstance(tree, dict):
        return {key: _nulls(value) for key, value in tree.items()}
    if isinstance(tree, float | np.floating):
        return _number(tree)
    return tree


def results_dict(project: Project, result: Adjustment) -> dict:
    """Everything of results.json as plain Python (no NaN: null instead).

    Keys of FORMATS.md (converged, sigma0, redundancy, iterations, cameras, images, points;
    angles and their σ in decimal degrees) plus: project, message, steps, n_observations,
    n_unknowns, sigma0_squared, sigma0_prior, units, image_cameras, image_residuals (RMS in mm
    and px: overall, per camera, per image) and observation_groups (n, vᵀPv). Iteration 0 is
    the approximations. Every parameter carries "status": free, fixed or weighted.
    """
    precision = result.precision
    cameras = camera_tables(project, result)
    images = image_table(project, result)
    points = point_table(project, result)
    return {
        "project": project.spec.name,
        "converged": bool(result.converged),
        "message": result.message,
        "steps": int(result.steps),
        "sigma0": _number(math.sqrt(precision.sigma0_squared)),
        "sigma0_squared": _number(precision.sigma0_squared),
        "sigma0_prior": _number(project.spec.settings.sigma0),
        "redundancy": int(precision.redundancy),
        "n_observations": int(precision.n_observations),
        "n_unknowns": int(precision.n_unknowns),
        "units": {
            "image": "mm", "angles": "degrees", "object": "object units of the input files",
        },
        "iterations": [
            {
                "iteration": int(it.iteration),
                "sigma0_squared": _number(it.sigma0_squared),
                "cost": _number(it.cost),
            }
            for it in result.iterations
        ],
        "cameras": {cid: _entries(table, 0) for cid, table in cameras.items()},
        "images": {iid: _entries(images, k) for k, iid in enumerate(images.ids)},
        "image_cameras": {iid: project.spec.images[iid].camera for iid in images.ids},
        "points": {pid: _entries(points, k) for k, pid in enumerate(points.ids)},
        "image_residuals": _nulls(residual_summaries(image_residuals(project, result))),
        "observation_groups": _nulls(group_summaries(project, result)),
    }


def results_json(project: Project, result: Adjustment) -> str:
    """results.json as text (strict JSON: raises if a NaN slipped through)."""
    return json.dumps(results_dict(project, result), indent=2, allow_nan=False) + "\n"
