"""``benchmarks/compare.py`` keeps working (its numbers are not asserted: speed is a benchmark)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_compare_smoke_runs_every_peer(tmp_path):
    out = tmp_path / "latest.md"
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "compare.py"), "--smoke", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    text = out.read_text()
    assert (tmp_path / "work_precision_smoke.png").stat().st_size > 0
    for peer in ("peeljax α-method", "numba α-method", "diffrax Kvaerno5", "scipy Radau", "SUNDIALS CVODE", "CasADi cvodes"):
        assert f"| {peer}" in text, peer
    lines = text.splitlines()
    # Every peer of the bench extra is installed with the test extra; only PETSc (petsc4py, run by
    # another interpreter) may be missing, and then its row says so cleanly.
    petsc_rows = [line for line in lines if line.startswith("| PETSc")]
    assert len(petsc_rows) == 1, petsc_rows
    assert "unavailable" not in "\n".join(line for line in lines if not line.startswith("| PETSc"))
    unavailable = "unavailable: petsc4py not installed (" in petsc_rows[0] and "not run here" in petsc_rows[0]
    ran = "TSALPHA" in petsc_rows[0] and "| N = 300 |" in petsc_rows[0]
    assert unavailable or ran, petsc_rows[0]
    peeljax_rows = [line for line in lines if line.startswith("| peeljax α-method | N = 300 |")]
    assert peeljax_rows and "| ok |" in peeljax_rows[0]

    # (P3) the batch: every method has a row with a time and a ratio to peeljax, and the targets are stated.
    p3 = text[text.index("## (P3) a batch of 8 trajectories") : text.index("## (P4)")]
    for method in ("peeljax.sweep", "diffrax Kvaerno5 under jax.vmap", "SUNDIALS CVODE", "CasADi cvodes", "scipy Radau"):
        row = next(line for line in p3.splitlines() if line.startswith(f"| {method}"))
        assert row.rstrip().endswith("|") and row.split("|")[-2].strip().replace(".", "").isdigit(), row
    assert "Targets (issue 6): peeljax ≥ 10× faster than diffrax under vmap:" in p3

    # (P4) the gradient: peeljax, finite differences and CasADi's forward sensitivities ran and were checked.
    p4 = text[text.index("## (P4) the gradient of a trajectory loss") : text.index("## (P5)")]
    for method in ("peeljax reverse mode", "central differences of peeljax", "CasADi cvodes (log v), forward"):
        row = next(line for line in p4.splitlines() if line.startswith(f"| {method}"))
        assert "| ok |" in row, row
    assert "Targets (issue 6), at equal gradient error:" in p4
