"""Steady peeling's linear stability: the equilibrium, its Jacobian against finite differences
of the reduced vector field, stability where v = V lies on a rising branch of φ, the ends at
the folds (∂φ/∂v(V, V) = 0), confirmed by runs, and the attractor map's steady boundaries."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy.optimize import brentq

import peeljax as pj
from peeljax.fit.attractors import steady_rows
from peeljax.sweeps.stick_slip_map import fold_table

MODEL = pj.PeelingModel()
GRID = np.linspace(0.3, 5.4, 200)


@pytest.fixture(scope="module")
def ends():
    return pj.steady_peeling_ends(MODEL, GRID)


@pytest.mark.parametrize("V", [0.3, 1.1, 5.0])
def test_steady_peeling_is_an_equilibrium_on_the_constraint(V):
    y = np.asarray(pj.steady_state(MODEL, V))
    np.testing.assert_allclose(np.asarray(MODEL.f(y[:3], y[3], V)), 0.0, atol=1e-12)
    assert abs(float(MODEL.constraint(y[:3], y[3], V))) <= 1e-10 * float(MODEL.phi(V, V))


@pytest.mark.parametrize("V", [0.3, 5.0])
def test_the_jacobian_is_the_reduced_vector_field_s_by_finite_differences(V):
    """J = ∂f/∂x + ∂f/∂v ⊗ F̃/∂φ/∂v against central differences of x ↦ f(x, v(x)), v(x) solved
    from the constraint on the branch of v = V."""
    y = np.asarray(pj.steady_state(MODEL, V))

    def reduced(x):
        g = float(MODEL.shear_force(x))
        v = brentq(lambda v: float(MODEL.phi(v, V)) - g, 0.9 * V, 1.1 * V, xtol=1e-15, rtol=1e-15)
        return np.asarray(MODEL.f(x, v, V))

    h = np.array([1e-6, 1e-4, 1e-8])  # α [rad], ω [rad/s], u [m]
    columns = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = h[i]
        columns.append((reduced(y[:3] + e) - reduced(y[:3] - e)) / (2 * h[i]))
    J = np.asarray(pj.steady_jacobian(MODEL, V))
    np.testing.assert_allclose(J, np.column_stack(columns), rtol=1e-5, atol=1e-6 * np.abs(J).max())


def test_steady_peeling_is_stable_exactly_where_v_lies_on_a_rising_branch(ends):
    """No Hopf bifurcation on the paper's φ: the eigenvalues agree with ∂φ/∂v(V, V) > 0 (the
    rule the fit's steady rows use) at every V of the 200-V grid."""
    stable = ends[0]
    np.testing.assert_array_equal(stable, steady_rows(MODEL, GRID))
    assert 0 < stable.sum() < GRID.size


def test_steady_peeling_ends_at_the_two_folds_of_phi(ends):
    _, V_stable, V_unstable, kinds = ends
    assert kinds == [pj.steady.FOLD, pj.steady.FOLD]
    np.testing.assert_array_less(np.abs(V_stable - V_unstable), 1.01e-10)
    low, high = 0.5 * (V_stable + V_unstable)
    assert V_stable[0] < V_unstable[0] and V_stable[1] > V_unstable[1]  # stable below the low end, above the high one
    folds = fold_table(MODEL, np.array([low, high]))
    np.testing.assert_allclose([folds["v_max"][0], folds["v_min"][1]], [low, high], rtol=1e-6)  # V = v̂(V), V = v̌(V)
    assert 0.3862 < low < 0.3863 and 4.8027 < high < 4.8028


def test_the_damping_of_steady_peeling_vanishes_at_the_fold(ends):
    """The slow complex pair (the spool's rotation, ≈ 27 rad/s) has Re λ ∝ −∂φ/∂v(V, V): near
    the fold a run from steady peeling hardly settles, and no finite run brackets the end."""
    _, V_stable, _, _ = ends
    for d in (1e-2, 1e-3, 1e-4):
        V = float(V_stable[0] - d)
        lam = np.asarray(pj.steady_eigenvalues(MODEL, V))
        pair = lam[np.abs(lam.imag) > 0]
        assert pair.size == 2 and 26 < abs(pair[0].imag) < 28
        slope = float(jax.grad(MODEL.phi)(V, V))
        assert -0.35 < pair[0].real / slope < -0.2, (d, pair, slope)


@pytest.mark.parametrize(("side", "jumps"), [(-0.01, False), (0.01, True)])
@pytest.mark.parametrize("end", [0, 1])
def test_runs_from_perturbed_steady_peeling_confirm_the_ends(ends, end, side, jumps):
    """0.01 m/s inside the stable side a run from steady peeling with v 0.1 % off returns
    without a jump; 0.01 m/s beyond, it jumps."""
    _, V_stable, V_unstable, _ = ends
    direction = np.sign(V_unstable[end] - V_stable[end])
    V = float(V_stable[end] + side * direction) if side < 0 else float(V_unstable[end] + side * direction)
    y0 = np.asarray(MODEL.consistent_state(V, 0.0, V / MODEL.R, 1.001 * V))
    sol = pj.simulate(MODEL, V=V, tau=0.0, t_final=1.0, y0=y0)
    assert int(sol.status) == 0
    assert (int(sol.stats["jumps"]) > 0) == jumps


def test_bad_grids_are_refused():
    with pytest.raises(ValueError, match="increasing"):
        pj.steady_peeling_ends(MODEL, [1.0, 0.5])
    with pytest.raises(ValueError, match="V must be > 0"):
        pj.steady_peeling_ends(MODEL, [-1.0, 0.5])
    with pytest.raises(TypeError, match="model must be a PeelingModel"):
        pj.steady_peeling_ends("paper", [0.3, 0.4])
    with pytest.raises(ValueError, match="xtol must be > 0"):
        pj.steady_peeling_ends(MODEL, [0.3, 0.4], xtol=0.0)


@pytest.mark.slow
def test_the_attractor_map_puts_the_steady_ends_at_the_folds(ends):
    _, V_stable, V_unstable, _ = ends
    amap = pj.attractor_map(V=[0.37, 0.40, 4.79, 4.82], random_starts=0, seed_rounds=0, lyapunov=False, progress=False)
    b = amap.boundaries
    steady = [i for i, change in enumerate(b["change"]) if change.startswith("steady peeling ends")]
    assert len(steady) == 2, b
    for i, end in zip(steady, (0, 1)):
        assert b["change"][i] == "steady peeling ends (fold of phi: dphi/dv(V, V) = 0)"
        np.testing.assert_allclose([b["V_inside"][i], b["V_outside"][i]], [V_stable[end], V_unstable[end]], atol=1e-8)


@pytest.mark.slow
def test_where_the_linearisation_places_no_end_runs_bracket_it(ends, monkeypatch):
    """The fallback: runs from steady peeling bisect the end; their bracket holds the fold."""
    import importlib

    am = importlib.import_module("peeljax.attractor_map")
    monkeypatch.setattr(am, "_steady_end", lambda *args: None)
    _, V_stable, _, _ = ends
    amap = pj.attractor_map(V=[0.37, 0.40], random_starts=0, seed_rounds=0, lyapunov=False, progress=False)
    b = amap.boundaries
    steady = [i for i, change in enumerate(b["change"]) if amap.kind[amap.branch == b["branch"][i]][0] == am.STEADY]
    assert len(steady) == 1, b
    i = steady[0]
    assert b["V_inside"][i] <= V_stable[0] <= b["V_outside"][i], b
