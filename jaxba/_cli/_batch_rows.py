"""`jaxba batch`'s summary: one row per project (`summary_row`), written as summary.csv and
summary.json (`write_summary`). Loads no jax until a row of an adjusted project is made: a
caller whose projects are adjusted by worker processes never needs it."""

import csv
import io
import json
import math
import pathlib

import numpy as np

from .._files._atomic import replace_files
from ._batch_read import BatchEntry, summary_paths


def summary_row(entry: BatchEntry) -> dict:
    """The summary row of `entry` (`run_batch` names its columns): from its result, the
    results.json of an earlier run (resumed) or, failed, its status and reason only."""
    row = {"path": str(entry.path), "name": entry.name, "status": entry.status,
           "reason": entry.reason, "mode": entry.mode}
    if entry.previous is not None:
        return row | _previous_row(entry.previous, entry.spec)
    result = entry.result
    row["converged"] = bool(result.converged) if result is not None else False
    row["sigma0"] = result.sigma0 if result is not None else None
    row["redundancy"] = result.precision.redundancy if result is not None else None
    if result is None:
        return row
    # Imported here: a caller whose projects were all adjusted by workers loads no jax.
    from .._models._cameras import CAMERA_MODELS
    from .._statistics._summary import variance_test

    row |= _test_columns(variance_test(result))
    for camera_id, (model, index) in entry.project.camera_rows.items():
        values = np.asarray(result.parameters.cameras[model])[index]
        stds = np.asarray(result.precision.std.cameras[model])[index]
        for name, value, std in zip(CAMERA_MODELS[model].parameter_names, values, stds):
            row[f"{camera_id}.{model}.{name}"] = float(value)
            row[f"{camera_id}.{model}.{name}.std"] = float(std)
    return row


TEST_COLUMNS = ("alpha", "statistic", "low", "high", "passed")


def _test_columns(test) -> dict:
    """The χ² test of σ̂0 (a `VarianceTest`, or results.json's "variance_test"; None: no
    redundancy) as the columns variance_test.alpha, .statistic, .low, .high, .passed."""
    if test is None:
        return dict.fromkeys((f"variance_test.{key}" for key in TEST_COLUMNS), None)
    get = test.get if isinstance(test, dict) else lambda key: getattr(test, key)
    return {f"variance_test.{key}": get(key) for key in TEST_COLUMNS}


def _previous_row(results: dict, spec) -> dict:
    """The summary columns of a project from its results.json (null: a non-finite number);
    the camera models from its project files."""
    row = {"converged": bool(results["converged"]), "sigma0": results["sigma0"],
           "redundancy": results["redundancy"]}
    row |= _test_columns(results.get("variance_test"))
    for camera_id, parameters in results["cameras"].items():
        model = spec.cameras[camera_id].model_key
        for name, entry in parameters.items():
            if entry["status"] != "constant":
                row[f"{camera_id}.{model}.{name}"] = entry["value"]
                row[f"{camera_id}.{model}.{name}.std"] = entry["std"]
    return row


def _json_number(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_summary(rows: list[dict], out_dir: pathlib.Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=columns, restval="")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    cleaned = [{k: _json_number(v) for k, v in row.items()} for row in rows]
    paths = summary_paths(out_dir)
    replace_files({paths["csv"]: table.getvalue(),
                   paths["json"]: json.dumps(cleaned, indent=1)})
