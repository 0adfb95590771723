"""Reports of an adjustment: BASC-style text files, results.json, observations.csv, the
plots and the HTML page.

Plain Python and NumPy around the adjusted result; the jitted core never imports this. The
output checks (`check_outputs`, `OutputError`), the output folder's lock (`output_lock`) and
`replace_files` need no jax; the rest is imported when first used.
"""

from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._atomic": ("replace_files",),
    "._console": ("iteration_line", "start_line", "summary_lines", "warning_lines"),
    "._csv": ("observations_csv", "read_observations"),
    "._figure_files": ("write_figures",),
    "._html": ("html_report", "png_bytes"),
    "._json": ("results_dict", "results_json"),
    "._lock": ("output_lock",),
    "._paths": ("OBSERVATIONS_FILE", "OutputError", "check_folder", "check_outputs",
                "check_targets", "html_path", "report_paths"),
    "._text": ("out_text", "res_text", "sigma_text"),
    "._uncertainty": ("write_uncertainty",),
    "._write": ("write_batch_reports", "write_reports"),
})
