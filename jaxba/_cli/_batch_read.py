"""`jaxba batch`, first step: read every project file and check every output, without jax.

A project that cannot be read is marked failed and the others go on; a report or summary
that would overwrite an input of any project of the batch, or an output folder that cannot
be written, stops the whole batch before anything is computed (`OutputError`).
"""

import dataclasses
import json
import pathlib

from .._files._paths import check_folder, check_targets, resolved
from .._io._project import ProjectFile, read_project, read_project_file, read_project_tables
from .._project import ProjectError
from .._project._spec import ProjectSpec
from .._report._outputs import REPORTS, report_paths


@dataclasses.dataclass
class BatchEntry:
    """One project of a batch: where it came from, what happened, and its result."""

    path: pathlib.Path
    name: str
    status: str = "pending"  # ok | not converged | failed
    reason: str = ""
    mode: str = ""  # batch | single | resumed
    spec: ProjectSpec | None = None
    head: ProjectFile | None = None  # its project file, where only that was read
    input_files: tuple[pathlib.Path, ...] = ()  # its TOML and tables, once its file is read
    project: object = None
    result: object = None
    out_dir: pathlib.Path | None = None
    reports: tuple[str, ...] = REPORTS  # the kinds of report it writes (`report_paths`)
    previous: dict | None = None  # resumed: its results.json
    row: dict | None = None  # its summary row, once adjusted


# What fails one project of a batch alone, while it is read or built (a malformed table, a
# file gone, a project that cannot be built).
PROJECT_ERRORS = (ProjectError, ValueError, OSError)


def read_whole(entry: BatchEntry) -> ProjectSpec:
    """`entry`'s whole project: its tables read after its project file (`head`, where
    `read_batch(tables=False)` read only that), or all of it. Raises `PROJECT_ERRORS`."""
    return read_project(entry.path) if entry.head is None else read_project_tables(entry.head)


def summary_paths(out_dir) -> dict[str, pathlib.Path]:
    """The batch's own outputs in `out_dir`: summary.csv and summary.json."""
    out_dir = pathlib.Path(out_dir)
    return {"csv": out_dir / "summary.csv", "json": out_dir / "summary.json"}


def _unique_folder(name: str, taken: set[str]) -> str:
    folder, k = name, 2
    while folder in taken:
        folder, k = f"{name}_{k}", k + 1
    taken.add(folder)
    return folder


def read_batch(paths, out_dir, *, tables: bool = True,
               reports: tuple[str, ...] = REPORTS) -> list[BatchEntry]:
    """Read the project files `paths` and give each its report folder `out_dir/<name>/`
    (`<name>_2`, ... for repeated names) and the kinds of report it writes (`reports`, see
    `report_paths`).

    Returns one `BatchEntry` per path, in order; one that cannot be read has status
    "failed" and the reason. Raises `OutputError` when `out_dir` is not a writable folder,
    or when summary.csv, summary.json or any project's report would be an input file of any
    project of the batch (its TOML or a table it names) or a folder.

    `tables`: read every project whole (`spec`); False: only its project file (`head`:
    `read_project_file`), `spec` left None for whoever adjusts it to read the tables
    (worker processes, each its share), a table it cannot read failing that project then.
    """
    out_dir = pathlib.Path(out_dir)
    check_folder(out_dir)
    entries, taken = [], set()
    for path in map(pathlib.Path, paths):
        entry = BatchEntry(path=path, name=path.stem, reports=reports)
        entries.append(entry)
        try:
            if tables:
                entry.spec = read_project(path)
                entry.name, entry.input_files = entry.spec.name, entry.spec.input_files
            else:
                entry.head = read_project_file(path)
                entry.name, entry.input_files = entry.head.name, entry.head.input_files
        except ProjectError as error:
            entry.status, entry.reason = "failed", str(error)
            continue
        entry.out_dir = out_dir / _unique_folder(entry.name, taken)
    # Each input resolved once: every report of every project is checked against them all
    # (a project's own among them: not given again, they would be resolved again).
    inputs = resolved(file for entry in entries for file in entry.input_files or (entry.path,))
    folders: dict = {}  # resolved once: out_dir, and each project's folder where it exists
    check_targets(summary_paths(out_dir).values(), inputs, "a project of the batch", folders)
    for entry in entries:
        if entry.out_dir is None:  # not read
            continue
        if entry.out_dir.exists():  # else made in out_dir, checked above
            check_folder(entry.out_dir)
        check_targets(report_paths(entry.name, entry.out_dir, entry.reports).values(), inputs,
                      f"project {entry.name!r}", folders)
    return entries


RESUMED_KEYS = {"converged", "message", "sigma0", "redundancy", "cameras"}


def finished_results(entry: BatchEntry) -> dict | None:
    """The results.json of `entry`'s earlier run when all its reports (`entry.reports`, with
    results.json) exist (they are written together, so all or none), none is empty (what a
    system crash can leave of reports not flushed to disk) and results.json can be read; None
    otherwise."""
    if entry.out_dir is None:  # not read
        return None
    paths = report_paths(entry.name, entry.out_dir, tuple(dict.fromkeys((*entry.reports, "json"))))
    if not all(path.is_file() and path.stat().st_size > 0 for path in paths.values()):
        return None
    try:
        results = json.loads(paths["json"].read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (not isinstance(results, dict) or results.get("project") != entry.name
            or not RESUMED_KEYS <= results.keys()):
        return None
    return results
