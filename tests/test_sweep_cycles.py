"""Sweep lanes keep what a map needs: a ring buffer of the last jumps and the window's cycle
statistics accumulated in the loop, equal to what :func:`peeljax.cycle_statistics` gives for
the whole record.

The fast tests feed made-up jump sequences (a settling repeat of 3 events, pairs of jumps the
same way, jumps before the window) through :class:`JumpRecord` with a
:class:`CycleAccumulator`; the slow ones run the DAE: one run with its whole record and the
accumulator in the same loop, and a sweep lane that makes 10× more jumps than it keeps.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.cycles import cycle_statistics, repeat_pattern
from peeljax.integrators.cycle_accumulator import KEPT_SLIPS, MAX_REPEAT_EVENTS, CycleAccumulator
from peeljax.integrators.events import FoldEvents
from peeljax.solution import JumpRecord
from peeljax.sweeps.lane_cycles import cycle_arrays, lane_cycle_statistics, repeat_table

SPREADS = ("stick_duration", "slip_duration", "slip_interval", "force_drop", "G_slip", "G_stick")


def _jumps(n: int, seed: int, period=(0.011, 0.017, 0.013), same_way=(7, 8, 40)):
    """n jumps: stick → slip every d_k of a 3-periodic sequence that settles (noise × 0.7 a
    repeat), a slip → stick jump between them, and at ``same_way`` two jumps up in a row."""
    rng = np.random.default_rng(seed)
    t, up = [], []
    time, noise = 0.01, 2e-3
    for i in range((n + 1) // 2):
        time += period[i % 3] + noise * rng.standard_normal()
        noise *= 0.4 ** (1 / 3)
        t += [time, time + 0.3 * period[i % 3]]
        up += [True, i in same_way]
    t, up = np.array(t[:n]), np.array(up[:n])
    G = np.where(up, 300.0, 200.0) + rng.standard_normal(n)
    v_before = np.where(up, 0.5, 8.0) + 0.1 * rng.standard_normal(n)
    v_after = np.where(up, 15.0, 1e-3) + 0.1 * rng.standard_normal(n)
    return t, up, v_before, v_after, G


@jax.jit
def _fill(record, t, up, v_before, v_after, G):
    def body(record, jump):
        return record.record(True, *jump), None

    return jax.lax.scan(body, record, (t, up, v_before, v_after, G))[0]


def _host(t, up, v_before, v_after, G, w0, t_end, rtol=1e-3):
    return cycle_statistics(
        {"jump_t": t, "jump_up": up, "jump_v_before": v_before, "jump_v_after": v_after, "jump_G": G},
        t_end, transient=w0, rtol=rtol,
    )  # fmt: skip


def _assert_same(loop, host, rtol=1e-13):
    """Counts and extremes exactly, means (sums added in another order) to rounding."""
    assert (loop.jumps, loop.slips) == (host.jumps, host.slips)
    for name in SPREADS:
        a, b = getattr(loop, name), getattr(host, name)
        assert a.n == b.n, name
        np.testing.assert_array_equal([a.min, a.max], [b.min, b.max], err_msg=name)
        np.testing.assert_allclose(a.mean, b.mean, rtol=rtol, err_msg=name)
    np.testing.assert_array_equal(loop.v_stick + loop.v_slip, host.v_stick + host.v_slip)
    np.testing.assert_allclose(loop.stick_fraction, host.stick_fraction, rtol=rtol)
    assert (loop.repeat is None) == (host.repeat is None)
    if host.repeat is not None:
        assert loop.repeat == host.repeat  # the same differences of the same times: bit for bit


@pytest.mark.parametrize(("w0", "t_end"), [(0.5, 3.2), (0.9, 2.8), (0.0, 0.5), (2.7, 2.75), (0.0, 0.01)])
def test_accumulated_statistics_are_the_records(w0, t_end):
    n = 400  # one shape: one compilation
    jumps = _jumps(n, seed=5)
    record = _fill(
        JumpRecord.empty(8, ring=True, statistics=CycleAccumulator.over(w0, t_end)), *map(jnp.asarray, jumps)
    )
    cycles = {key: np.asarray(value)[None] for key, value in cycle_arrays(record.statistics.finish(t_end)).items()}
    host = _host(*jumps, w0, t_end)
    loop = lane_cycle_statistics(cycles, 0, w0, t_end)
    _assert_same(loop, host)
    if w0 == 0.9:
        assert host.repeat is not None and host.repeat.events == 3  # the settled repeat is found
        assert host.slips > KEPT_SLIPS  # more than the stick → slip times kept


def test_no_jump_in_the_window_takes_the_branch_before_it():
    t, up, v_before, v_after, G = (a[:5] for a in _jumps(5, seed=1))
    for landed_stuck in (True, False):
        up_last = up.copy()
        up_last[-1] = not landed_stuck
        record = _fill(JumpRecord.empty(2, ring=True, statistics=CycleAccumulator.over(1.0, 2.0)),
                       *map(jnp.asarray, (t, up_last, v_before, v_after, G)))  # fmt: skip
        cycles = {key: np.asarray(value)[None] for key, value in cycle_arrays(record.statistics.finish(2.0)).items()}
        assert cycles["cycle_stick_fraction"][0] == _host(t, up_last, v_before, v_after, G, 1.0, 2.0).stick_fraction
    empty = CycleAccumulator.over(0.5, 1.0).finish(1.0)
    assert int(empty["jumps"]) == 0 and math.isnan(float(empty["stick_fraction"]))  # no jump at all: unknown


def test_repeat_table_is_repeat_pattern_up_to_its_longest_k():
    """Every lane's repeat from the loop's deviations, as repeat_pattern finds it on all the times."""
    rng = np.random.default_rng(3)
    lanes = []
    for k, n in ((1, 12), (5, 40), (MAX_REPEAT_EVENTS, 2 * MAX_REPEAT_EVENTS + 9), (MAX_REPEAT_EVENTS + 1, 90), (4, 8)):
        d = np.tile(rng.uniform(0.01, 0.02, k), n)[: n - 1]
        lanes.append(np.concatenate([[0.3], 0.3 + np.cumsum(d)]))
    width = max(times.size for times in lanes)
    padded = np.stack([np.pad(times, (0, width - times.size), constant_values=np.nan) for times in lanes])

    @jax.jit
    @jax.vmap
    def accumulate(times):
        def body(accumulator, time):
            return accumulator.add(jnp.isfinite(time), time, True, 0.5, 15.0, 300.0), None

        accumulator = jax.lax.scan(body, CycleAccumulator.over(0.0, 100.0), times)[0]
        return cycle_arrays(accumulator.finish(100.0))

    cycles = jax.tree_util.tree_map(np.asarray, accumulate(jnp.asarray(padded)))
    table = repeat_table(cycles, 1e-3)
    for i, times in enumerate(lanes):
        want = repeat_pattern(times, rtol=1e-3)
        if want is None or want.events > MAX_REPEAT_EVENTS:  # beyond the longest repeat the loop searches
            assert table["events"][i] == 0
            continue
        assert (table["events"][i], table["repeats"][i]) == (want.events, want.repeats)
        assert table["period"][i] == want.period and table["spread"][i] == want.spread
    assert table["events"].tolist() == [1, 5, MAX_REPEAT_EVENTS, 0, 0]  # k = 4 in 8 events: too few repeats


def test_ring_buffer_keeps_the_last_jumps_in_order():
    t, up, v_before, v_after, G = map(jnp.asarray, _jumps(11, seed=2))
    ring = _fill(JumpRecord.empty(4, ring=True), t, up, v_before, v_after, G)
    assert int(ring.count) == 11 and int(ring.kept) == 4 and not bool(ring.full)
    assert np.asarray(ring.slot_valid()).all()
    latest = ring.latest()
    assert int(latest.count) == 4 and not latest.ring
    np.testing.assert_array_equal(np.asarray(latest.t), np.asarray(t[-4:]))
    np.testing.assert_array_equal(np.asarray(latest.up), np.asarray(up[-4:]))
    np.testing.assert_array_equal(ring.as_numpy()["jump_G"], np.asarray(G[-4:]))
    # fewer jumps than slots: the first ones, in order, the rest invalid
    few = _fill(JumpRecord.empty(16, ring=True), t, up, v_before, v_after, G)
    assert np.asarray(few.slot_valid()).tolist() == [True] * 11 + [False] * 5
    np.testing.assert_array_equal(np.asarray(few.latest().t)[:11], np.asarray(t))
    assert np.isnan(np.asarray(few.latest().t)[11:]).all()
    # a batch of records (as a sweep's lanes hold them)
    batch = jax.vmap(lambda r: r.latest())(jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), ring))
    np.testing.assert_array_equal(np.asarray(batch.t)[1], np.asarray(t[-4:]))
    # a plain record fills its slots and then writes nothing more (the loop stops the run)
    plain = _fill(JumpRecord.empty(4), t, up, v_before, v_after, G)
    assert int(plain.count) == 4 and bool(plain.full)
    np.testing.assert_array_equal(np.asarray(plain.t), np.asarray(t[:4]))


def test_fold_events_default_is_the_plain_record():
    events = FoldEvents()
    assert not events.ring and events.statistics is None and not events.empty_record().ring
    assert "jump_record" not in events.settings()
    assert FoldEvents(ring=True).settings()["jump_record"] == "ring"
    with pytest.raises(ValueError, match="ring must be True or False"):
        FoldEvents(ring="yes")
    assert not events.folds_at_first_jump and "folds_at_first_jump" not in events.settings()  # (the same results)
    with pytest.raises(ValueError, match="folds_at_first_jump must be True or False"):
        FoldEvents(folds_at_first_jump=1)


# ---------------------------------------------------------------------------- the DAE's runs
def _integrator(t_final, w0, max_jumps, ring):
    from peeljax.integrators.select import integrator_for

    integrator = integrator_for(
        None, rho=0.0, dt=None, t_final=t_final, rtol=1e-6, atol=1e-9, dtmin=None, max_steps=200_000, adjoint="forward",
        fold="jump", max_jumps=max_jumps, dae=True,
    )  # fmt: skip
    events = dataclasses.replace(integrator.events, ring=ring, statistics=CycleAccumulator.over(w0, t_final))
    return dataclasses.replace(integrator, events=events)


@pytest.mark.slow
def test_the_loops_statistics_are_the_whole_records():
    """One DAE run (V = 2 m/s, 3 s: 540 jumps) keeps its whole record and accumulates the
    statistics of [1.5, 3] s in the same loop: they agree (means to rounding)."""
    model = pj.PeelingModel()
    ode = pj.ConstrainedDAE(model, 2.0)
    integrator = _integrator(3.0, 1.5, 4096, ring=False)
    sol = eqx_jit(integrator.integrate)(ode, model.initial_state(2.0), 0.0, 3.0, jnp.array([0.0, 3.0]))
    assert int(sol.status) == 0 and int(sol.jumps.count) > 500
    cycles = {
        key: np.asarray(value)[None] for key, value in cycle_arrays(sol.jumps.statistics.finish(sol.t_stop)).items()
    }
    host = cycle_statistics(sol, float(sol.t_stop), transient=1.5)
    loop = lane_cycle_statistics(cycles, 0, 1.5, float(sol.t_stop))
    _assert_same(loop, host, rtol=1e-12)
    assert host.slips > KEPT_SLIPS


def eqx_jit(fn):
    import equinox as eqx

    return eqx.filter_jit(fn)


@pytest.mark.slow
def test_a_lane_never_stops_for_a_full_record():
    """V = 5 m/s, where the default 2048-slot record used to fill: the lane completes, keeps its
    last 64 jumps — those of the run alone — and its statistics are the run's. (The lane and the
    run alone are compiled apart, so their fast cycles drift apart by rounding: 3e-8 in the jump
    times after 1 s, measured.)"""
    result = pj.sweep(V=[5.0], tau=0, t_final=1.0, grid="pairs", progress=False)
    alone = pj.simulate(V=5.0, tau=0, t_final=1.0, ts=np.array([0.0, 1.0]), adjoint="forward", max_jumps=4096)
    count = int(alone.jumps.count)
    assert result.completed.all() and int(result.jumps["jump_count"][0]) == count > 10 * 64
    assert result.jumps["jump_t"].shape == (1, 64)
    np.testing.assert_allclose(result.jumps["jump_t"][0], np.asarray(alone.jumps.t)[count - 64 : count], rtol=1e-6)
    lane = result.cycle_statistics(0)
    host = cycle_statistics(alone, 1.0, transient=0.5)
    assert (lane.jumps, lane.slips) == (host.jumps, host.slips)
    np.testing.assert_allclose(lane.slip_interval.mean, host.slip_interval.mean, rtol=1e-6)
    np.testing.assert_allclose(lane.stick_fraction, host.stick_fraction, rtol=1e-6)
    with pytest.raises(ValueError, match="kept its last 64 jumps"):
        result.cycle_statistics(0, transient=0.2)
