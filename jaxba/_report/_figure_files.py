"""The report's figures written as files: PNG images and the HTML page that embeds them."""

import pathlib
from collections.abc import Callable

from .._files._atomic import replace_files
from ._html import html_report, png_bytes
from ._outputs import html_path


def write_figures(project, result, out_dir, *, plots: bool, html: bool,
                  warn: Callable[[str], None], uncertainty: dict | None = None
                  ) -> list[pathlib.Path]:
    """The report's figures (`figure_set`) as NAME.png files (`plots`) and NAME.html
    (`html`) with them embedded, in `out_dir`; each figure drawn once; `uncertainty`: the
    projection-uncertainty files already written (path -> content), for the HTML report's
    section.

    Never over an input: a figure whose file name is an input's is skipped with a warning
    (`warn`; NAME.html was checked before the run); the files replace the old ones together
    (`replace_files`).
    """
    from ._plots import figure_set

    out_dir = pathlib.Path(out_dir)
    inputs = {pathlib.Path(path).resolve() for path in project.spec.input_files}
    images = {figure.name: png_bytes(figure.make()) for figure in figure_set(project, result)}
    files = {}
    for name, image in images.items() if plots else ():
        path = out_dir / f"{name}.png"
        if path.resolve() in inputs:
            warn(f"--plots: {path} is an input file of the project; not written")
            continue
        files[path] = image
    if html:
        files[html_path(project.spec, out_dir)] = html_report(
            project, result, figures=images,
            uncertainty={path.name: content for path, content in (uncertainty or {}).items()})
    replace_files(files)
    return list(files)
