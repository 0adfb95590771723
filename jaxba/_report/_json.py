"""results.json: the machine-readable report (docs/outputs.md)."""

import json
import math
from json.encoder import encode_basestring_ascii as _string

import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._board_warp import board_warp_tree
from ._collect import (
    ParameterTable,
    camera_correlations,
    camera_covariances,
    camera_tables,
    camera_units,
    datum_text,
    image_table,
    outlier_check,
    point_ellipsoids,
    point_table,
    project_units,
    rejections,
    reliability_summary,
    shared_tables,
    variance_check,
)
from ._no_sigma import no_sigma_entries
from ._outputs import OBSERVATIONS_FILE
from ._rigs import frame_table, mount_correlations, mounts_tree, rigs_tree
from ._shortest import number_texts
from ._summaries import group_summaries, image_residual_summaries


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
    """Replace non-finite floats anywhere in nested dicts and lists by None."""
    if isinstance(tree, float):  # np.float64 too
        return float(tree) if math.isfinite(tree) else None
    if isinstance(tree, dict):
        return {key: _nulls(value) for key, value in tree.items()}
    if isinstance(tree, (list, tuple)):
        return [_nulls(value) for value in tree]
    if isinstance(tree, np.floating):
        return _number(tree)
    return tree


def _points(project: Project, result: Adjustment) -> dict[str, dict]:
    """X, Y, Z entries per point, plus the 1σ "ellipsoid" for points with free coordinates:
    semi-axes descending (object units) and "directions", the unit vector of each axis."""
    points = point_table(project, result)
    axes, directions, has = point_ellipsoids(project, result)
    return {pid: _point_entry(points, axes, directions, has, k) for k, pid in enumerate(points.ids)}


def _point_entry(points: ParameterTable, axes, directions, has, k: int) -> dict:
    entry = _entries(points, k)
    if has[k]:
        entry["ellipsoid"] = _nulls({
            "axes": axes[k].tolist(), "directions": directions[k].T.tolist(),
        })
    return entry


class _Deferred:
    """A value of the results tree that lays itself out (`_layout`): `render(depth, indent)`
    returns its JSON text."""

    def __init__(self, render):
        self.render = render


def _points_text(project: Project, result: Adjustment, depth: int, indent: str) -> str:
    """The "points" value of results.json as `_layout` writes `_points`, formatted in one `%`
    over all points, their numbers printed by orjson (`number_texts`: null where not
    finite)."""
    if depth != 2:
        return _layout(_points(project, result), depth, indent)
    points = point_table(project, result)
    if not points.ids:
        return _layout({}, depth, indent)
    axes, directions, has = point_ellipsoids(project, result)
    values, stds = np.asarray(points.values, dtype=float), np.asarray(points.stds, dtype=float)
    # Per point the semi-axes, then the unit vector of each axis (column k of `directions`).
    ellipsoid = np.column_stack([axes, np.swapaxes(directions, 1, 2).reshape(len(axes), -1)])
    inner, leaf = indent + "  ", indent + "    "
    names = [_string(name).replace("%", "%%") for name in points.names]
    fields = [f'{name}: {{"value": %s, "std": %s, "status": %s}}' for name in names]
    axes_text = "[" + ", ".join(["%s"] * axes.shape[1]) + "]"
    direction_text = "[" + ", ".join([axes_text] * axes.shape[1]) + "]"
    with_ellipsoid = f'"ellipsoid": {{"axes": {axes_text}, "directions": {direction_text}}}'
    # One template per kind of point: without an ellipsoid, with one.
    templates = np.array([
        "%s: {\n" + leaf + f",\n{leaf}".join(lines) + f"\n{inner}}}"
        for lines in (fields, [*fields, with_ellipsoid])], dtype=object)
    kind = has.astype(int)
    status = np.asarray(points.status, dtype=object)
    encoded = {name: _string(name) for name in set(status.ravel().tolist())}
    n_names = values.shape[1]
    size = 1 + 3 * n_names  # the fields of a point without an ellipsoid
    width = size + ellipsoid.shape[1] * bool(has.any())  # no ellipsoid: no columns for one
    numbers = np.column_stack([values, stds, ellipsoid[:, :width - size]])
    numbers = np.array(number_texts(numbers), dtype=object).reshape(numbers.shape)
    table = np.empty((len(kind), width), dtype=object)
    table[:, 0] = list(map(_string, points.ids))
    table[:, 1:size:3] = numbers[:, :n_names]
    table[:, 2:size:3] = numbers[:, n_names:2 * n_names]
    for j in range(n_names):
        table[:, 3 + 3 * j] = [encoded[name] for name in status[:, j].tolist()]
    table[:, size:] = numbers[:, 2 * n_names:]
    used = np.arange(width) < np.array([size, width])[kind][:, None]
    text = f",\n{inner}".join(templates[kind].tolist()) % tuple(table[used].tolist())
    return "{\n" + inner + text + f"\n{indent}}}"


def _correlations(project: Project, result: Adjustment) -> dict[str, dict]:
    return {
        cid: {"parameters": list(names), "matrix": _nulls(np.asarray(matrix).tolist())}
        for cid, (names, matrix) in camera_correlations(project, result).items()
    }


def _camera_models(project: Project, result: Adjustment) -> dict[str, dict]:
    """Per camera what its values need to be used elsewhere (`jaxba export`, `jaxba.compare`):
    its model key (with a ray refraction "<model>+<refraction>"), image size (`sensor`:
    columns, rows; null if not given), `pixel_size` (mm, x and y; null where cameras.toml
    gives none), the model's constants, and its parameters in the model's order and units
    with their covariance (fixed ones 0; σ̂0² N⁻¹ as the σ of "cameras")."""
    models, covariances = {}, camera_covariances(project, result)
    for cid, (model, row) in project.camera_rows.items():
        camera = project.spec.cameras[cid]
        models[cid] = _nulls({
            "model": model,
            "sensor": None if camera.sensor is None else [int(n) for n in camera.sensor],
            "pixel_size": (None if camera.pixel_size is None
                           else [float(size) for size in camera.pixel_size]),
            "constants": {n: camera.constants[n] for n in CAMERA_MODELS[model].constant_names},
            "parameters": list(CAMERA_MODELS[model].parameter_names),
            "values": np.asarray(result.parameters.cameras[model])[row].tolist(),
            "covariance": covariances[cid].tolist(),
        })
    return models


def _variance_components(result: Adjustment) -> dict[str, dict] | None:
    if result.variance_components is None:
        return None
    return _nulls({
        name: {
            "sigma0": float(component.sigma0),
            "redundancy": float(component.redundancy),
            "n_observations": int(component.n_observations),
        }
        for name, component in result.variance_components.items()
    })


def _reliability(project: Project, result: Adjustment) -> dict | None:
    summary = reliability_summary(project, result)
    if summary is None:
        return None
    return _nulls({
        "alpha": summary.alpha,
        "critical_value": summary.critical_value,
        "redundancy_sum": summary.redundancy_sum,
        "min_redundancy": summary.min_redundancy,
        "mean_redundancy": summary.mean_redundancy,
        "max_abs_w": summary.max_abs_w,
        "n_outliers": summary.n_outliers,
    })


def _variance_test(project: Project, result: Adjustment) -> dict | None:
    """The χ² test of the variance factor (`variance_test`), null without redundancy."""
    test = variance_check(project, result)
    if test is None:
        return None
    return _nulls({
        "alpha": test.alpha, "redundancy": test.redundancy, "statistic": test.statistic,
        "low": test.low, "high": test.high, "sigma0_low": test.sigma0_low,
        "sigma0_high": test.sigma0_high, "passed": test.passed,
    })


def _outliers(project: Project, result: Adjustment) -> dict | None:
    """|w| above the critical value: count and the worst few; null without a reliability."""
    found = outlier_check(project, result)
    if found is None:
        return None
    return _nulls({
        "critical_value": found.critical_value, "alpha": found.alpha, "count": found.count,
        "removed": found.removed,
        "worst": [{"group": group, "observation": name, "abs_w": abs_w}
                  for group, name, abs_w in found.worst],
    })


def _timings(result: Adjustment) -> dict:
    """{"seconds": {phase: run seconds, ..., "compile": s, "total": s}, "compilations": n,
    "cache_hits": n}: the phases timed before the reports are written (read, start-up, datum
    check, solve, statistics, as far as the run timed them)."""
    timings = result.timings
    return {
        "seconds": {name: round(seconds, 4) for name, seconds in timings.summary().items()},
        "compilations": timings.compilations,
        "cache_hits": timings.cache_hits,
    }


def results_dict(project: Project, result: Adjustment) -> dict:
    return _results_tree(project, result, _points(project, result))


def _results_tree(project: Project, result: Adjustment, points) -> dict:
    """Everything of results.json as plain Python (no NaN: null instead).

    Keys of docs/outputs.md (converged, sigma0, redundancy, iterations, cameras, images, points;
    angles and their σ in decimal degrees) plus: project, message, steps, n_observations,
    n_unknowns, sigma0_squared, sigma0_prior, units (image: "mm", "pixel" for pixel-unit
    camera models, or "mixed"; image_cameras: per camera), image_cameras, image_residuals (RMS
    in mm and px: overall, per camera, per image; data-snooping rejections left out),
    observation_groups (n, vᵀPv), correlations (per camera: the estimated IOPs and their
    correlation matrix), variance_components ({group: sigma0, redundancy, n_observations}) and
    variance_component_iterations (null when not estimated), observations_file (the name of
    the per-observation table beside results.json, observations.csv: residuals, redundancy
    numbers, normalised residuals, outlier flags), rejections (data snooping, in order of
    removal), reliability (alpha, critical_value, redundancy_sum, ...; null when not computed)
    and per point with a free coordinate its 1σ "ellipsoid"; solver (the normal-equation
    backend that ran: "dense" or "schur"), datum (the project's definition and what fixes
    it), variance_test (the χ² test of σ̂0), outliers (|w| above the critical value: count,
    the worst few) and timings (seconds per phase up to the reports,
    compilation apart; see `_timings`); initialisation (what `complete_project` computed,
    `Completion.summary()`), only when the approximations were computed; datum (how it is
    defined: `Project.datum`). Iteration 0 is the approximations.
    camera_models (per camera: model, sensor, pixel_size, constants, parameters, values and
    their covariance: what `jaxba.compare` reads).
    Every parameter carries "status": free, fixed or weighted; a tied camera parameter
    "tied to CAMERA.parameter" (its source's unknown: the same value and std). With rigs:
    "images" every image's pose composed from its frame's and its camera's (σ propagated),
    "frames" the frames' poses (as "images"), "image_frames" every image's frame, "rigs"
    {rig: {camera: X0 .. kappa, baseline}} (`rigs_tree`), and "correlations" also per
    "<rig>/<camera>" its relative pose's.
    """
    precision = result.precision
    cameras = camera_tables(project, result)
    images = image_table(project, result)
    tree = {
        "project": project.spec.name,
        "converged": bool(result.converged),
        "message": result.message,
        "steps": int(result.steps),
        "solver": result.backend,
        # `datum_summary`: kind and what it fixes; the description as in NAME.out
        "datum": {**project.datum, "description": datum_text(project, result)},
        "timings": _timings(result),
        "sigma0": _number(math.sqrt(precision.sigma0_squared)),
        "sigma0_squared": _number(precision.sigma0_squared),
        "sigma0_prior": _number(project.spec.settings.sigma0),
        "variance_test": _variance_test(project, result),
        "redundancy": int(precision.redundancy),
        "n_observations": int(precision.n_observations),
        "n_unknowns": int(precision.n_unknowns),
        "units": {
            "image": project_units(project),
            "image_cameras": {cid: camera_units(project, cid) for cid in cameras},
            "angles": "degrees",
            "object": "object units of the input files",
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
        "points": points,
        "image_residuals": _nulls(image_residual_summaries(project, result)),
        "observation_groups": _nulls(group_summaries(project, result)),
        "correlations": _correlations(project, result),
        "camera_models": _camera_models(project, result),
        "variance_components": _variance_components(result),
        "variance_component_iterations": (
            int(result.variance_iterations) if result.variance_components is not None else None
        ),
        "observations_file": OBSERVATIONS_FILE,
        "rejections": _nulls(rejections(project, result)),
        "reliability": _reliability(project, result),
        "outliers": _outliers(project, result),
        "no_sigma": no_sigma_entries(project, result),
    }
    if project.rigs is not None:
        frames = frame_table(project, result)
        tree["frames"] = {fid: _entries(frames, k) for k, fid in enumerate(frames.ids)}
        tree["image_frames"] = {iid: project.rigs.frame_ids[row] for iid, row in
                                zip(project.image_ids, project.rigs.image_frame.tolist())}
        tree["rigs"] = _nulls(rigs_tree(project, result, _entries))
        tree["mounts"] = _nulls(mounts_tree(project, result))
        tree["correlations"].update(
            {mid: {"parameters": list(names), "matrix": _nulls(np.asarray(matrix).tolist())}
             for mid, (names, matrix) in mount_correlations(project, result).items()})
    warp = board_warp_tree(project, result)
    if warp is not None:
        tree["board_warp"] = _nulls(warp)
    if project.initialisation is not None:
        tree["initialisation"] = _nulls(project.initialisation)
    return tree


# json.dumps(value, allow_nan=False) without a new encoder per call; `_string` is json.dumps
# of a str (the keys and IDs).
_STRICT = json.JSONEncoder(allow_nan=False)


def _layout(value, depth: int, indent: str = "") -> str:
    """JSON text of `value`: dicts and lists indented by two spaces down to `depth` levels,
    each deeper value on one line (json's C encoder, fast for thousands of points)."""
    if isinstance(value, _Deferred):
        return value.render(depth, indent)
    if depth == 0 or not isinstance(value, dict | list) or not value:
        return _STRICT.encode(value)
    inner = indent + "  "
    if isinstance(value, dict):
        items = [f"{_string(k)}: {_layout(v, depth - 1, inner)}" for k, v in value.items()]
        opening, closing = "{", "}"
    else:
        items = [_layout(v, depth - 1, inner) for v in value]
        opening, closing = "[", "]"
    return f"{opening}\n{inner}" + f",\n{inner}".join(items) + f"\n{indent}{closing}"


def results_json(project: Project, result: Adjustment) -> str:
    """results.json as text (strict JSON: raises if a NaN slipped through); indented to the
    entries of each point, image, camera and iteration, these on one line each."""
    points = _Deferred(lambda depth, indent: _points_text(project, result, depth, indent))
    with shared_tables():
        return _layout(_results_tree(project, result, points), 3) + "\n"
