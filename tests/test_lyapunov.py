"""Lyapunov exponents through the jumps (peeljax.lyapunov): against the Floquet multipliers of the
periodic orbit, and bad input refused before anything compiles."""

import jax
import numpy as np
import pytest

import peeljax as pj
from peeljax.model import PAPER_ALPHA0


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"V": 0.0}, "V must"),
        ({"V": np.array([1.0, 2.0])}, "V must be one pull velocity"),
        ({"n": 4}, r"n must be an integer in \[1, 3\]"),
        ({"n": 0}, r"n must be an integer in \[1, 3\]"),
        ({"segment": 0.0}, "segment must"),
        ({"segment": 20.0, "t_total": 10.0}, r"segment must lie in \(0, t_total\]"),
        ({"t_transient": -1.0}, r"t_transient must be a number in \[0, inf\)"),
        ({"rtol": -1e-6}, "rtol must"),
        ({"y0": [0.0, 0.0, 0.0, -1.0]}, "y0"),
    ],
)
def test_bad_input_is_refused_before_compiling(options, match, monkeypatch):
    monkeypatch.setattr(pj.lyapunov, "_on_lanes", None)  # nothing may run
    with pytest.raises(ValueError, match=match):
        pj.lyapunov_exponents(**options)


def test_tau_is_not_an_option():
    with pytest.raises(TypeError):
        pj.lyapunov_exponents(V=1.1, tau=0.01)


@pytest.mark.slow
def test_exponents_of_the_periodic_orbit_are_its_floquet_exponents():
    """λ₁ = 0 (the flow), λ₂,₃ = ln|μ₁,₂|/T: the tangents carried through ~7000 jumps by the run's
    own derivative agree with the shooting's monodromy."""
    result = pj.lyapunov_exponents(V=1.1, n=3, t_total=100.0)
    assert result.status == pj.StopReason.COMPLETED and np.isnan(result.stopped_at)
    assert result.history.shape == (200, 3) and result.t[-1] == pytest.approx(100.0)
    orbit = pj.periodic_orbit(V=1.1)
    floquet = np.log(np.abs(np.asarray(orbit.multipliers))) / float(orbit.period)
    lam, se = np.asarray(result.exponents), np.asarray(result.standard_error)
    assert abs(lam[0]) <= max(3 * se[0], 0.05)
    np.testing.assert_allclose(lam[1:], floquet, rtol=0.01)  # measured: 0.4 % and 0.02 %
    assert np.all(np.diff(lam) < 0)
    # the estimate converges: the last half moves λ₂ less than the first tenth's spread
    history = np.asarray(result.history)
    assert abs(history[-1, 1] - history[100, 1]) < abs(history[19, 1] - floquet[0])


@pytest.mark.slow
def test_steady_peeling_exponents_are_those_of_its_linearization():
    """On steady peeling the run's tangents are not the flow's (module docstring): the exponents
    are the real parts of the eigenvalues of ∂ẋ/∂x there, here against central differences."""
    result = pj.lyapunov_exponents(V=0.2, n=3)
    assert result.steady and result.status == pj.StopReason.COMPLETED
    assert "steady peeling" in result.message and np.all(np.asarray(result.standard_error) == 0)
    y = np.asarray(pj.simulate(V=0.2, tau=0, t_final=10.0, ts=np.array([0.0, 10.0])).ys[-1])
    dae = pj.ConstrainedDAE(pj.PeelingModel(), 0.2).with_folds()
    rhs = lambda x: np.asarray(dae(np.concatenate([x, y[3:]]))[:3])  # noqa: E731
    h = 1e-6
    A = np.stack([(rhs(y[:3] + h * e) - rhs(y[:3] - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    expected = np.sort(np.linalg.eigvals(A).real)[::-1]
    np.testing.assert_allclose(np.asarray(result.exponents), expected, rtol=1e-5)  # -11.73 (twice), -74.70


@pytest.mark.slow
def test_a_stopped_transient_says_where_and_why():
    result = pj.lyapunov_exponents(V=1.1, max_steps=20)
    assert result.status == pj.StopReason.MAX_STEPS and result.stopped_at < 0
    assert np.all(np.isnan(np.asarray(result.exponents))) and result.history.shape == (0, 2)
    assert result.message.startswith("the transient stopped at t = ")


@pytest.mark.slow
def test_a_tangent_that_leaves_the_flow_stops_the_estimate():
    """At V = 4.9 the run's leading tangent and a nearby run part in the first segment (16.7×;
    before the two-reference tangential folds, 1e16 against ~200): the check stops the estimate
    and says why."""
    result = pj.lyapunov_exponents(V=4.9, t_total=10.0)
    assert result.status == pj.StopReason.COMPLETED and result.stopped_at >= 0
    assert "a run from a nearby state differ by a factor" in result.message
    assert result.why and result.history.shape[0] < 20  # stopped before its 20 segments


def test_a_new_V_compiles_nothing_new(caplog):
    """V is traced: exponents over many V reuse one compiled segment (V was a static argument,
    one compilation of ~8 s per V)."""
    import logging

    pj.lyapunov_exponents(V=1.1, t_total=1.0, t_transient=0.5)
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        pj.lyapunov_exponents(V=1.2, t_total=1.0, t_transient=0.5)
    # (the check can fail: a static V compiles the lanes' program again, named in the log)
    messages = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
    assert not [m for m in messages if "_on_lanes" in m], messages


@pytest.mark.slow
def test_lanes_in_one_batch_are_the_lanes_one_by_one():
    """lyapunov_spectra runs every lane's segments in one program per chunk (padded, dealt over
    the devices): each lane's exponents are those of its own lyapunov_exponents, a steady lane
    its linearization's and a lane whose transient stops says so."""
    model = pj.PeelingModel()
    V = np.array([1.1, 2.0, 0.2])
    y0 = np.stack([model.initial_state(1.1), model.initial_state(2.0), model.consistent_state(0.2, PAPER_ALPHA0, 0.2 / model.R, 0.2)])
    options = {"t_total": 2.0, "t_transient": 1.0}
    lanes = pj.lyapunov_spectra(V=V, y0=y0, chunk=2, **options)
    assert len(lanes) == 3
    for lane, v, y in zip(lanes, V, y0):
        alone = pj.lyapunov_exponents(V=float(v), y0=y, **options)
        assert lane.V == v and lane.steady == alone.steady and lane.status == alone.status
        np.testing.assert_allclose(lane.exponents, alone.exponents, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lane.standard_error, alone.standard_error, rtol=1e-9, atol=1e-12)
    assert lanes[2].steady and not lanes[0].steady
    stopped = pj.lyapunov_spectra(V=V[:2], max_steps=20, chunk=2, **options)
    assert all(r.stopped_at < 0 and r.status != pj.StopReason.COMPLETED for r in stopped)
    assert all("the transient stopped" in r.message for r in stopped)


def test_lanes_bad_input_is_refused_before_compiling(monkeypatch):
    monkeypatch.setattr(pj.lyapunov, "_on_lanes", None)  # nothing may run
    with pytest.raises(ValueError, match=r"y0 must be one state .* per V, shape \(2, 4\)"):
        pj.lyapunov_spectra(V=[1.0, 2.0], y0=np.ones((3, 4)))
    with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
        pj.lyapunov_spectra(V=[1.0], chunk=0)
    with pytest.raises(ValueError, match="V must"):
        pj.lyapunov_spectra(V=[1.0, -1.0])
