"""The speed guard (``benchmarks/guard.py``): it passes at CI's limits, and it fails on a real slowdown.

The ratios it measures are not asserted here beyond its own limits (speed is a benchmark); what
is tested is that the guard runs from a fresh process, compares with the committed limits, and
catches a gradient made twice as slow.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import jax
import pytest

ROOT = Path(__file__).resolve().parents[1]
GUARD = ROOT / "benchmarks" / "guard.py"


def _guard_module():
    spec = importlib.util.spec_from_file_location("speed_guard", GUARD)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_ratio_has_a_limit_and_ci_doubles_its_margin():
    guard = _guard_module()
    table = json.loads(guard.LIMITS.read_text())
    assert set(table) == {*guard.CHECKS, "compile"}
    for row in table.values():
        assert row["what"] and 0 < row["measured"] < row["limit"]
    ci = guard.limits_of(table, ci=True)
    for name, row in table.items():
        assert ci[name] - row["measured"] == pytest.approx(2 * (row["limit"] - row["measured"]))
    assert guard.broken({"fit_step": table["fit_step"]["limit"] * 1.01}, guard.limits_of(table, ci=False))


def _guard_passes_at_ci_limits(names, tmp_path):
    """The guard's ``names`` in a fresh process, as CI runs it: exit 0, every ratio under its CI limit."""
    out = tmp_path / "guard.json"
    done = subprocess.run(
        [sys.executable, str(GUARD), "--ci", "--repeats", "3", "--json", str(out), "--only", *names],
        capture_output=True, text=True, timeout=900, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(out.read_text())
    assert set(result["ratios"]) == set(names)
    for name, ratio in result["ratios"].items():
        assert 0 < ratio <= result["limits"][name], name


def test_the_guard_passes_at_ci_limits(tmp_path):
    """Every check but the two whose programs take longest to build (the slow tier's test below)."""
    guard = _guard_module()
    names = [name for name in (*guard.CHECKS, "compile") if name not in guard.LONGEST_SET_UP]
    _guard_passes_at_ci_limits(names, tmp_path)


@pytest.mark.slow
def test_the_guards_longest_checks_pass_at_ci_limits(tmp_path):
    """A fit step and the checkpointed gradient: together, every check runs in CI."""
    guard = _guard_module()
    assert set(guard.LONGEST_SET_UP) < set(guard.CHECKS)
    _guard_passes_at_ci_limits(guard.LONGEST_SET_UP, tmp_path)


def test_the_guard_fails_on_a_twice_slower_gradient(monkeypatch, capsys):
    """The gradient through jumps made twice as slow (each timed call computes it twice): the
    guard exits 1 naming that ratio."""
    guard = _guard_module()
    real = guard.gradient_through_jumps

    def slower():
        gradient, forward = real()

        def twice():
            jax.block_until_ready(gradient())  # not left to run beside the second on the other core
            return gradient()

        return twice, forward

    monkeypatch.setitem(guard.CHECKS, "gradient_through_jumps", slower)
    assert guard.main(["--only", "gradient_through_jumps", "--repeats", "3"]) == 1
    assert "gradient_through_jumps" in capsys.readouterr().err
