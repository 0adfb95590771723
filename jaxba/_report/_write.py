"""Write the report files of an adjustment, never over an input file."""

import pathlib

from .._project import Project, ProjectSpec
from .._solve import Adjustment
from ._csv import OBSERVATIONS_FILE, observations_csv
from ._json import results_json
from ._text import out_text, res_text, sigma_text


class OutputError(ValueError):
    """A report file cannot be written where asked (it would replace an input file, ...)."""


def report_paths(spec: ProjectSpec, out_dir) -> dict[str, pathlib.Path]:
    """The report files of a project in `out_dir`: NAME.out, NAME.res, NAME.sigma, results.json
    and observations.csv."""
    out_dir = pathlib.Path(out_dir)
    return {
        "out": out_dir / f"{spec.name}.out",
        "res": out_dir / f"{spec.name}.res",
        "sigma": out_dir / f"{spec.name}.sigma",
        "json": out_dir / "results.json",
        "observations": out_dir / OBSERVATIONS_FILE,
    }


def check_outputs(spec: ProjectSpec, out_dir) -> dict[str, pathlib.Path]:
    """`report_paths`, after checking that none of them is an input file or a folder.

    Raises `OutputError` naming the file; call it before adjusting to fail early.
    """
    out_dir = pathlib.Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: output folder is not a folder")
    inputs = {pathlib.Path(path).resolve() for path in spec.input_files}
    paths = report_paths(spec, out_dir)
    for path in paths.values():
        if path.resolve() in inputs:
            raise OutputError(
                f"{path}: report file would overwrite an input file of project"
                f" {spec.name!r}; choose another output folder (--out) or rename the input"
            )
        if path.is_dir():
            raise OutputError(f"{path}: report file name is taken by a folder")
    return paths


def write_reports(project: Project, result: Adjustment, out_dir) -> list[pathlib.Path]:
    """Write NAME.out, NAME.res, NAME.sigma, results.json and observations.csv into `out_dir`
    (created if needed).

    NAME is the project name. Nothing is written if any target is an input file of the
    project (`OutputError`). Returns the written paths.
    """
    paths = check_outputs(project.spec, out_dir)
    texts = {
        "out": out_text(project, result),
        "res": res_text(project, result),
        "sigma": sigma_text(project, result),
        "json": results_json(project, result),
        "observations": observations_csv(project, result),
    }
    pathlib.Path(out_dir).mkdir(parents=True, exist_ok=True)
    for key, text in texts.items():
        paths[key].write_text(text, encoding="utf-8")
    return list(paths.values())
