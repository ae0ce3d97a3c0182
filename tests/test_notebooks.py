"""The notebooks run top to bottom in a real Jupyter kernel, at a small iteration count
(``SWARMCURVES_ITERATIONS``), with one paper case per figure
(``SWARMCURVES_CASES_PER_FIGURE``: every case compiles its own program, and all 42 took
most of the suite's time) and at most 8 control points besides the count a figure shows
(``SWARMCURVES_MAX_CPS``: Table 1's 4-25 at two degrees took a quarter of the notebook's
time, and the open cubics of Figs. 2, 3 and 7 then share one program), so what they show
keeps working.  The paper-figures notebook fits with the pure swarm
(``SWARMCURVES_REFINE=none``): a polish program per case took nearly half its time (this
test alone 42-45 s with them, 24 s without), and the polish has tests of its own; the
quickstart polishes, as a user's first fit does."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from swarmcurves_jax.paper import paper_cases

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
ITERATIONS = "60"


@pytest.mark.parametrize("name", ["quickstart.ipynb", "paper_figures.ipynb"])
def test_notebook_runs_top_to_bottom(name, monkeypatch):
    monkeypatch.setenv("SWARMCURVES_ITERATIONS", ITERATIONS)
    monkeypatch.setenv("SWARMCURVES_CASES_PER_FIGURE", "1")
    monkeypatch.setenv("SWARMCURVES_MAX_CPS", "8")
    monkeypatch.setenv("SWARMCURVES_REFINE", "none")  # the paper figures' pure swarm
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
    text = "".join(o.get("text", "") for o in outputs)
    if name == "quickstart.ipynb":
        assert "sparsest" in text
    else:  # one case per figure, each fitted and drawn
        figures = {case.figure for case in paper_cases()[0]}
        assert text.count("best degree") == len(figures), text
        assert len(images) == len(figures) + 1  # a figure per case and the Table 1 panel
