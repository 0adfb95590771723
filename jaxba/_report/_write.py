"""Write the report files of an adjustment, never over an input file."""

import pathlib

from .._project._build import Project
from .._solve import Adjustment
from ._json import results_json
from ._paths import check_outputs
from ._text import out_text, res_text, sigma_text


def write_reports(project: Project, result: Adjustment, out_dir) -> list[pathlib.Path]:
    """Write NAME.out, NAME.res, NAME.sigma and results.json into `out_dir` (created if needed).

    NAME is the project name. Nothing is written if any target is an input file of the
    project (`OutputError`). Returns the written paths.
    """
    paths = check_outputs(project.spec, out_dir)
    texts = {
        "out": out_text(project, result),
        "res": res_text(project, result),
        "sigma": sigma_text(project, result),
        "json": results_json(project, result),
    }
    pathlib.Path(out_dir).mkdir(parents=True, exist_ok=True)
    for key, text in texts.items():
        paths[key].write_text(text, encoding="utf-8")
    return list(paths.values())
