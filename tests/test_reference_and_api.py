"""The diffrax reference and the Python API's input checks."""

from __future__ import annotations

import numpy as np
import pytest

import peeljax as pj
from peeljax.solution import StopReason

BAD_INPUT = [
    (dict(tau=0.0, dt=0.01), "tau"),  # τ = 0 (the DAE) runs with error control only (simulate_reference: τ > 0)
    (dict(tau=-1.0), "tau"),
    (dict(V=0.0), "V"),
    (dict(V=float("nan")), "V"),
    (dict(tau=float("inf")), "tau"),
    (dict(tau=1e7), "tau"),
    (dict(dt=0.0), "dt"),
    (dict(t_final=0.0), "t_final"),
    (dict(dt=4.0, t_final=3.0), "dt"),
    (dict(rho=1.0), "rho"),
    (dict(rho=-0.1), "rho"),
    (dict(y0=[0.0, 0.0, 0.1, 0.0]), "v"),
    (dict(y0=[0.0, 0.0, 0.1]), "y0"),
    (dict(truncation=-1), "truncation"),
]


@pytest.mark.parametrize(("kwargs", "name"), BAD_INPUT)
def test_bad_input_is_rejected_before_compilation(no_compilation, kwargs, name):
    with pytest.raises(ValueError, match=name):
        pj.simulate(**kwargs)


@pytest.mark.parametrize(("kwargs", "name"), [(k, n) for k, n in BAD_INPUT if "rho" not in k])
def test_reference_rejects_the_same_input(no_compilation, kwargs, name):
    with pytest.raises(ValueError, match=name):
        pj.simulate_reference(**kwargs)


def test_bad_model_parameter_and_geometry(no_compilation):
    with pytest.raises(ValueError, match="model.R"):
        pj.simulate(pj.PeelingModel(R=-0.1))
    with pytest.raises(ValueError, match="geometry"):
        pj.PeelingModel(geometry="round")


def test_mesh_ends_exactly_at_t_final():
    sol = pj.simulate(V=1.1, tau=0.1, dt=0.012195, t_final=0.5)
    assert float(sol.ts[-1]) == pytest.approx(0.5, abs=1e-15)
    assert float(sol.stats["step_size"]) == pytest.approx(0.5 / round(0.5 / 0.012195))


@pytest.mark.slow
def test_reference_detects_the_stall_at_an_impasse():
    """At τ = 1e-3, diffrax's step size collapses near t ≈ 0.17 s; it must stop, not spin to max_steps."""
    sol = pj.simulate_reference(V=1.1, tau=1e-3, dt=0.01, t_final=1.0, rtol=1e-8, atol=1e-10)
    assert int(sol.status) in (StopReason.STALLED, StopReason.MAX_STEPS, StopReason.SOLVER_FAILED)
    assert int(sol.status) == StopReason.STALLED, sol.reason
    assert 0.1 < float(sol.t_stop) < 0.25
    valid = np.asarray(sol.valid)
    assert np.all(np.isnan(np.asarray(sol.ys)[~valid])) and np.all(np.isfinite(np.asarray(sol.ys)[valid]))
    assert int(sol.stats["steps"]) < 200_000


@pytest.mark.slow
def test_reference_completes_and_settles_at_large_tau():
    sol = pj.simulate_reference(V=1.1, tau=0.1, dt=0.1, t_final=3.0)
    assert bool(sol.completed)
    assert abs(float(sol.v[-1]) - 1.1) < 1e-3
