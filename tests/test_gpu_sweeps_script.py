"""``benchmarks/gpu_sweeps.py`` (the V-map at 10⁴–10⁶ lanes and P3 at 1024 on one GPU) runs:
its ``--smoke`` sizes on a CPU, writing its table with the device named. Its numbers are a
benchmark's, not asserted."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_gpu_script_smoke_runs_on_a_cpu(tmp_path):
    out = tmp_path / "gpu_sweeps_smoke.md"
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "gpu_sweeps.py"), "--smoke", "--out", str(out)],
        check=True, capture_output=True, text=True, timeout=900, cwd=ROOT,
    )  # fmt: skip
    text = out.read_text()
    assert text.startswith(f"Made by `python benchmarks/gpu_sweeps.py --smoke --out {out}`.")
    assert "Device: CPU" in text
    rows = {
        match[0]: match
        for match in re.findall(
            r"^\| (V-map, \d+ lanes|P3, \d+ lanes) \| (\d+) \|[^|]*\|[^|]*\|[^|]*\| (\d+) \|", text, re.M
        )
    }
    assert set(rows) == {"V-map, 16 lanes", "V-map, 64 lanes", "P3, 8 lanes"}
    for case, _, completed in rows.values():
        assert int(completed) == int(case.split(", ")[1].split()[0]), case  # every lane reached t_final
