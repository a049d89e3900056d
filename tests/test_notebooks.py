"""Notebooks 01–07 run top to bottom (nbclient, the ``notebooks`` extra; skipped without it).

CI sets ``PEELJAX_NOTEBOOK_T_FINAL=0.2`` so that every run is short (and the grids of 03 and the
fit of 04 small); outputs are not stored. Measured on 2 shared CPU cores: 03 about 1 min, 04
about 2.5 min (its trajectory fit compiles the gradient update twice).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "01_paper_figures.ipynb",
        "02_index_and_time_scales.ipynb",
        "03_sweeps.ipynb",
        "04_fitting_phi.ipynb",
        "05_stick_slip.ipynb",
        "06_orbits.ipynb",
        "07_attractor_map.ipynb",
    ],
)
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
