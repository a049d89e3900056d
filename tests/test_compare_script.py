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
    assert "unavailable" not in text  # every peer of the bench extra is installed with the test extra
    peeljax_rows = [line for line in text.splitlines() if line.startswith("| peeljax α-method | N = 300 |")]
    assert peeljax_rows and "| ok |" in peeljax_rows[0]
