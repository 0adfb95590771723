"""The notebooks run from top to bottom without an error (executed in memory, files untouched)."""

import pathlib

import nbclient
import nbformat
import pytest

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
TIMEOUT_S = 600  # per cell


PLOTTING = {"01_calibrate_lab.ipynb", "02_statistics.ipynb", "03_batch.ipynb",
            "04_differentiable.ipynb"}


@pytest.mark.parametrize("name", [
    "01_calibrate_lab.ipynb",
    "02_statistics.ipynb",
    "05_zhang_vs_opencv.ipynb",
    pytest.param("06_dbat_camcal.ipynb", marks=pytest.mark.slow),  # ~10 s: 4148 observations
    pytest.param("03_batch.ipynb", marks=pytest.mark.slow),  # ~15 s: 8 projects, one batch
    pytest.param("04_differentiable.ipynb", marks=pytest.mark.slow),  # ~20 s: 3 compilations
    pytest.param("07_start_from_nothing.ipynb", marks=pytest.mark.slow),  # ~12 s: 2 compiles
])
def test_notebook_runs(name):
    notebook = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=TIMEOUT_S, kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOKS)}},
    )
    client.execute()  # raises CellExecutionError, naming the cell, on any error
    errors = [
        output for cell in notebook.cells if cell.cell_type == "code"
        for output in cell.outputs if output.output_type == "error"
    ]
    assert not errors
    images = [
        output for cell in notebook.cells if cell.cell_type == "code"
        for output in cell.outputs if "image/png" in output.get("data", {})
    ]
    assert images or name not in PLOTTING, "the plots show inline"
