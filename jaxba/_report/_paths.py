"""Where the reports of a project go, checked before anything is computed (no jax here)."""

import pathlib

from .._project._spec import ProjectSpec

OBSERVATIONS_FILE = "observations.csv"


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
