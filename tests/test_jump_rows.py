"""Both sides of every jump in a run's rows: the output observers on hand-made steps (fast,
nothing integrated), and a real run of the DAE through its folds (one compiled program).

A step that ends at a fold where v jumps hands the observer the state before the jump (``y1``)
and the state after it (``y_after``), both at ``t1``; the output keeps both as two rows with
equal times, the second marked ``after_jump`` (as DifferentialEquations.jl saves both sides of
an event).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax import analysis as A
from peeljax.integrators.observers import AcceptedStep, DenseOutput, StepPoints


class _Linear:
    """The straight line from (t0, y0) to (t1, y1): a stand-in for a step's interpolant."""

    def __init__(self, t0, y0, t1, y1):
        self.t0, self.y0, self.t1, self.y1 = t0, jnp.asarray(y0), t1, jnp.asarray(y1)

    def evaluate(self, ts):
        theta = ((jnp.asarray(ts) - self.t0) / (self.t1 - self.t0))[:, None]
        return (1 - theta) * self.y0 + theta * self.y1


def _step(t0, y0, t1, y1, after=None, advance=True):
    """An accepted step; ``after``: the state just after a jump at t1 (None: no jump)."""
    y0, y1 = jnp.asarray([y0], float), jnp.asarray([y1], float)
    jumped = after is not None
    return AcceptedStep(
        t0=jnp.asarray(t0), t1=jnp.asarray(t1), h=jnp.asarray(t1 - t0), y0=y0, y1=y1, J1=jnp.asarray(1.0),
        iterations=jnp.asarray(3), advance=jnp.asarray(advance), interpolant=_Linear(t0, y0, t1, y1),
        jumped=jnp.asarray(jumped), y_after=jnp.asarray([after if jumped else 0.0], float), J_after=jnp.asarray(-1.0),
    )  # fmt: skip


def _run(observer, steps):
    record = observer.init(jnp.asarray(0.0), jnp.asarray([0.0]), jnp.asarray(1.0), jnp.asarray(True))
    for step in steps:
        record = observer.update(record, step, "lax")
    return record


# y = t, jumping up by 10 at t = 0.5 and down by 10 at t = 0.73 (a third jump at 0.9 finds no room)
_STEPS = [
    _step(0.0, 0.0, 0.25, 0.25),
    _step(0.25, 0.25, 0.4, 0.4, advance=False),  # a rejected attempt: nothing written
    _step(0.25, 0.25, 0.5, 0.5, after=10.5),
    _step(0.5, 10.5, 0.73, 10.73, after=0.73),
    _step(0.73, 0.73, 0.9, 0.9, after=20.9),
]


def test_dense_output_inserts_both_sides_of_each_jump_among_the_output_times():
    """Output times 0, 0.1, …, 1 with room for two jumps: each jump's pair sits at its time in
    time order, an output time equal to a jump's time holds the state before it, a third jump
    finds no room and is left out while every output time is still written, and the times the
    run did not reach (it ends at 0.9) are the rows after the written ones (state NaN)."""
    ts = jnp.linspace(0.0, 1.0, 11)
    out = _run(DenseOutput(ts, jump_rows=2), _STEPS)
    t, y, valid, after = (np.asarray(a) for a in (out.t, out.y[:, 0], out.valid, out.after_jump))
    expected_t = [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.5, 0.5, 0.6, 0.7, 0.73, 0.73, 0.8, 0.9, 1.0]
    np.testing.assert_allclose(t, expected_t, rtol=0, atol=1e-15)
    np.testing.assert_allclose(y[:14], [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.5, 10.5, 10.6, 10.7, 10.73, 0.73, 0.8, 0.9],
                               atol=1e-12)  # fmt: skip
    assert valid[:14].all() and not valid[14] and np.isnan(y[14])
    np.testing.assert_array_equal(np.flatnonzero(after), [7, 11])
    np.testing.assert_array_equal(np.asarray(out.J)[[6, 7]], [1.0, -1.0])  # J_t on each side


def test_dense_output_without_jump_rows_is_the_grid_alone():
    ts = jnp.linspace(0.0, 1.0, 11)
    out = _run(DenseOutput(ts), _STEPS)
    np.testing.assert_array_equal(np.asarray(out.t), np.asarray(ts))
    assert not np.asarray(out.after_jump).any() and not out.keeps_jumps


def test_dense_output_of_a_stopped_run_keeps_the_unreached_times_in_order():
    """A run stopped after one jump: the rows after the written ones hold the output times not
    reached (state NaN), and the jump rows not used repeat the last of them, so the rows stay
    in time order and the last row is the last output time's, as without jumps."""
    ts = jnp.linspace(0.0, 1.0, 11)
    out = _run(DenseOutput(ts, jump_rows=3), _STEPS[:3])
    t, y, valid = np.asarray(out.t), np.asarray(out.y[:, 0]), np.asarray(out.valid)
    np.testing.assert_allclose(t[:13], [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.5, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0], atol=1e-15)
    assert t.size == 17 and (t[13:] == 1.0).all() and np.isnan(y[8:]).all()
    assert valid.sum() == 8 and not np.asarray(out.after_jump)[8:].any()


def test_dense_output_pads_with_the_last_row_and_the_host_drops_it():
    """A completed run with fewer jumps than room: the unused rows repeat the state at the last
    output time (ys[-1] is that state, as without jumps, also under jit), and
    Solution.without_padding() leaves the output times and the jumps."""
    from peeljax.solution import Solution

    ts = jnp.linspace(0.0, 0.5, 6)
    out = _run(DenseOutput(ts, jump_rows=4), _STEPS[:3])  # ends at 0.5, after the jump there
    t, y, valid, after = (np.asarray(a) for a in (out.t, out.y[:, 0], out.valid, out.after_jump))
    assert t.size == 14 and (t[8:] == 0.5).all() and (y[8:] == 10.5).all() and valid.all()
    np.testing.assert_array_equal(np.flatnonzero(after), [7])
    sol = Solution(ts=out.t, ys=out.y, valid=out.valid, status=jnp.asarray(0), t_stop=jnp.asarray(0.5), stats={},
                   diagnostics=None, after_jump=out.after_jump).without_padding()  # fmt: skip
    np.testing.assert_allclose(np.asarray(sol.ts), [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.5, 0.5], atol=1e-15)
    np.testing.assert_array_equal(np.flatnonzero(np.asarray(sol.after_jump)), [7])


def test_step_points_write_the_state_after_a_jump_in_its_own_row():
    out = _run(StepPoints(rows=6, jump_rows=3), _STEPS)
    t, y, after = np.asarray(out.t), np.asarray(out.y[:, 0]), np.asarray(out.after_jump)
    n = int(out.next)
    np.testing.assert_allclose(t[:n], [0, 0.25, 0.5, 0.5, 0.73, 0.73, 0.9, 0.9])
    np.testing.assert_allclose(y[:n], [0, 0.25, 0.5, 10.5, 10.73, 0.73, 0.9, 20.9])
    np.testing.assert_array_equal(np.flatnonzero(after), [3, 5, 7])
    assert np.asarray(out.iterations)[3] == 0 and np.asarray(out.iterations)[2] == 3


def test_time_average_and_interpolation_take_rows_with_equal_times():
    """Rows holding both sides of a jump (equal times) give the time average that inserting the
    jump record gives, whatever the window's ends; numpy's interp is exact on either side."""
    ts = np.array([0.0, 0.2, 0.5, 0.5, 0.7, 1.0])
    x = np.array([0.0, 0.2, 0.5, 3.5, 3.7, 4.0])  # t, then 3 + t after the jump at 0.5
    plain = np.array([0, 1, 2, 4, 5])  # the same rows without the one after the jump
    jump = (np.array([0.5]), np.array([0.5]), np.array([3.5]))
    for window in ((None, None), (0.1, 0.5), (0.5, 0.9), (0.3, 0.8)):
        assert A.time_average(ts, x, *window) == pytest.approx(A.time_average(ts[plain], x[plain], *window, jumps=jump))
    assert A.time_average(ts, x) == pytest.approx(0.5 + 3.0 * 0.5, rel=1e-12)
    assert A.time_average(ts, x, 0.5, 1.0) == pytest.approx(3.75)  # starts after the jump
    assert A.time_average(ts, x, 0.0, 0.5) == pytest.approx(0.25)  # ends before it
    np.testing.assert_allclose(np.interp([0.49, 0.51], ts, x), [0.49, 3.51])


# ---------------------------------------------------------------------------- a real run
@pytest.fixture(scope="module")
def dae_run():
    """The DAE at V = 1.1 to t = 0.2 s on its accepted steps: the first slip (0.1663 s) and
    re-stick (0.1682 s), and the next slip."""
    return pj.simulate(V=1.1, tau=0.0, t_final=0.2)


@pytest.mark.slow
def test_a_run_keeps_v_after_each_jump_in_its_rows(dae_run):
    """Every jump is two rows at its time: v⁻ and v⁺ of the jump record, x the same in both;
    so the run's largest v (summary, analysis) is the v just after a slip."""
    sol = dae_run
    record = sol.jumps.as_numpy()
    valid = np.asarray(sol.valid)
    after, before = np.asarray(sol.after_jump) & valid, np.asarray(sol.before_jump) & valid
    ts, ys = np.asarray(sol.ts), np.asarray(sol.ys)
    assert record["jump_t"].size >= 3 and after.sum() == record["jump_t"].size
    np.testing.assert_array_equal(ts[after], record["jump_t"])
    np.testing.assert_array_equal(ts[before], record["jump_t"])
    np.testing.assert_allclose(ys[after, 3], record["jump_v_after"], rtol=1e-12)
    np.testing.assert_allclose(ys[before, 3], record["jump_v_before"], rtol=1e-12)
    np.testing.assert_allclose(ys[after, :3], ys[before, :3], rtol=1e-14)  # x does not jump
    assert np.all(np.diff(ts[valid]) >= 0)
    v_plus = float(record["jump_v_after"].max())  # 15.318 m/s at the first slip
    assert v_plus > 15.0
    assert sol.summary()["v_max"] == v_plus
    a = A.analyze(sol, V=1.1, tau=0.0, t_transient=0.0)
    assert a.v_max.max() == v_plus and a.amplitude == pytest.approx(0.5 * (v_plus - np.nanmin(a.v)))
    # the rows after a slip are slipping, those after a re-stick stuck
    up = record["jump_up"]
    np.testing.assert_array_equal(a.slip[after], up)
    np.testing.assert_array_equal(a.stick[before], up)


def test_grids_of_lengths_in_one_bucket_share_one_compiled_run(caplog):
    """simulate pads ``ts`` to the next of 8, 10, 12, 14, 16, 20, 24, … rows by repeating its last
    time, and drops those rows after the run: a grid of another length in the same bucket
    compiles nothing, and its rows are the padded grid's without the repeats, the jumps
    after its last time included (bit for bit: one program)."""
    import logging

    import jax

    t_last = 0.167  # between the first slip (0.1663 s) and the re-stick (0.1682 s)
    ts = np.linspace(0.0, t_last, 45)
    short = pj.simulate(V=1.1, tau=0.0, t_final=0.2, ts=ts)
    padded = pj.simulate(V=1.1, tau=0.0, t_final=0.2, ts=np.concatenate([ts, [t_last] * 3]))  # 48: its bucket
    assert int(short.jumps.count) >= 3 and float(short.jumps.t[0]) < t_last < float(short.jumps.t[1])
    assert padded.ts.shape[0] == short.ts.shape[0] + 3
    at_last = np.flatnonzero(np.asarray(padded.ts) == t_last)
    keep = np.setdiff1d(np.arange(padded.ts.shape[0]), at_last[1:4])
    for name in ("ts", "ys", "valid", "after_jump"):
        np.testing.assert_array_equal(np.asarray(getattr(short, name)), np.asarray(getattr(padded, name))[keep], err_msg=name)
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        other = pj.simulate(V=1.1, tau=0.0, t_final=0.2, ts=np.linspace(0.0, t_last, 46))
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling")]
    assert not compiled, compiled  # (the rows are cut on the host)
    assert other.ts.shape[0] == short.ts.shape[0] + 1 and bool(other.completed)


@pytest.mark.parametrize("kind", ["lax", "checkpointed"])
def test_rows_after_those_in_use_are_not_evaluated_and_repeat_the_last(kind):
    """J_t and the DAE's v are computed after the loop on the rows in use only (the room kept
    for jumps mostly stays empty): equal to evaluating every row where in use, the last such
    value after, with the same derivative. (A run's rows came out bit for bit the
    same as before at V = 1.1 with the α-method, Tsit5 and the DAE.)"""
    import jax

    from peeljax.integrators.adaptive import map_rows_in_use

    rows = jnp.linspace(0.0, 1.0, 3 * 700).reshape(700, 3)

    def fn(z):
        return jnp.sin(z) * z[0], jnp.sum(z**2)

    for count in (1, 255, 256, 300, 700):
        values = map_rows_in_use(fn, rows, jnp.asarray(count), kind, block=256)
        full = jax.vmap(fn)(rows)
        for got, want in zip(values, full):
            got, want = np.asarray(got), np.asarray(want)  # (to rounding: XLA vectorizes 256 and 700 rows apart)
            np.testing.assert_allclose(got[:count], want[:count], rtol=1e-15, atol=1e-300)
            np.testing.assert_array_equal(got[count:], np.broadcast_to(got[count - 1], got[count:].shape))

    def loss(rows, use):
        return jnp.sum(use(rows)[0] ** 2)

    def padded(count):  # every row evaluated, the rows after count being the last in use
        return lambda r: jax.vmap(fn)(jnp.where(jnp.arange(700)[:, None] < count, r, r[count - 1]))

    tangent = jnp.cos(rows)
    for count in (300, 700):
        blocked = lambda r: map_rows_in_use(fn, r, jnp.asarray(count), kind, block=256)  # noqa: E731
        if kind == "checkpointed":  # reverse mode, as simulate's default loop
            got, want = (jax.grad(loss)(rows, use) for use in (blocked, padded(count)))
        else:  # forward mode only, as the plain while loop
            got, want = (jax.jvp(lambda r: loss(r, use), (rows,), (tangent,))[1] for use in (blocked, padded(count)))
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-13, atol=1e-13)


@pytest.mark.slow
def test_jump_rows_under_an_eager_jvp_are_merged_in_the_program():
    """Under ``jax.jvp`` outside ``jit`` some of a run's arrays are traced and others (the output
    times, the count of rows) are not: the jumps' rows are then merged at the static size,
    ``len(ts) + 2·max_jumps``, as under ``jit`` — never on the host (slow: its forward-mode
    program compiles for ~30 s)."""
    import jax

    ts = np.linspace(0.0, 0.2, 5)

    def v(V):
        return pj.simulate(V=V, tau=0.0, t_final=0.2, ts=ts, max_jumps=8, adjoint="forward").ys[:, 3]

    values, tangents = jax.jvp(v, (1.1,), (1.0,))
    assert values.shape == tangents.shape == (ts.size + 2 * 8,)
    assert np.all(np.isfinite(np.asarray(tangents)))
    on_host = np.asarray(v(1.1))  # the rows in use, merged on the host
    values, used = np.asarray(values), on_host.size
    assert ts.size < used < values.size
    np.testing.assert_allclose(values[:used], on_host, rtol=1e-5)  # (another program: its steps may differ)
    assert np.all(values[used:] == values[used - 1])  # the padding repeats the last row
