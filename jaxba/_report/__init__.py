"""Reports of an adjustment: BASC-style text files, results.json, observations.csv, the
plots and the HTML page.

Plain Python and NumPy around the adjusted result; the jitted core never imports this. The
report files of a project and their checks (`report_paths`, `check_outputs`) need no jax;
the rest is imported when first used. The file handling they share with the readers and the
command line (`replace_files`, `output_lock`, `OutputError`) is `jaxba._files`.
"""

from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._console": ("iteration_line", "start_line", "summary_lines", "warning_lines"),
    "._csv": ("observations_csv", "read_observations"),
    "._figure_files": ("write_figures",),
    "._html": ("html_report", "png_bytes"),
    "._json": ("results_dict", "results_json"),
    "._outputs": ("OBSERVATIONS_FILE", "check_outputs", "html_path", "report_paths"),
    "._text": ("out_text", "res_text", "sigma_text"),
    "._uncertainty": ("write_uncertainty",),
    "._write": ("write_batch_reports", "write_reports"),
})
