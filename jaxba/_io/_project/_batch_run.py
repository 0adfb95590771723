"""`jaxba batch`: adjust many project files in padded batches, write reports and a summary.

Plain Python around the jitted core (`_batch.adjust_batch`). Projects are read and their
outputs checked first (`_batch_read.read_batch`, no jax), then built one by one; a file or
datum error marks that project failed and the others go on. Projects of
one kind (same observation groups, camera models, iteration settings) share one padded,
vmapped solve: one compilation for all of them. A project that asks for a robust loss,
variance components or data snooping is adjusted alone with `adjust_project` (those are
sequential re-adjustments); its summary row says so.
"""

import csv
import io
import json
import math
import pathlib
import time
from collections.abc import Callable

import numpy as np

from ..._adjust._adjust import NotConvergedError
from ..._adjust._batch import _signature, adjust_batch, check_datum_batch
from ..._models._cameras import CAMERA_MODELS
from ..._report._atomic import replace_files
from ..._statistics._datum import DatumError
from . import ProjectError, adjust_project, build_project
from ._batch_read import BatchEntry, read_batch, summary_paths


def _needs_single(project) -> bool:
    settings = project.spec.settings
    return (project.problem.robust is not None or settings.variance_components
            or settings.data_snooping)


def run_batch(
    paths,
    out_dir,
    *,
    progress: Callable[[str], None] | None = None,
    entries: list[BatchEntry] | None = None,
    advance: Callable[[], None] | None = None,
) -> list[dict]:
    """Adjust the projects `paths` and write DIR/<project name>/ reports, DIR/summary.csv and
    DIR/summary.json. Returns the summary rows (one dict per project, in input order).

    Nothing is computed when a report would overwrite an input file or DIR cannot be
    written (`OutputError`, from `read_batch`; `entries`: its result, if already read).

    Each row: path, name, status ("ok", "not converged", "failed"), reason, mode ("batch" or
    "single"), converged, sigma0, redundancy, and per camera parameter `<camera>.<name>` and
    `<camera>.<name>.std` (the model's units: mm for mm-models, pixels for "opencv").
    `progress` receives one line per stage and per project; `advance()` is called once per
    project when it is finished (failed, or adjusted and its reports written), for a bar.
    """
    from ..._report import write_reports

    say = progress or (lambda line: None)
    finished = advance or (lambda: None)
    out_dir = pathlib.Path(out_dir)
    started = time.perf_counter()
    entries = read_batch(paths, out_dir) if entries is None else entries
    for entry in entries:
        if entry.status == "pending":
            try:
                entry.project = build_project(entry.spec)
            except (ProjectError, ValueError, OSError) as error:
                entry.status, entry.reason = "failed", str(error)
        if entry.status == "failed":
            say(f"failed  {entry.path}: {entry.reason}")
            finished()
    ready = [e for e in entries if e.status == "pending"]
    say(f"read {len(entries)} projects ({len(ready)} ok) in {time.perf_counter() - started:.1f} s")

    groups: dict[tuple, list[BatchEntry]] = {}
    for entry in ready:
        if _needs_single(entry.project):
            groups.setdefault(("single", id(entry)), []).append(entry)
            continue
        settings = entry.project.spec.settings
        key = (_signature(entry.project.problem), settings.max_iterations, settings.rtol,
               settings.atol)
        groups.setdefault(key, []).append(entry)

    done = 0
    for key, members in groups.items():
        if key[0] == "single":
            _run_single(members[0])
        else:
            say(f"solving {len(members)} project(s) in one padded batch")
            _run_group(members)
        for entry in members:
            if entry.result is not None:
                try:
                    write_reports(entry.project, entry.result, entry.out_dir)
                except (ValueError, OSError) as error:
                    entry.status, entry.reason = "failed", f"reports not written: {error}"
            done += 1
            sigma0 = f"sigma0 {entry.result.sigma0:.4f}" if entry.result is not None else ""
            say(f"[{done:{len(str(len(ready)))}d}/{len(ready)}] {entry.name}: {entry.status}"
                f" {sigma0} {entry.reason}".rstrip())
            finished()
    rows = [_summary_row(entry) for entry in entries]
    _write_summary(rows, out_dir)
    say(f"wrote {out_dir / 'summary.csv'} and summary.json"
        f" ({time.perf_counter() - started:.1f} s in all)")
    return rows


def _set_result(entry: BatchEntry, result) -> None:
    entry.result = result
    entry.status = "ok" if result.converged else "not converged"
    entry.reason = "" if result.converged else result.message


def _run_single(entry: BatchEntry) -> None:
    entry.mode = "single"
    try:
        _set_result(entry, adjust_project(entry.project))
    except (DatumError, NotConvergedError) as error:
        entry.status, entry.reason = "failed", str(error)


def _run_group(members: list[BatchEntry]) -> None:
    errors = check_datum_batch([e.project.problem for e in members],
                               labels=[e.project.labels for e in members])
    for entry, error in zip(members, errors):
        if error is not None:
            entry.status, entry.reason = "failed", f"{entry.path}: {error}"
    good = [e for e, error in zip(members, errors) if error is None]
    if not good:
        return
    settings = [e.project.spec.settings for e in good]
    results = adjust_batch(
        [e.project.problem for e in good],
        sigma0=[s.sigma0 for s in settings],
        max_steps=settings[0].max_iterations,
        rtol=settings[0].rtol,
        atol=settings[0].atol,
        alpha=[s.snooping_alpha for s in settings],
        familywise=[s.snooping_familywise for s in settings],
    )
    for entry, result in zip(good, results):
        entry.mode = "batch"
        if not math.isfinite(result.precision.sigma0_squared):
            entry.status, entry.reason = "failed", "non-finite residuals (NaN or inf)"
            continue
        _set_result(entry, result)


def _summary_row(entry: BatchEntry) -> dict:
    row = {"path": str(entry.path), "name": entry.name, "status": entry.status,
           "reason": entry.reason, "mode": entry.mode}
    result = entry.result
    row["converged"] = bool(result.converged) if result is not None else False
    row["sigma0"] = result.sigma0 if result is not None else None
    row["redundancy"] = result.precision.redundancy if result is not None else None
    if result is None:
        return row
    for camera_id, (model, index) in entry.project.camera_rows.items():
        values = np.asarray(result.parameters.cameras[model])[index]
        stds = np.asarray(result.precision.std.cameras[model])[index]
        for name, value, std in zip(CAMERA_MODELS[model].parameter_names, values, stds):
            row[f"{camera_id}.{name}"] = float(value)
            row[f"{camera_id}.{name}.std"] = float(std)
    return row


def _json_number(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_summary(rows: list[dict], out_dir: pathlib.Path) -> None:
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
