"""peeljax.least_tau: τ* completes, τ*·(1 − tau_rtol) stops, and the paper's ordering over V.

Steps used (docs/sweeps.md): dt = 1/82 s at every V (the paper's step at V = 1.1) over
t_final = 1 s; measured τ* ≈ 4.8e-3 (V = 1.1), 1.7e-3 (V = 2), 1.2e-4 (V = 4).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import peeljax
from peeljax import simulate
from peeljax.sweeps import engine
from peeljax.sweeps.least_tau import _bracket

DT, T_FINAL, RTOL = 1 / 82, 1.0, 0.05


@pytest.fixture(scope="module")
def paper():
    return peeljax.least_tau(V=[1.1, 2.0, 4.0], dt=DT, t_final=T_FINAL, tau_range=(1e-5, 1.0), tau_rtol=RTOL, n_points=8)


@pytest.mark.slow
def test_found_for_every_V(paper):
    assert paper.found.all(), paper
    assert paper.rounds <= 8
    assert np.all(paper.tau_below < paper.tau_star)
    assert np.all(paper.tau_below >= paper.tau_star * (1 - RTOL) * (1 - 1e-12))


@pytest.mark.slow
def test_tau_star_completes_and_below_stops(paper):
    for V, tau_star in zip(paper.V, paper.tau_star):
        at = simulate(None, V, tau_star, DT, T_FINAL)
        below = simulate(None, V, tau_star * (1 - RTOL), DT, T_FINAL)
        assert int(at.status) == 0, (V, tau_star, at.reason)
        assert int(below.status) != 0, (V, tau_star)
        assert float(below.t_stop) < T_FINAL


@pytest.mark.slow
def test_every_tested_tau_above_tau_star_completes(paper):
    for tested, tau_star in zip(paper.tested, paper.tau_star):
        above = [done for tau, (done, _) in tested if tau >= tau_star]
        assert above and all(above)
        assert any(not done for tau, (done, _) in tested if tau < tau_star)


@pytest.mark.slow
def test_paper_ordering(paper):
    """The paper (Figs. 2, 5, 7): the least τ at V = 1.1 and 2 is larger than at V = 4."""
    tau_11, tau_2, tau_4 = paper.tau_star
    assert tau_11 > tau_4 and tau_2 > tau_4
    assert tau_11 > tau_2  # also measured: the least τ decreases with V here


def test_bracket_rules():
    # a stop above a completion (non-monotone): τ* is above the largest stop
    history = {1e-4: (False, 0.1), 1e-3: (True, 1.0), 2e-3: (False, 0.5), 4e-3: (True, 1.0), 1e-2: (True, 1.0)}
    lower, upper, t_below, verdict = _bracket(history, 0.05)
    assert (lower, upper, t_below, verdict) == (2e-3, 4e-3, 0.5, None)
    history[4e-3 * 0.95] = (False, 0.7)
    assert _bracket(history, 0.05)[3] is True
    history[4e-3 * 0.95] = (True, 1.0)  # completes: the new bracket is (2e-3, 3.8e-3)
    assert _bracket(history, 0.05)[:2] == (2e-3, 4e-3 * 0.95)
    # a bracket tighter than tau_rtol whose τ*·(1 − tau_rtol) completes below a stop: cannot be resolved
    tight = {1e-3: (False, 0.2), 1.02e-3: (True, 1.0), 1.02e-3 * 0.95: (True, 1.0)}
    assert _bracket(tight, 0.05) == (1e-3, 1.02e-3, 0.2, False)
    everything = {1e-3: (True, 1.0), 1e-2: (True, 1.0)}
    lower, upper, _, verdict = _bracket(everything, 0.05)
    assert math.isnan(lower) and upper == 1e-3 and verdict is False
    nothing = {1e-3: (False, 0.1), 1e-2: (False, 0.2)}
    lower, upper, _, verdict = _bracket(nothing, 0.05)
    assert lower == 1e-2 and math.isnan(upper) and verdict is False


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"V": []}, "V is empty"),
        ({"V": [1.1, -2.0]}, "V must be > 0"),
        ({"tau_range": (1e-2, 1e-3)}, "tau_range"),
        ({"tau_range": (0.0, 1.0)}, "tau_range"),
        ({"tau_rtol": 1.5}, "tau_rtol"),
        ({"n_points": 1}, "n_points"),
        ({"dt": -1.0}, "dt must be > 0"),
    ],
)
def test_bad_input_rejected_before_compiling(kwargs, match, monkeypatch):
    monkeypatch.setattr(engine, "run_batch", lambda *a, **k: pytest.fail("must not run"))
    options = {"V": [1.1], "dt": DT, "t_final": T_FINAL}
    options.update(kwargs)
    with pytest.raises(ValueError, match=match):
        peeljax.least_tau(**options)
