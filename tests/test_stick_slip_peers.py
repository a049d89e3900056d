"""``benchmarks/stick_slip.py`` (P6) and its peers (``benchmarks/peers/jump_peers.py``): selection, rows, targets.

Speed is a benchmark, never asserted; the one slow test checks that the compiled while-loop
peer (diffrax issue #492's recipe) finds every jump of the reference.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import stick_slip  # noqa: E402
from peers.jump_peers import SOLVERS, DiffraxWhileLoop, PeeljaxDAE, jump_reference, solver_named  # noqa: E402


def test_peeljax_rows_name_their_stepper():
    assert PeeljaxDAE([1e-6]).name == "peeljax simulate(tau=0)"
    assert PeeljaxDAE([1e-6], solver="tsit5").name == "peeljax simulate(tau=0, tsit5)"
    with pytest.raises(ValueError, match="unknown solver"):
        PeeljaxDAE([1e-6], solver="rk4")
    import diffrax

    import peeljax

    assert solver_named(None) is None
    assert isinstance(solver_named("alpha"), peeljax.AlphaMethod)
    for name, cls in (("tsit5", diffrax.Tsit5), ("dopri5", diffrax.Dopri5), ("dopri8", diffrax.Dopri8)):
        assert isinstance(solver_named(name), cls)
    assert set(SOLVERS) == {"alpha", "tsit5", "dopri5", "dopri8", "kvaerno5"}


def test_every_peer_and_the_selection():
    peers = stick_slip.all_peers()
    assert next(iter(peers)) == "peeljax"
    for key in ("peeljax_tsit5", "peeljax_dopri5", "peeljax_dopri8"):
        assert peers[key].settings == peers["tsit5"].settings == list(stick_slip.LADDERS["fine"])
    assert peers["while_loop"].name == "diffrax Tsit5 + Event, one lax.while_loop"
    chosen = [k for k, p in peers.items() if stick_slip.selected(["while_loop", "lsoda events"], k, p.name)]
    assert chosen == ["lsoda", "lsoda_refined", "while_loop"]
    assert all(stick_slip.selected(None, k, p.name) for k, p in peers.items())


def _rung(rtol, error, median):
    return {"rtol": rtol, "status": "ok", "error": error, "median_s": median, "stats": {}}


def test_targets_state_both_ratios():
    checks = {
        "peeljax": {"name": "peeljax simulate(tau=0)", "rungs": [_rung(1e-6, 5e-6, 0.01), _rung(1e-7, 5e-7, 0.02)]},
        "lsoda": {"name": "scipy LSODA events", "rungs": [_rung(1e-7, 4e-6, 0.5), _rung(1e-9, 8e-7, 0.3)]},
        "while_loop": {"name": DiffraxWhileLoop([]).name, "rungs": [_rung(1e-7, 4e-6, 0.05)]},
    }
    data = {"checks": checks, "targets": (1e-6, 1e-5), "masses": []}
    text = "\n".join(stick_slip.targets(data))
    line_5 = next(line for line in text.splitlines() if line.startswith("* Every jump within 1e-05 s"))
    assert "(a) **met**" in line_5 and "= 5× peeljax's (needs ≥ 3×)" in line_5
    assert "(b) **met**" in line_5 and "= 50× peeljax's (needs ≥ 20×)" in line_5
    line_6 = next(line for line in text.splitlines() if line.startswith("* Every jump within 1e-06 s"))
    assert "(a) not decided" in line_6 and "(b) **missed**" in line_6 and "= 15× peeljax's" in line_6
    quick = "\n".join(stick_slip.targets({**data, "targets": (1e-5,)}))
    assert "1e-06 s: not measured in this run" in quick


@pytest.mark.slow
def test_the_while_loop_peer_finds_every_jump():
    # Over [0, 0.5] s: the first stick → slip and 15 more cycles, 32 jumps (P6's 3 s hold 210; the
    # restarts are the same, and the reference and the run take a sixth of the time).
    ref = jump_reference()
    reference = ref.reference_jump_run(1.1, 0.5, rtol=1e-12, atol=1e-14, method="LSODA")["jump_t"]
    peer = DiffraxWhileLoop([1e-8], t_final=0.5)
    peer.prepare()
    jumps = peer.run(1e-8)
    assert jumps.size == reference.size == 32
    assert np.max(np.abs(jumps - reference)) < 2e-6
    stats = peer.run_stats(1e-8)
    assert stats["restarts"] == 32 and stats["accepted_steps"] > 500 and stats["rejected_steps"] >= 0
