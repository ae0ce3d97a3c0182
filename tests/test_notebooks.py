"""The notebooks run top to bottom in a real Jupyter kernel, at a small iteration count
(``SWARMCURVES_ITERATIONS``), so what they show keeps working."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
ITERATIONS = "60"


@pytest.mark.parametrize("name", ["quickstart.ipynb", "paper_figures.ipynb"])
def test_notebook_runs_top_to_bottom(name, monkeypatch):
    monkeypatch.setenv("SWARMCURVES_ITERATIONS", ITERATIONS)
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = NotebookClient(
        nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    )
    client.execute()  # raises CellExecutionError, with the cell and traceback, on any failure
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert images, f"{name} drew no figure"
    if name == "quickstart.ipynb":
        assert any("sparsest" in o.get("text", "") for o in outputs)
