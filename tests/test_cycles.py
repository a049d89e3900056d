"""peeljax.cycles: stick-slip cycle statistics and the repeat, on synthetic jump records (fast, no run)."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from peeljax.cycles import (
    CycleStatistics,
    RepeatPattern,
    Spread,
    TooFewRepeats,
    cycle_statistics,
    repeat_outlook,
    repeat_pattern,
)
from peeljax.solution import JumpRecord, Solution

T8 = 0.2182711  # V = 1.1 m/s: 8 stick → slip events per repeat
T9 = 0.2362121  # the coexisting orbit: 9 per repeat
RTOL = 1e-3  # the default of repeat_pattern and cycle_statistics


# ---------------------------------------------------------------------------- building records
def make_record(t, up, v_before, v_after, G, max_jumps: int | None = None) -> JumpRecord:
    """A JumpRecord holding these jumps, padded with NaN to ``max_jumps`` slots."""
    n = len(t)
    m = n + 3 if max_jumps is None else max_jumps

    def pad(values, fill):
        array = np.full(m, fill, dtype=np.asarray(fill).dtype)
        array[:n] = values
        return jnp.asarray(array)

    return JumpRecord(
        t=pad(t, np.nan), up=pad(up, False), v_before=pad(v_before, np.nan), v_after=pad(v_after, np.nan),
        G=pad(G, np.nan), count=jnp.asarray(n, jnp.int32),
    )  # fmt: skip


def orbit(events: int, period: float, repeats: int, t0: float = 0.5, extra: int = 1):
    """Up/down jumps of a periodic orbit with ``events`` stick → slip events per repeat.

    Intervals between slips: ``events − 1`` short ones of 12.5–17.1 ms and one long one making up
    ``period``; slips of 2.0–2.3 ms; ``repeats·events + extra`` stick → slip events from ``t0``.
    Returns the jump arrays (t, up, v_before, v_after, G).
    """
    short = np.linspace(0.0125, 0.0171, events - 1)
    pattern = np.append(short, period - short.sum())
    slip = np.resize([0.0020, 0.0021, 0.0022, 0.0023], events)
    n_up = repeats * events + extra
    intervals = np.resize(pattern, n_up - 1)
    up_times = t0 + np.concatenate([[0.0], np.cumsum(intervals)])
    down_times = up_times + np.resize(slip, n_up)
    t = np.ravel(np.column_stack([up_times, down_times]))
    up = np.ravel(np.column_stack([np.ones(n_up, bool), np.zeros(n_up, bool)]))
    v_before = np.where(up, 0.05, 0.4)
    v_after = np.where(up, 0.9, 0.01)
    G = np.where(up, 2.0, 1.2)
    return t, up, v_before, v_after, G


def as_mapping(t, up, v_before, v_after, G) -> dict[str, np.ndarray]:
    return {"jump_t": np.asarray(t), "jump_up": np.asarray(up), "jump_v_before": np.asarray(v_before),
            "jump_v_after": np.asarray(v_after), "jump_G": np.asarray(G)}  # fmt: skip


# A small run by hand on [0, 1] s: it starts slipping (the first jump is down), lands fully stuck
# (v_after = 0) twice and ends mid-stick.
#          t     up     v_before v_after G
HAND = [
    (0.10, False, 0.50, 0.00, 1.0),
    (0.30, True, 0.05, 0.90, 2.0),
    (0.35, False, 0.40, 0.02, 1.2),
    (0.60, True, 0.06, 1.00, 2.1),
    (0.64, False, 0.45, 0.00, 1.1),
]


def hand_arrays():
    return tuple(np.array(column) for column in zip(*HAND))


# ---------------------------------------------------------------------------- the repeat
@pytest.mark.parametrize("events, period", [(8, T8), (9, T9)])
def test_repeat_of_a_built_orbit(events, period):
    arrays = orbit(events, period, repeats=5)
    stats = cycle_statistics(make_record(*arrays), t_end=arrays[0][-1] + 0.05)
    assert stats.repeat is not None and stats.regular
    assert stats.repeat.events == events
    assert stats.repeat.period == pytest.approx(period, rel=1e-12)
    assert stats.repeat.repeats == 5
    assert stats.repeat.spread < 1e-12
    assert stats.slips == 5 * events + 1 and stats.jumps == 2 * stats.slips
    assert stats.as_dict()["repeat"]["events"] == events
    assert f"{events} stick → slip events per repeat" in str(stats)


def test_jittering_one_interval_beyond_rtol_makes_it_irregular():
    t, *_ = orbit(8, T8, repeats=5)
    up_times = t[::2]
    tolerance = RTOL * np.diff(up_times).mean()
    for jitter, regular in [(0.3 * tolerance, True), (3.0 * tolerance, False)]:
        shifted = up_times.copy()
        shifted[20:] += jitter  # one interval (the 20th) longer by `jitter`, every other unchanged
        found = repeat_pattern(shifted, rtol=RTOL)
        assert (found is not None) == regular
        if regular:
            assert found.events == 8 and found.period == pytest.approx(T8, abs=jitter)
    # the same through cycle_statistics: no repeat over the window, but the orbit repeats after the
    # jittered interval: "too few repeats to tell", with the window from there
    arrays = orbit(8, T8, repeats=5)
    jittered = arrays[0].copy()
    jittered[40:] += 3.0 * tolerance
    stats = cycle_statistics(as_mapping(jittered, *arrays[1:]), t_end=jittered[-1] + 0.05)
    assert stats.repeat is None and not stats.regular
    assert stats.verdict == "too few repeats to tell" and stats.too_few.events == 8
    assert stats.too_few.start == jittered[2 * 20]  # the orbit repeats from the jittered event on
    assert stats.as_dict()["repeat"] == "too few repeats to tell"
    assert stats.as_dict()["too_few_repeats"]["events"] == 8
    assert "too few repeats to tell" in str(stats) and "irregular" not in str(stats)
    shown = repeat_pattern(jittered[::2][jittered[::2] >= stats.too_few.start])
    assert shown.events == 8 and shown.period == pytest.approx(T8, rel=1e-12)


def settling_orbit(n_up: int, rate: float = 0.5, first: float = 1e-3):
    """Stick → slip times of the 8-event orbit approached geometrically: interval i is off by
    ``first·rate^(i // 8)`` (alternating sign within a repeat)."""
    short = np.linspace(0.0125, 0.0171, 7)
    pattern = np.append(short, T8 - short.sum())
    i = np.arange(n_up - 1)
    d = np.resize(pattern, n_up - 1) + first * rate ** (i // 8) * np.where(i % 2, 1.0, -1.0)
    return 0.5 + np.concatenate([[0.0], np.cumsum(d)])


def test_a_settling_repeat_is_too_few_to_tell_with_the_window_that_shows_it():
    """Three repeats of the 8-event orbit still settling (deviation halving per repeat): not
    "irregular" but too few repeats; the window it proposes does show the repeat."""
    t = settling_orbit(3 * 8 + 1)
    assert repeat_pattern(t) is None
    outlook = repeat_outlook(t, t_end=t[-1])
    assert isinstance(outlook, TooFewRepeats) and outlook.events == 8
    assert outlook.period == pytest.approx(T8, rel=1e-2)
    assert outlook.spread > outlook.tolerance and outlook.start > t[-1]
    longer = settling_orbit(20 * 8 + 1)
    assert longer[-1] > outlook.end
    shown = repeat_pattern(longer[(longer >= outlook.start) & (longer <= outlook.end)])
    assert shown is not None and shown.events == 8 and shown.period == pytest.approx(T8, rel=1e-4)
    # through cycle_statistics and its text
    up = np.ones(t.size, bool)
    stats = cycle_statistics(as_mapping(t, up, 0.05 + 0 * t, 0.9 + 0 * t, 2.0 + 0 * t), t_end=t[-1] + 0.01)
    assert stats.verdict == "too few repeats to tell" and stats.too_few.events == 8
    assert "too few repeats to tell (near repeat: T ≈ 0.218" in str(stats)
    assert f"a window [{stats.too_few.start:.3g}, {stats.too_few.end:.3g}] s would do" in str(stats)


def test_irregular_is_measured_and_short_windows_are_too_few():
    """Intervals from the logistic map (chaotic): with ≥ 31 events "irregular"; the same
    intervals with fewer events: too few to tell, with the length that would do."""
    x = np.empty(60)
    x[0] = 0.3
    for i in range(1, x.size):
        x[i] = 4.0 * x[i - 1] * (1.0 - x[i - 1])
    t = np.concatenate([[0.0], np.cumsum(0.02 * (1.0 + 0.5 * x))])
    assert repeat_pattern(t) is None and repeat_outlook(t) is None
    stats = cycle_statistics(as_mapping(t, np.ones(t.size, bool), *(np.ones(t.size),) * 3), t_end=t[-1] + 0.01)
    assert stats.verdict == "irregular" and stats.too_few is None
    assert stats.as_dict()["repeat"] == "irregular" and "irregular (no repeat forming)" in str(stats)
    short = repeat_outlook(t[:12])
    assert short.events == 0 and short.length == pytest.approx(30 * np.diff(t[:12]).mean())
    assert "fewer than 31 stick → slip events; a window of at least" in str(short)
    assert repeat_outlook(t[:1]).events == 0 and math.isnan(repeat_outlook(t[:1]).length)
    assert repeat_outlook([]) is None


def test_regular_stick_slip_has_one_event_per_repeat():
    up_times = 0.2 + 0.05 * np.arange(11)
    found = repeat_pattern(up_times)
    assert found == RepeatPattern(period=pytest.approx(0.05, rel=1e-12), events=1, repeats=10, spread=found.spread)
    assert found.spread < 1e-12
    arrays = orbit(1, 0.05, repeats=10)
    stats = cycle_statistics(make_record(*arrays), t_end=1.0)
    assert stats.repeat.events == 1 and stats.repeat.period == pytest.approx(0.05, rel=1e-12)
    assert "1 stick → slip event per repeat" in str(stats)


def test_repeat_needs_two_full_repeats_and_takes_the_smallest_k():
    t, *_ = orbit(8, T8, repeats=2, extra=1)
    up_times = t[::2]  # 17 events: exactly 2 full repeats
    assert repeat_pattern(up_times).repeats == 2
    assert repeat_pattern(up_times[:-1]) is None  # 16 events: not 2k + 1
    # a, b, a, b, …: k = 2, not 4 or 6
    d = np.resize([0.01, 0.03], 12)
    found = repeat_pattern(np.concatenate([[0.0], np.cumsum(d)]))
    assert found.events == 2 and found.repeats == 6 and found.period == pytest.approx(0.04)
    # too few events, or times that do not advance
    assert repeat_pattern([]) is None and repeat_pattern([1.0]) is None and repeat_pattern([1.0, 2.0]) is None
    assert repeat_pattern([1.0, 1.0, 1.0]) is None


# ---------------------------------------------------------------------------- durations and forces
def test_durations_forces_and_velocity_ranges_by_hand():
    stats = cycle_statistics(make_record(*hand_arrays()), t_end=1.0)
    assert isinstance(stats, CycleStatistics)
    assert (stats.jumps, stats.slips) == (5, 2)
    # sticks 0.10 → 0.30 and 0.35 → 0.60; the one from 0.64 is still under way at t_end
    assert stats.stick_duration == Spread(pytest.approx(0.225), pytest.approx(0.20), pytest.approx(0.25), 2)
    assert stats.slip_duration == Spread(pytest.approx(0.045), pytest.approx(0.04), pytest.approx(0.05), 2)
    assert stats.slip_interval == Spread(pytest.approx(0.30), pytest.approx(0.30), pytest.approx(0.30), 1)
    assert stats.force_drop == Spread(pytest.approx(0.9), pytest.approx(0.8), pytest.approx(1.0), 2)
    assert stats.G_slip == Spread(pytest.approx(2.05), 2.0, 2.1, 2)
    assert stats.G_stick == Spread(pytest.approx(1.1), 1.0, 1.2, 3)
    assert stats.v_stick == (0.0, 0.06)  # lands fully stuck: v_after = 0
    assert stats.v_slip == (0.40, 1.00)
    assert stats.repeat is None and stats.verdict == "too few repeats to tell"  # two slips only


def test_stick_fraction_by_hand():
    # slipping until 0.10 (the first jump is down), stuck 0.10–0.30, slipping 0.30–0.35,
    # stuck 0.35–0.60, slipping 0.60–0.64, stuck 0.64–1.00
    stats = cycle_statistics(make_record(*hand_arrays()), t_end=1.0)
    assert stats.stick_fraction == pytest.approx(0.20 + 0.25 + 0.36)
    # starting stuck: one up jump in the middle
    one = cycle_statistics(as_mapping([0.5], [True], [0.05], [0.9], [2.0]), t_end=2.0)
    assert one.stick_fraction == pytest.approx(0.25)
    assert (one.jumps, one.slips, one.G_slip.n, one.stick_duration.n, one.slip_duration.n) == (1, 1, 1, 0, 0)
    assert math.isnan(one.v_stick[0]) and one.v_stick[1] == 0.05  # no down jump: no landing v


def test_the_transient_cut():
    arrays = hand_arrays()
    stats = cycle_statistics(make_record(*arrays), t_end=1.0, transient=0.32)
    # the window [0.32, 1] holds the down jump at 0.35, the up at 0.60, the down at 0.64
    assert (stats.jumps, stats.slips) == (3, 1)
    assert stats.stick_duration.n == 1 and stats.stick_duration.mean == pytest.approx(0.25)
    assert stats.slip_duration.n == 1 and stats.slip_duration.mean == pytest.approx(0.04)
    assert stats.force_drop.n == 1 and stats.force_drop.mean == pytest.approx(1.0)  # the 0.30 slip began before
    assert stats.G_stick.n == 2 and stats.slip_interval.n == 0
    assert stats.stick_fraction == pytest.approx((0.25 + 0.36) / 0.68)  # slipping at 0.32
    # jumps only before the transient: the branch is where the last one landed (stuck)
    late = cycle_statistics(make_record(*arrays), t_end=1.0, transient=0.8)
    assert late.jumps == 0 and late.stick_fraction == 1.0 and late.repeat is None
    # and slipping after an up jump
    up_last = cycle_statistics(make_record(*(a[:4] for a in arrays)), t_end=1.0, transient=0.8)
    assert up_last.stick_fraction == 0.0
    # jumps after t_end are left out
    cut = cycle_statistics(make_record(*arrays), t_end=0.5)
    assert cut.jumps == 3 and cut.stick_fraction == pytest.approx((0.20 + 0.15) / 0.5)


def test_settling_transient_hides_the_repeat_until_cut():
    arrays = orbit(8, T8, repeats=4, t0=0.5)
    settle = (np.array([0.17, 0.19, 0.25, 0.27, 0.40, 0.42]), np.array([True, False] * 3),
              np.full(6, 0.05), np.full(6, 0.01), np.full(6, 1.5))  # fmt: skip
    t, up, v_before, v_after, G = (np.concatenate([a, b]) for a, b in zip(settle, arrays))
    record = make_record(t, up, v_before, v_after, G)
    t_end = t[-1] + 0.03
    assert cycle_statistics(record, t_end=t_end).repeat is None
    stats = cycle_statistics(record, t_end=t_end, transient=0.45)
    assert stats.repeat.events == 8 and stats.repeat.repeats == 4
    assert stats.repeat.period == pytest.approx(T8, rel=1e-12)
    assert stats.jumps == len(arrays[0]) and stats.G_slip.mean == pytest.approx(2.0)


# ---------------------------------------------------------------------------- inputs
def test_empty_record():
    stats = cycle_statistics(JumpRecord.empty(16), t_end=3.0)
    assert (stats.jumps, stats.slips) == (0, 0) and stats.repeat is None
    for spread in (stats.stick_duration, stats.slip_duration, stats.slip_interval, stats.force_drop,
                   stats.G_slip, stats.G_stick):  # fmt: skip
        assert spread.n == 0 and all(math.isnan(x) for x in (spread.mean, spread.min, spread.max))
    assert all(math.isnan(v) for v in stats.v_stick + stats.v_slip)
    assert math.isnan(stats.stick_fraction)  # no jump at all: the branch is unknown
    out = stats.as_dict()
    assert out["repeat"] == "none" and out["stick_fraction"] is None and out["G_slip"]["mean"] is None
    assert out["too_few_repeats"] is None and stats.verdict == "none"
    assert "0 jumps" in str(stats) and "repeat: none (no stick → slip in the window)" in str(stats)


def test_record_built_jump_by_jump_and_other_inputs_agree(tmp_path):
    record = JumpRecord.empty(8)
    for t, up, v_before, v_after, G in HAND:
        record = record.record(jnp.asarray(True), t, up, v_before, v_after, G)
    record = record.record(jnp.asarray(False), 0.9, True, 0.0, 0.0, 0.0)  # not written
    assert int(record.count) == 5
    expected = cycle_statistics(make_record(*hand_arrays()), t_end=1.0)
    assert cycle_statistics(record, t_end=1.0) == expected
    assert cycle_statistics(record.as_numpy(), t_end=1.0) == expected
    # a saved .npz
    np.savez(tmp_path / "jumps.npz", **record.as_numpy())
    with np.load(tmp_path / "jumps.npz") as loaded:
        assert cycle_statistics(loaded, t_end=1.0) == expected
    # NaN-padded arrays with their count
    padded = {f"jump_{name}": np.asarray(getattr(record, name)) for name in ("t", "up", "v_before", "v_after", "G")}
    assert cycle_statistics({**padded, "jump_count": np.asarray(record.count)}, t_end=1.0) == expected
    # a Solution of a fold="jump" run
    solution = Solution(ts=jnp.linspace(0.0, 1.0, 3), ys=jnp.zeros((3, 4)), valid=jnp.ones(3, bool),
                        status=jnp.asarray(0), t_stop=jnp.asarray(1.0), stats={}, diagnostics=None,
                        jumps=record)  # fmt: skip
    assert cycle_statistics(solution, t_end=1.0) == expected


def test_as_dict_round_trips_through_json():
    arrays = orbit(8, T8, repeats=3)
    for stats in (
        cycle_statistics(make_record(*arrays), t_end=arrays[0][-1] + 0.1, transient=0.1),
        cycle_statistics(make_record(*hand_arrays()), t_end=1.0),
        cycle_statistics(JumpRecord.empty(4), t_end=1.0),
    ):
        out = stats.as_dict()
        text = json.dumps(out, allow_nan=False)
        assert "NaN" not in text
        assert json.loads(text) == out
    regular = cycle_statistics(make_record(*arrays), t_end=arrays[0][-1] + 0.1).as_dict()
    assert set(regular["repeat"]) == {"period", "events", "repeats", "spread"}
    assert set(regular["stick_duration"]) == {"mean", "min", "max", "n"}


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"transient": -0.1}, "transient must be >= 0"),
        ({"transient": 1.0}, "transient must be < t_end"),
        ({"transient": 2.0}, "transient must be < t_end"),
        ({"transient": math.nan}, "transient must be finite"),
        ({"rtol": 0.0}, "rtol must be > 0"),
        ({"rtol": -1e-4}, "rtol must be > 0"),
        ({"rtol": math.inf}, "rtol must be finite"),
        ({"t_end": math.nan}, "t_end must be finite"),
        ({"t_end": "soon"}, "t_end must be a real number"),
    ],
)
def test_bad_parameters(kwargs, match):
    args = {"t_end": 1.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        cycle_statistics(make_record(*hand_arrays()), **args)


def test_bad_jump_input():
    record = make_record(*hand_arrays())
    batch = jax.tree.map(lambda a: jnp.stack([a, a]), record)
    with pytest.raises(ValueError, match="single run.*index the batch"):
        cycle_statistics(batch, t_end=1.0)
    with pytest.raises(ValueError, match="jump_G"):
        cycle_statistics({k: v for k, v in record.as_numpy().items() if k != "jump_G"}, t_end=1.0)
    with pytest.raises(ValueError, match="non-decreasing"):
        cycle_statistics(as_mapping(*(a[::-1] for a in hand_arrays())), t_end=1.0)
    with pytest.raises(ValueError, match="jump_t must be finite"):
        cycle_statistics({f"jump_{n}": np.asarray(getattr(record, n)) for n in ("t", "up", "v_before", "v_after", "G")},
                         t_end=1.0)  # fmt: skip
    with pytest.raises(ValueError, match="differ in length"):
        cycle_statistics({**record.as_numpy(), "jump_G": np.ones(2)}, t_end=1.0)
    with pytest.raises(ValueError, match="JumpRecord"):
        cycle_statistics([0.1, 0.2], t_end=1.0)
    solution = Solution(ts=jnp.zeros(1), ys=jnp.zeros((1, 4)), valid=jnp.ones(1, bool), status=jnp.asarray(0),
                        t_stop=jnp.asarray(0.0), stats={}, diagnostics=None)  # fmt: skip
    with pytest.raises(ValueError, match="fold='jump'"):
        cycle_statistics(solution, t_end=1.0)
    with pytest.raises(ValueError, match="rtol must be > 0"):
        repeat_pattern([0.0, 1.0, 2.0], rtol=0.0)
    with pytest.raises(ValueError, match="up_times must be non-decreasing"):
        repeat_pattern([0.0, 2.0, 1.0])
