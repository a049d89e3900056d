"""Periodic stick-slip orbits by shooting (peeljax.orbits): convergence, exactness, stability,
derivatives by the implicit function theorem, and honest failures.

Every orbit here is shot with the same compiled program (k = 8 slips per period; rtol, V, the
start and the model are traced), so the module compiles it once; the derivative tests add
one forward-mode and one reverse-mode program.
"""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.orbits import OrbitStatus, SlipSection, one_period, orbit_shooting, periodic_orbit, periodic_orbits
from peeljax.orbits.api import compiled_orbit
from peeljax.orbits.continuation import BifurcationKind, continue_orbit

V = 1.1
STATS = ("F_mean", "F_slip", "F_stick", "period", "slip_duration")


@pytest.fixture(scope="module")
def run():
    return pj.simulate(V=V, tau=0, t_final=3.0)


@pytest.fixture(scope="module")
def orbit(run):
    return periodic_orbit(V=V, start=run)


def _quantities(orbit) -> np.ndarray:
    st = orbit.statistics
    return np.array([float(orbit.period)] + [float(st[k]) for k in STATS])


def test_newton_converges_from_the_runs_repeat(run, orbit):
    repeat = pj.cycle_statistics(run, float(run.t_stop), transient=1.5).repeat
    assert orbit.status_name == "converged", orbit.reason
    assert orbit.slips == repeat.events == 8
    assert 1 <= int(orbit.iterations) <= 8
    assert float(orbit.residual) <= 1e-10
    assert abs(float(orbit.period) / repeat.period - 1) < 1e-5
    assert float(orbit.approach) < 0  # no grazing here
    json.loads(orbit.to_json())  # JSON-able


def test_an_orbit_shot_with_twice_its_slips_is_found_with_its_own(orbit):
    """The least period (orbits.api.least_period): the orbit shot as a fixed point of P^16 is
    that of P^8, and the check of each divisor of 16 stops Newton after two iterations."""
    from peeljax.orbits.api import least_period

    twice = compiled_orbit(
        orbit_shooting(), orbit.model, orbit.V, orbit.section, jnp.asarray(16, jnp.int32), jnp.asarray(4 * orbit.period)
    )
    assert twice.status_name == "converged" and int(twice.slips) == 16
    least = least_period(orbit_shooting(), twice)
    assert int(least.slips) == 8 and least.status_name == "converged"
    assert float(least.period) == pytest.approx(float(orbit.period), rel=1e-9)
    assert float(twice.period) == pytest.approx(2 * float(orbit.period), rel=1e-9)
    assert int(least.iterations) <= 2


def test_orbit_matches_an_independent_implementation(orbit):
    # An independent scipy implementation of the DAE with jumps (LSODA, rtol 1e-11),
    # Newton on its return map: T, the statistics, the multipliers' moduli.
    st = {k: float(v) for k, v in orbit.statistics.items()}
    assert float(orbit.period) == pytest.approx(0.2182712, abs=2e-7)
    assert 1e3 * st["period"] == pytest.approx(27.2839, abs=1e-4)
    assert st["F_slip"] == pytest.approx(259.648, abs=1e-3)
    assert st["F_mean"] == pytest.approx(245.698, abs=1e-3)
    assert 1e3 * st["slip_duration"] == pytest.approx(2.1911, abs=1e-4)
    moduli = np.abs(np.asarray(orbit.multipliers))
    assert moduli == pytest.approx([0.558, 0.009], abs=1e-3)
    assert bool(orbit.stable)


def test_orbit_converges_in_rtol(run):
    # rtol is traced: the same program. The defaults' orbit agrees with rtol 1e-6 and 1e-11.
    loose = _quantities(periodic_orbit(V=V, start=run, rtol=1e-6))
    default = _quantities(periodic_orbit(V=V, start=run))
    tight = _quantities(periodic_orbit(V=V, start=run, rtol=1e-11))
    assert np.max(np.abs(default / tight - 1)) < 1e-8
    assert np.max(np.abs(loose / tight - 1)) < 1e-6
    assert np.max(np.abs(default / tight - 1)) < np.max(np.abs(loose / tight - 1))


def test_statistics_are_one_periods_means(orbit):
    # One period as a single run from the section (its own events, not the shooting's returns).
    period = float(orbit.period)
    sol = orbit.trajectory(np.linspace(0.0, period, 20001), rtol=1e-10)
    assert sol.status_name == "completed"
    jumps = sol.jumps.as_numpy()
    t, up, F_jump = jumps["jump_t"], jumps["jump_up"], jumps["jump_F"]
    # 2k − 1 jumps inside the period, alternating from the re-stick after the section's slip,
    # and the slip that closes it at T.
    assert len(t) == 16 and np.array_equal(up, np.arange(16) % 2 == 1)
    assert t[-1] == pytest.approx(period, rel=1e-7)  # (the run at rtol 1e-10, the orbit at 1e-8)
    st = {k: float(v) for k, v in orbit.statistics.items()}
    assert st["F_slip"] == pytest.approx(np.mean(F_jump[up]), rel=1e-7)  # the slip at T is the one at 0
    assert st["F_stick"] == pytest.approx(np.mean(F_jump[~up]), rel=1e-7)
    assert st["slip_duration"] == pytest.approx(np.mean(t[~up] - np.concatenate([[0.0], t[up][:-1]])), rel=1e-7)
    # The time average of F against a fine trapezoid of the dense trajectory over one period.
    F = (orbit.model.k / orbit.model.l) * np.asarray(sol.ys)[:, 2]
    mean = np.trapezoid(F, np.asarray(sol.ts)) / period
    assert st["F_mean"] == pytest.approx(mean, rel=2e-6)


@pytest.mark.slow
def test_multipliers_match_central_differences_of_the_return_map(orbit):
    shooting = orbit_shooting(rtol=1e-10)
    tight = periodic_orbit(V=V, start=np.asarray(orbit.section), slips=8, period=float(orbit.period), rtol=1e-10)
    section = SlipSection.at(tight.model, V)
    P = eqx.filter_jit(lambda s: one_period(section, shooting.integrator, s, 8, 0.7).end)
    s = np.asarray(tight.section)
    M = np.zeros((2, 2))
    for j, h in enumerate([1e-6, 1e-5]):
        e = np.zeros(2)
        e[j] = h
        M[:, j] = (np.asarray(P(s + e)) - np.asarray(P(s - e))) / (2 * h)
    ad = np.sort_complex(np.asarray(tight.multipliers))
    fd = np.sort_complex(np.linalg.eigvals(M).astype(complex))
    assert np.max(np.abs(ad - fd)) < 1e-6
    assert np.max(np.abs(np.asarray(tight.monodromy) - M) / (np.abs(M) + 1e-3 * np.abs(M).max())) < 1e-5


@pytest.fixture(scope="module")
def derivative_setup(orbit):
    rtol = 1e-10
    shooting = orbit_shooting(rtol=rtol)
    model, s_star = orbit.model, jnp.asarray(orbit.section)

    def quantities(c1, V_, start=s_star, t_max=0.7):
        # every argument an array: compiled_orbit's one jitted program (a Python float would be a
        # static argument of its filter_jit fallback, compiled anew for every difference's value)
        m = eqx.tree_at(lambda m: m.adhesion.c1, model, jnp.asarray(c1, float))
        o = compiled_orbit(shooting, m, jnp.asarray(V_, float), start, jnp.asarray(8, jnp.int32), jnp.asarray(t_max, float))
        st = o.statistics
        return jnp.stack([o.period] + [st[k] for k in STATS])

    # One reverse-mode program for both tests that take a gradient (t_max is traced).
    grad_F_mean = jax.jit(jax.grad(lambda c, t_max: quantities(c, V, t_max=t_max)[1]))
    return quantities, model.adhesion.c1, grad_F_mean


@pytest.mark.slow
def test_derivatives_match_central_differences_of_converged_orbits(derivative_setup):
    quantities, c1, grad_F_mean = derivative_setup
    # d/dc1 and d/dV in one forward-mode program (the implicit function theorem on the fixed point).
    jac = jax.jit(jax.jacfwd(quantities, argnums=(0, 1)))(jnp.asarray(c1), jnp.asarray(V))
    # Central differences of converged orbits, steps well below the bifurcation between
    # c1 × 1.0005 and × 1.0010 (shared/notes/orbits.md).
    for argnum, (x0, h) in enumerate([(float(c1), 1e-5 * float(c1)), (V, 1e-5)]):
        args = [float(c1), V]
        args[argnum] = x0 + h
        plus = np.asarray(quantities(*args))
        args[argnum] = x0 - h
        minus = np.asarray(quantities(*args))
        fd = (plus - minus) / (2 * h)
        assert np.max(np.abs(np.asarray(jac[argnum]) / fd - 1)) < 1e-5, (argnum, np.asarray(jac[argnum]), fd)
    # Reverse mode transposes the same linear rule: equal to forward mode.
    # (Newton's values under 2 and 3 tangents may round differently: not bit for bit.)
    grad = grad_F_mean(jnp.asarray(c1), 0.7)
    assert float(grad) == pytest.approx(float(jac[0][1]), rel=1e-9)


@pytest.mark.slow
def test_a_failed_orbit_says_why_and_its_gradient_is_finite(orbit, derivative_setup):
    quantities, c1, grad_F_mean = derivative_setup
    # A period bound of 3 ms: the run from the section cannot come back through 8 slips.
    failed = periodic_orbit(V=V, start=np.asarray(orbit.section), slips=8, period=1e-3)
    assert failed.status_name == "events_changed"
    assert "did not come back through k stick → slip events" in failed.reason
    assert all(np.isfinite(float(v)) for v in failed.statistics.values())
    assert np.isfinite(float(grad_F_mean(jnp.asarray(c1), 3e-3)))


def test_bad_input_is_refused_before_compiling(run):
    with pytest.raises(ValueError, match="slips must be a positive integer"):
        periodic_orbit(V=V, start=(0.3, 16.0), slips=0)
    with pytest.raises(ValueError, match="slips is needed"):
        periodic_orbit(V=V, start=(0.3, 16.0))
    with pytest.raises(ValueError, match="rtol"):
        periodic_orbit(V=V, start=run, rtol=2.0)
    with pytest.raises(ValueError, match="V"):
        periodic_orbit(V=-1.0, start=run)
    with pytest.raises(ValueError, match="start must be"):
        periodic_orbit(V=V, start=(0.3, 16.0, 1.0), slips=8)
    with pytest.raises(ValueError, match="max_iterations"):
        periodic_orbit(V=V, start=run, max_iterations=0)


def test_no_orbit_where_the_peeling_is_steady():
    with pytest.raises(pj.OrbitNotFound, match="no fold"):
        periodic_orbit(V=6.0, start=(0.1, 60.0), slips=1)
    short = pj.simulate(V=V, tau=0, t_final=0.1)  # from rest: the first slip comes at 0.166 s
    with pytest.raises(pj.OrbitNotFound, match="no stick → slip event"):
        periodic_orbit(V=V, start=short)


def test_orbit_status_messages_are_complete():
    for status in OrbitStatus:
        assert status.message


@pytest.mark.slow
def test_continuation_over_V_locates_the_branchs_bifurcations(orbit):
    # The 8-slip orbit's branch through V = 1.1, both ways, one compiled corrector.
    branch = continue_orbit(orbit, bounds=(0.9, 1.2))
    kinds = {b.kind: b for b in branch.bifurcations}
    assert set(kinds) == {BifurcationKind.NEW_SLIP, BifurcationKind.TORUS, BifurcationKind.LOST_SLIP}, branch
    assert np.all(branch.slips == 8) and np.all(np.diff(branch.values) > 0)
    # Above: a stick phase grazes phi's maximum (approach -> 0) and a 9th slip appears.
    grazing = kinds[BifurcationKind.NEW_SLIP]
    assert 1.1025 < grazing.V < 1.1027
    assert branch.approach[-1] > -1e-3 * (branch.statistics["F_slip"][-1] - branch.statistics["F_stick"][-1])
    # ... and past it the orbit has 9 slips per period, from the same section point.
    past = periodic_orbit(V=grazing.V + 2e-4, start=np.asarray(grazing.section), slips=9, period=grazing.period * 9 / 8)
    assert past.status_name == "converged"
    assert float(past.statistics["F_slip"]) < branch.statistics["F_slip"][-1] - 1.0  # the per-slip mean jumps
    # Below: a torus (Neimark-Sacker) point, where a complex pair crosses the unit circle:
    # stable above it, unstable below.
    torus = kinds[BifurcationKind.TORUS]
    assert 0.9765 < torus.V < 0.9775
    M = np.asarray(torus.monodromy).reshape(2, 2)
    assert abs(np.linalg.det(M) - 1) < 1e-3 and np.trace(M) ** 2 < 4 * np.linalg.det(M)
    assert np.all(branch.stable[branch.V > torus.V + 1e-3]) and not np.any(branch.stable[branch.V < torus.V - 1e-3])
    # Further below a slip's crossing of the section becomes tangential: the 8-slip orbit ends.
    lost = kinds[BifurcationKind.LOST_SLIP]
    assert 0.9623 < lost.V < 0.9625
    assert branch.crossing[0] < 1e-2 * branch.crossing.max()
    # The branch passes through the orbit it started from.
    i = int(np.argmin(np.abs(branch.V - V)))
    assert branch.period[i] == pytest.approx(float(orbit.period), rel=1e-6)


@pytest.mark.slow
def test_a_batch_of_orbits_equals_the_orbits_shot_alone(orbit):
    V_lanes = np.array([1.09, 1.1, 1.095])
    start = np.tile(np.asarray(orbit.section), (3, 1))
    batch = periodic_orbits(V=V_lanes, start=start, slips=8, period=float(orbit.period))
    assert np.all(np.asarray(batch.status) == 0) and np.asarray(batch.V) == pytest.approx(V_lanes)
    for i, v in enumerate(V_lanes):
        alone = periodic_orbit(V=v, start=start[i], slips=8, period=float(orbit.period))
        assert float(batch.period[i]) == pytest.approx(float(alone.period), rel=1e-12)
        for key in STATS:
            assert float(batch.statistics[key][i]) == pytest.approx(float(alone.statistics[key]), rel=1e-12)
    with pytest.raises(ValueError, match="start must be"):
        periodic_orbits(V=V_lanes, start=start[:2], slips=8)
