"""Where the reports of a project go, checked before anything is computed (no jax here)."""

import os
import pathlib
from collections.abc import Iterable

from .._files._paths import check_folder, check_targets, resolved
from .._project._spec import ProjectSpec

OBSERVATIONS_FILE = "observations.csv"

# The reports of a project by kind: NAME.out, NAME.res, NAME.sigma, results.json,
# observations.csv (`report_paths`).
REPORTS = ("out", "res", "sigma", "json", "observations")
# The sets `jaxba batch --reports` writes: "compact" leaves out the two files with a row per
# observation (NAME.res and observations.csv: most of the bytes and of the formatting).
REPORT_SETS = {"all": REPORTS, "compact": ("out", "sigma", "json")}


def report_paths(name: str, out_dir, kinds: tuple[str, ...] = REPORTS) -> dict[str, pathlib.Path]:
    """The report files of the project `name` in `out_dir` by kind (`REPORTS`: NAME.out,
    NAME.res, NAME.sigma, results.json and observations.csv), those of `kinds` only."""
    out_dir = pathlib.Path(out_dir)
    paths = {
        "out": out_dir / f"{name}.out",
        "res": out_dir / f"{name}.res",
        "sigma": out_dir / f"{name}.sigma",
        "json": out_dir / "results.json",
        "observations": out_dir / OBSERVATIONS_FILE,
    }
    return {kind: paths[kind] for kind in kinds}


def report_kinds(name: str) -> tuple[str, ...]:
    """The report kinds of the set `name` (`REPORT_SETS`); ValueError naming the sets."""
    if name not in REPORT_SETS:
        raise ValueError(f"reports {name!r}: one of {', '.join(REPORT_SETS)}")
    return REPORT_SETS[name]


def html_path(spec: ProjectSpec, out_dir) -> pathlib.Path:
    """The HTML report of a project in `out_dir`: NAME.html."""
    return pathlib.Path(out_dir) / f"{spec.name}.html"


def check_outputs(
    spec: ProjectSpec, out_dir, *, inputs: Iterable[os.PathLike] = ()
) -> dict[str, pathlib.Path]:
    """`report_paths`, after checking that `out_dir` is writable (`check_folder`) and that
    no report is an input file of the project (or one of `inputs`, e.g. those of the other
    projects of a batch, best as one `resolved` set for them all) or a folder.

    Raises `OutputError` naming the file; call it before adjusting to fail early.
    """
    return check_named_outputs(spec.name, spec.input_files, out_dir, inputs=inputs)


def check_named_outputs(
    name: str, input_files: Iterable[os.PathLike], out_dir, *,
    inputs: Iterable[os.PathLike] = (),
) -> dict[str, pathlib.Path]:
    """`check_outputs` of the project `name` whose files are `input_files` (its spec's
    `input_files`, or its `read_project_file`'s before its tables are read)."""
    check_folder(out_dir)
    paths = report_paths(name, out_dir)
    inputs = inputs if isinstance(inputs, frozenset) else resolved(inputs)
    check_targets(paths.values(), resolved(input_files) | inputs, f"project {name!r}")
    return paths
