"""peeljax.alternatives: direct DAE integration fails at the maximum of φ; inertial regularization
keeps (sac) on the rising branch and leaves an O(1) residual in the slip jump.

Short windows (≤ 0.4 s) at V = 4 and 1.1; each run compiles one diffrax solve.
"""

from __future__ import annotations

import numpy as np
import pytest

from peeljax import StopReason
from peeljax.alternatives import constraint_report, integrate_index1, integrate_inertial, integrate_state_space
from peeljax.analysis import phi_extrema


@pytest.mark.slow
@pytest.mark.parametrize("V", [4.0])
def test_index1_ode_fails_at_the_maximum_of_phi(V):
    v_top, _ = phi_extrema(V=V)
    sol = integrate_index1(V=V, dt=1 / 8200, t_final=0.1, rtol=1e-6, atol=1e-8)
    assert int(sol.status) == StopReason.STALLED
    v = np.asarray(sol.v)[np.asarray(sol.valid)]
    # the step collapses where ∂φ/∂v → 0: at the first stick → slip point
    assert v[-1] == pytest.approx(v_top, rel=0.02)
    assert 0.06 < float(sol.t_stop) < 0.07


@pytest.mark.slow
def test_state_space_form_fails_at_the_fold_and_keeps_the_constraint():
    V = 4.0
    v_top, _ = phi_extrema(V=V)
    sol = integrate_state_space(V=V, dt=1 / 8200, t_final=0.1, rtol=1e-4, atol=1e-6)
    assert not bool(sol.completed)
    valid = np.asarray(sol.valid)
    v = np.asarray(sol.v)[valid]
    assert v[-1] == pytest.approx(v_top, rel=0.02) and 0.06 < float(sol.t_stop) < 0.07
    report = constraint_report(sol, V=V)
    assert report["max_relative_residual"] < 1e-8  # v(x) solves (sac) exactly
    assert np.isnan(report["max_abs_residual_branch1"])  # the stick branch only: it cannot enter the slip


def test_state_space_rejects_a_law_without_maximum():
    with pytest.raises(ValueError, match="no maximum"):
        integrate_state_space(V=8.0, t_final=0.01)


@pytest.mark.slow
def test_inertial_regularization_residual_stays_large_in_the_slip():
    """The paper's remark: m·v̇ = G − φ does not keep (sac) where v jumps, however small m is."""
    reports = {}
    for m in (1e-3, 1e-5):
        sol = integrate_inertial(V=1.1, m=m, t_final=0.4, save_steps=True, max_steps=100_000)
        assert bool(sol.completed)
        assert np.nanmax(np.asarray(sol.v)) > 8.49  # the jump crosses the falling branch
        reports[m] = constraint_report(sol, V=1.1)
    for report in reports.values():
        assert report["max_abs_residual_branch1"] > 50.0  # N, ≈ 40 % of φ
        assert report["max_relative_residual"] > 0.3
        # the first slip comes where the DAE's own solution reaches the maximum of φ (t ≈ 0.166 s)
        assert report["t_first_slip"] == pytest.approx(0.166, abs=0.01)
    # a 100× smaller mass does not shrink the slip residual
    assert reports[1e-5]["max_abs_residual_branch1"] > 0.5 * reports[1e-3]["max_abs_residual_branch1"]


def test_inertial_input_checks():
    with pytest.raises(ValueError, match="m must be > 0"):
        integrate_inertial(m=0.0)


def test_ida_fails_at_the_maximum_of_phi():
    """SUNDIALS IDA on the DAE itself (optional scikit-sundae): the corrector fails where ∂φ/∂v = 0."""
    pytest.importorskip("sksundae")
    from peeljax.alternatives import integrate_ida

    v_top, _ = phi_extrema(V=1.1)
    result = integrate_ida(V=1.1, rtol=1e-10, atol=1e-12, t_final=0.3, positive_v=False)
    assert not result["completed"]
    assert 0.16 < result["t_stop"] < 0.175
    assert result["v_at_stop"] == pytest.approx(v_top, rel=0.01)
