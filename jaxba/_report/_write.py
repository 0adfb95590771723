"""Write the report files of an adjustment, never over an input file, all or none."""

import pathlib

from .._files._atomic import replace_files
from .._gc import paused_gc
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from ._collect import shared_tables
from ._csv import observations_csv
from ._json import results_json
from ._outputs import REPORTS, check_outputs, report_paths
from ._text import out_text, res_text, sigma_text


def write_reports(project: Project, result: Adjustment, out_dir) -> list[pathlib.Path]:
    """Write NAME.out, NAME.res, NAME.sigma, results.json and observations.csv into `out_dir`
    (created if needed).

    NAME is the project name. Nothing is written if any target is an input file of the
    project (`OutputError`). The files replace the old reports together (`replace_files`):
    a run that fails while writing (a full disk, an interrupt) leaves the previous reports
    as they were. Returns the paths.
    """
    paths = check_outputs(project.spec, out_dir)
    _replace(report_texts(project, result, paths), out_dir, durable=True)
    return list(paths.values())


def write_batch_reports(project: Project, result: Adjustment, out_dir,
                        kinds: tuple[str, ...] = REPORTS) -> None:
    """`write_reports` for a project of `jaxba batch`, whose outputs were all checked before
    anything was computed (`read_batch`): the same files (those of `kinds`, see
    `report_paths`), not checked again, replaced together but not flushed to disk one by one
    (`replace_files` without `durable`)."""
    paths = report_paths(project.spec.name, out_dir, kinds)
    _replace(report_texts(project, result, paths), out_dir, durable=False)


_WRITERS = {"out": out_text, "res": res_text, "sigma": sigma_text, "json": results_json,
            "observations": observations_csv}


def report_texts(project: Project, result: Adjustment,
                 paths: dict[str, pathlib.Path]) -> dict[pathlib.Path, str]:
    """The text of each report of `paths` (`report_paths`: by kind), by its path."""
    # The residuals, statistics and point tables gathered once; the collector paused while
    # hundreds of thousands of rows are formatted (none of them in a cycle).
    with shared_tables(), paused_gc():
        return {path: _WRITERS[kind](project, result) for kind, path in paths.items()}


def _replace(texts: dict[pathlib.Path, str], out_dir, *, durable: bool) -> None:
    pathlib.Path(out_dir).mkdir(parents=True, exist_ok=True)
    replace_files(texts, durable=durable)
