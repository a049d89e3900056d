"""``benchmarks/studies/vmap_lane_cost.py`` keeps working (its numbers are not asserted: speed is a benchmark)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PEERS = (
    "peeljax.sweep (all lanes, every core)",
    "peeljax.simulate loop",
    "scipy LSODA events loop",
    "SUNDIALS CVODE (BDF) + rootfinding loop",
    "CasADi cvodes + events loop",
)


@pytest.mark.slow
def test_vmap_lane_cost_tiny_writes_every_peer_row(tmp_path):
    out = tmp_path / "vmap_lane_cost.md"
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "studies" / "vmap_lane_cost.py"), "--tiny", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    text = out.read_text()
    table = text[text.index("| method | rtol |") : text.index("The sweep at rtol")]
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| method")]
    for peer in PEERS:
        row = next((line for line in rows if line.startswith(f"| {peer} |")), None)
        assert row is not None, peer
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        assert len(cells) == 12, row
        # a timed row has its core-seconds per lane; CasADi's experimental events may fail (at every
        # rung, or on a timed lane), and then its row says so instead
        timed = cells[6].replace(".", "").replace("e-", "").isdigit() and cells[8].endswith("×")
        failed = peer.startswith("CasADi") and ("not reached" in row or "failed on the timed lanes" in row)
        assert timed or failed, row
    assert "| peeljax.sweep (all lanes, every core) |" in table and "| 1× |" in table
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["n_v"] == 4 and len(data["tiers"]) == 2  # every calibration V, then one left out
    assert data["timings"][data["tiers"][0]["checks"]["sweep"]["timing_key"]]["lanes"] == 4
    assert text.splitlines()[0] == f"Made by `{data['command']}`." and "--tiny" in data["command"]
    # the report remade from the JSON alone is the same, header included (in this process: no JAX needed)
    sys.path.insert(0, str(ROOT / "benchmarks" / "studies"))
    import vmap_lane_cost

    again = tmp_path / "again.md"
    vmap_lane_cost.main(["--report-only", str(out.with_suffix(".json")), "--out", str(again)])
    assert again.read_text() == text
