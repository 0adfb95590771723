"""Write the report files of an adjustment, never over an input file, all or none."""

import os
import pathlib
import tempfile

from .._project._build import Project
from .._solve import Adjustment
from ._csv import observations_csv
from ._json import results_json
from ._paths import check_outputs
from ._text import out_text, res_text, sigma_text


def write_reports(project: Project, result: Adjustment, out_dir) -> list[pathlib.Path]:
    """Write NAME.out, NAME.res, NAME.sigma, results.json and observations.csv into `out_dir`
    (created if needed).

    NAME is the project name. Nothing is written if any target is an input file of the
    project (`OutputError`). Every file is first written completely under a temporary name
    in `out_dir`, then all are renamed over the old reports: a run that fails while writing
    (a full disk, an interrupt) leaves the previous reports as they were. Returns the paths.
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
    written = {}
    try:
        for key, text in texts.items():
            handle, name = tempfile.mkstemp(dir=out_dir, prefix=f".{paths[key].name}.")
            written[key] = pathlib.Path(name)
            with os.fdopen(handle, "w", encoding="utf-8") as file:
                file.write(text)
    except BaseException:
        for temporary in written.values():
            temporary.unlink(missing_ok=True)
        raise
    for key, temporary in written.items():
        os.replace(temporary, paths[key])
    return list(paths.values())
