"""Reports of an adjustment: BASC-style text files, results.json (FORMATS.md), observations.csv.

Plain Python and NumPy around the adjusted result; the jitted core never imports this.
"""

from ._console import iteration_line, start_line, summary_lines
from ._csv import OBSERVATIONS_FILE, observations_csv, read_observations
from ._json import results_dict, results_json
from ._text import out_text, res_text, sigma_text
from ._write import OutputError, check_outputs, report_paths, write_reports

__all__ = [
    "OBSERVATIONS_FILE", "OutputError", "check_outputs", "iteration_line", "observations_csv",
    "out_text", "read_observations", "report_paths", "res_text", "results_dict", "results_json",
    "sigma_text", "start_line", "summary_lines", "write_reports",
]
