"""Notebooks 01 and 02 run top to bottom (nbclient, the ``notebooks`` extra; skipped without it).

CI sets ``PEELJAX_NOTEBOOK_T_FINAL=0.2`` so that every run is short; outputs are not stored.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["01_paper_figures.ipynb", "02_index_and_time_scales.ipynb"])
def test_notebook_runs(name, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    book = nbformat.read(NOTEBOOKS / name, as_version=4)
    assert all(not cell.get("outputs") for cell in book.cells if cell.cell_type == "code"), "stored with outputs"
    monkeypatch.setenv("PEELJAX_NOTEBOOK_T_FINAL", "0.2")
    client = nbclient.NotebookClient(
        book, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    )
    client.execute(env=dict(os.environ))
