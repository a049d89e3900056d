"""The peers of ``benchmarks/compare.py`` build their solvers in ``setup``, never inside the timed ``run``.

peeljax's compilation is kept out of its timings, so every peer's one-time set-up must be too
(CasADi's integrator, CVODE's solver object, a JAX or numba compilation). Constructions are
counted here by wrapping the constructors. JAX compilations are counted by ``compare.py`` itself,
in every run, from JAX's own compile events (``compiles_in_run``): ``tests/test_compare_script.py``
asserts none for its JAX peers in the smoke run, which compiles them anyway.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

casadi = pytest.importorskip("casadi")
cvode_module = pytest.importorskip("sksundae.cvode")
pytest.importorskip("numba")

RTOL = 1e-4


@pytest.fixture
def constructions(monkeypatch):
    """Counts of ``casadi.integrator`` and ``sksundae.cvode.CVODE`` constructions."""
    counts = {"casadi.integrator": 0, "CVODE": 0}
    integrator, CVODE = casadi.integrator, cvode_module.CVODE

    def counted_integrator(*args, **kwargs):
        counts["casadi.integrator"] += 1
        return integrator(*args, **kwargs)

    def counted_cvode(*args, **kwargs):
        counts["CVODE"] += 1
        return CVODE(*args, **kwargs)

    monkeypatch.setattr(casadi, "integrator", counted_integrator)
    monkeypatch.setattr(cvode_module, "CVODE", counted_cvode)
    return counts


def _peers():
    from peers.casadi_peer import CasadiPeer
    from peers.sundials_peer import CvodePeer

    return [CasadiPeer(0.1, [RTOL]), CasadiPeer(0.1, [RTOL], log_v=True), CvodePeer(0.1, [RTOL], log_v=True)]


@pytest.mark.slow
def test_p1_peers_construct_their_solver_in_setup_only(constructions):
    from compare_problems import GRID

    for peer in _peers():
        peer.prepare()
        before = dict(constructions)
        peer.setup(RTOL)
        built = {k: constructions[k] - before[k] for k in constructions}
        assert sum(built.values()) == 1, (peer.name, built)  # setup builds the one solver it needs
        after_setup = dict(constructions)
        v1, v2 = peer.run(RTOL), peer.run(RTOL)
        assert constructions == after_setup, f"{peer.name}: run() constructed a solver"
        assert v1.shape == GRID.shape and np.all(np.isfinite(v1))
        np.testing.assert_array_equal(v1, v2)  # a reused solver object gives the same answer every call


@pytest.mark.slow
def test_p3_loops_construct_one_solver_per_rtol(constructions):
    from peers.casadi_peer import CasadiBatch
    from peers.sundials_peer import CvodeBatch

    for batch in (CasadiBatch(), CvodeBatch()):
        batch.setup(RTOL)
        after_setup = dict(constructions)
        first = batch(1.1, 0.1, RTOL)
        for Vp, tau in ((2.0, 0.05), (4.0, 0.5)):
            batch(Vp, tau, RTOL)
        assert constructions == after_setup, f"{type(batch).__name__}: a call constructed a solver"
        np.testing.assert_allclose(batch(1.1, 0.1, RTOL), first, rtol=0, atol=0)  # (V, τ) set per call, not stale
        assert RTOL in batch.setup_seconds
