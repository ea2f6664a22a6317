"""The tutorial notebook (jupytext percent format) runs headless from top to bottom without an error."""

from pathlib import Path

import pytest

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "mapping_tutorial.py"


def test_tutorial_notebook_executes(monkeypatch):
    # the kernel (a process of its own) compiles as a user's Python would, at XLA's defaults, whatever XLA_FLAGS
    # the tests run with
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    nb = jupytext.read(NOTEBOOK)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()  # raises CellExecutionError, naming the cell, on any error
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert "effective sample size" in text and "wrong visible cells" in text
    assert len(images) >= 8  # the figures are really drawn
