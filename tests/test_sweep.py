"""peeljax.sweep: summaries equal those of full simulate runs; layouts, compilation, chunks, resume.

Short runs (40 steps of 0.01 s) at V ∈ {1.1, 2}, τ ∈ {1e-3, 1e-2}: at V = 1.1, τ = 1e-3 the run
stops (t ≈ 0.17 s), the others complete, so both kinds of lane are covered. The batch shapes
are few (chunk 4 with saved states; a parameter sweep and the 4-device run in ``slow`` tests),
so that the fast tests compile the sweep once and simulate once.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax
from peeljax import PeelingModel, StopReason, simulate
from peeljax.sweeps import api, engine, slip_velocity

DT, T_FINAL, N = 0.01, 0.4, 40
V_AXIS, TAU_AXIS = [1.1, 2.0], [1e-3, 1e-2]
WINDOW = (0.25, 1.0)
SUMMARY_KEYS = ("status", "t_stop", "v_mean", "v_std", "v_min", "v_max", "v_final", "events", "window_count")


def small_sweep(**kwargs):
    options = {
        "V": V_AXIS,
        "tau": TAU_AXIS,
        "dt": DT,
        "t_final": T_FINAL,
        "window": WINDOW,
        "chunk": 4,
        "save_every": 5,
        "progress": False,
    }
    options.update(kwargs)
    return peeljax.sweep(**options)


@pytest.fixture(scope="module")
def saved():
    return small_sweep()


@pytest.fixture(scope="module")
def plain(saved):
    return saved  # one batch shape for the whole module: one compilation


def reference_summary(V, tau, v_slip):
    """The summaries from a full simulate trajectory (the definitions in peeljax.sweeps.engine)."""
    solution = simulate(PeelingModel(), V, tau, DT, T_FINAL)
    ts, valid = np.asarray(solution.ts), np.asarray(solution.valid)
    v = np.asarray(solution.ys)[:, 3]
    w = valid & (ts >= WINDOW[0] * T_FINAL - 1e-12) & (ts <= WINDOW[1] * T_FINAL + 1e-12)
    crossings = np.zeros_like(valid)
    crossings[1:] = valid[1:] & valid[:-1] & (v[:-1] < v_slip) & (v[1:] >= v_slip)
    last = np.flatnonzero(valid)[-1]
    return solution, {
        "status": int(solution.status),
        "t_stop": float(solution.t_stop),
        "v_mean": v[w].mean(),
        "v_std": v[w].std(),
        "v_min": v[w].min(),
        "v_max": v[w].max(),
        "v_final": v[last],
        "events": int(np.sum(crossings & w)),
        "window_count": int(w.sum()),
    }


def test_layout_and_statuses(saved):
    assert len(saved) == 4 and saved.grid_shape == (2, 2)
    np.testing.assert_array_equal(saved.V, [1.1, 1.1, 2.0, 2.0])
    np.testing.assert_array_equal(saved.tau, [1e-3, 1e-2, 1e-3, 1e-2])
    assert saved.status[0] != 0 and saved.t_stop[0] < T_FINAL  # V = 1.1, τ = 1e-3 stops early
    assert saved.completed[1:].all()
    np.testing.assert_array_equal(saved.grid("completed"), saved.completed.reshape(2, 2))
    assert saved.reasons[1] == "completed"


def test_summaries_equal_full_trajectories(saved):
    for i in range(len(saved)):
        solution, expected = reference_summary(saved.V[i], saved.tau[i], saved.v_slip[i])
        for key, value in expected.items():
            np.testing.assert_allclose(getattr(saved, key)[i], value, rtol=1e-9, atol=1e-13, err_msg=f"{key}, lane {i}")
        # saved states: every 5th state of the full trajectory, NaN after the stop
        np.testing.assert_allclose(saved.ys[i], np.asarray(solution.ys)[::5], rtol=1e-12, atol=1e-15, equal_nan=True)
        assert int(saved.subdivided_steps[i]) == int(solution.stats["subdivided_steps"])
        assert int(saved.newton_iterations[i]) == int(solution.stats["newton_iterations"])
    np.testing.assert_allclose(saved.ts, DT * 5 * np.arange(9))
    assert saved.events.sum() > 0  # the start ramps v through the maximum of φ inside the window


def test_slip_velocity_is_the_maximum_of_phi():
    model = PeelingModel()
    Vs = (1.1, 2.0, 4.0)
    v_slip = np.asarray(jax.jit(jax.vmap(lambda V: slip_velocity(model, V)))(jnp.asarray(Vs)))
    for V, found in zip(Vs, v_slip):
        v = np.geomspace(1e-6, 10.0, 200_001)
        phi = np.asarray(model.phi(jnp.asarray(v), V))
        first_max = np.flatnonzero((phi[1:-1] > phi[:-2]) & (phi[1:-1] >= phi[2:]))[0] + 1  # first local maximum
        np.testing.assert_allclose(found, v[first_max], rtol=1e-4)


def test_pairs_equal_outer(plain):
    pairs = small_sweep(grid="pairs", V=plain.V, tau=plain.tau)
    assert pairs.grid_shape is None
    for key in SUMMARY_KEYS:
        np.testing.assert_array_equal(getattr(pairs, key), getattr(plain, key), err_msg=key)
    broadcast = small_sweep(grid="pairs", V=2.0, tau=TAU_AXIS * 2)  # length 1 broadcasts
    np.testing.assert_array_equal(broadcast.v_mean, np.tile(plain.v_mean[2:], 2))


@pytest.mark.slow
def test_one_compilation_whatever_the_values(plain):
    small_sweep()  # the fixture's sweep: compiled here if the caches were emptied since
    size = engine.run_batch._cached._cache_size()
    small_sweep(V=[1.3, 2.5], tau=[2e-3, 5e-2])
    assert engine.run_batch._cached._cache_size() == size  # new values: no new compilation
    # Sweeping model parameters adds at most one entry (another pytree of traced leaves; none
    # where a test before this one in the same worker compiled it), whatever their values.
    result = small_sweep(V=[2.0], tau=[1e-2], params={"k": [800.0, 1200.0], "c6": [415.0, 400.0]})
    with_params = engine.run_batch._cached._cache_size()
    assert with_params <= size + 1
    small_sweep(V=[2.0], tau=[1e-2], params={"k": [700.0, 1100.0], "c6": [405.0, 420.0]})
    assert engine.run_batch._cached._cache_size() == with_params
    assert result.grid_shape == (1, 1, 2, 2)
    np.testing.assert_array_equal(result.params["k"], [800.0, 800.0, 1200.0, 1200.0])
    from peeljax import AdhesionLaw

    for i in (1, 2):
        model = PeelingModel(k=result.params["k"][i], adhesion=AdhesionLaw(c6=result.params["c6"][i]))
        solution = simulate(model, 2.0, 1e-2, DT, T_FINAL)
        np.testing.assert_allclose(result.v_final[i], np.asarray(solution.ys)[-1, 3], rtol=1e-12)


def test_chunked_equals_one_chunk(plain):
    chunked = small_sweep(V=V_AXIS + [1.1], tau=TAU_AXIS, chunk=4)  # 6 trajectories: 2 chunks, the last padded
    np.testing.assert_array_equal(chunked.V, [1.1, 1.1, 2.0, 2.0, 1.1, 1.1])
    for key in SUMMARY_KEYS:
        np.testing.assert_array_equal(getattr(chunked, key)[:4], getattr(plain, key), err_msg=key)
        np.testing.assert_array_equal(getattr(chunked, key)[4:], getattr(plain, key)[:2], err_msg=key)


def test_resume_skips_finished_chunks(plain, tmp_path, monkeypatch):
    out = tmp_path / "sweep.npz"
    V = V_AXIS + [1.1, 2.0]  # 8 trajectories, 2 chunks of 4
    calls = []
    original = engine.run_batch

    def interrupted(*args, **kwargs):
        if calls:
            raise KeyboardInterrupt("interrupted after the first chunk")
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(engine, "run_batch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        small_sweep(V=V, out=out)
    assert (tmp_path / "sweep.npz.chunks" / "chunk_00000.npz").exists()
    assert not (tmp_path / "sweep.npz.chunks" / "chunk_00001.npz").exists() and not out.exists()
    monkeypatch.setattr(engine, "run_batch", original)
    resumed = small_sweep(V=V, out=out)
    assert resumed.computed_chunks == (1,)
    for key in SUMMARY_KEYS:
        np.testing.assert_array_equal(getattr(resumed, key), np.tile(getattr(plain, key), 2), err_msg=key)
    with np.load(out, allow_pickle=False) as data:
        for key in api.PER_TRAJECTORY_KEYS:
            assert data[key].shape == (8,), key
        assert data["completed"].dtype == bool
        assert json.loads(str(data["meta_json"]))["settings"]["V"] == V
    again = small_sweep(V=V, out=out)  # finished: loaded, nothing computed
    assert again.computed_chunks == ()
    np.testing.assert_array_equal(again.v_mean, resumed.v_mean)


def test_resume_refuses_other_settings_and_malformed_files(tmp_path, monkeypatch):
    out = tmp_path / "s.npz"
    small_sweep(out=out)
    with pytest.raises(ValueError, match=r"different settings \(tau differ\)"):
        small_sweep(tau=[1e-3, 2e-2], out=out)
    with pytest.raises(ValueError, match="window differ"):
        small_sweep(window=(0.5, 1.0), out=out)
    # a malformed chunk of an unfinished sweep
    out.unlink()
    chunk = tmp_path / "s.npz.chunks" / "chunk_00000.npz"
    chunk.write_bytes(b"not an npz")
    monkeypatch.setattr(engine, "run_batch", lambda *a, **k: pytest.fail("must not run"))
    with pytest.raises(ValueError, match="not a readable .npz"):
        small_sweep(out=out)
    np.savez(chunk, status=np.zeros(3))
    with pytest.raises(ValueError, match="malformed: missing"):
        small_sweep(out=out)
    (tmp_path / "s.npz.chunks" / "meta.json").write_text("{broken")
    with pytest.raises(ValueError, match="not valid JSON"):
        small_sweep(out=out)
    (tmp_path / "s.npz.chunks" / "meta.json").write_text(json.dumps({"something": 1}))
    with pytest.raises(ValueError, match="not a peeljax sweep output"):
        small_sweep(out=out)
    other = tmp_path / "other.npz"
    np.savez(other, V=np.ones(4))
    with pytest.raises(ValueError, match="malformed: missing"):
        small_sweep(out=other)


def test_memory_refusal_before_running(monkeypatch):
    monkeypatch.setattr(engine, "run_batch", lambda *a, **k: pytest.fail("must not run"))
    with pytest.raises(ValueError, match="larger save_every, now 1"):
        small_sweep(save_every=1, memory_limit=1000)
    with pytest.raises(ValueError, match="memory limit"):
        peeljax.sweep(V=np.linspace(1, 4, 1000), tau=np.geomspace(1e-3, 1, 1000), dt=1e-4, t_final=3.0, save_every=10,
                      progress=False)  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"V": []}, "V is empty"),
        ({"tau": [1e-3, -1.0]}, r"tau must be >= 0 \(allowed range"),
        ({"tau": [0.0, 1e-3]}, r"tau = 0 \(the DAE itself\) and tau > 0"),
        ({"V": [1.1, np.nan]}, "V must be finite"),
        ({"tau": [[1e-3]]}, "1-D"),
        ({"grid": "cross"}, "grid must be one of"),
        ({"grid": "pairs", "V": [1, 2, 3]}, "equal lengths"),
        ({"window": (0.5, 1.5)}, "window"),
        ({"save_every": 0}, "save_every"),
        ({"chunk": 0}, "chunk"),
        ({"dt": 1.0}, "dt must be <= t_final"),
        ({"params": {"zeta": [1.0]}}, "unknown model parameter"),
        ({"params": {"k": [0.0]}}, r"k must be > 0"),
        ({"rho": 1.0}, "rho"),
    ],
)
def test_bad_input_rejected_before_compiling(kwargs, match, monkeypatch):
    monkeypatch.setattr(engine, "run_batch", lambda *a, **k: pytest.fail("must not run"))
    with pytest.raises(ValueError, match=match):
        small_sweep(**kwargs)


SHARDED = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import jax
    import peeljax
    assert len(jax.devices()) == 4, jax.devices()
    kwargs = dict(V=[1.1, 2.0, 1.1], tau=[1e-3, 1e-2], dt=0.01, t_final=0.4, window=(0.25, 1.0), save_every=5,
                  chunk=5, progress=False)
    many = peeljax.sweep(**kwargs)
    one = peeljax.sweep(**{**kwargs, "chunk": 8}, devices=jax.devices()[:1])
    assert many.settings["chunk"] == 8, many.settings["chunk"]  # rounded up to a multiple of 4
    for key in ("status", "completed", "t_stop", "events", "window_count"):
        np.testing.assert_array_equal(getattr(many, key), getattr(one, key), err_msg=key)
    # XLA fuses the partitioned program differently: floating-point values agree to rounding.
    for key in ("v_mean", "v_std", "v_min", "v_max", "ys"):
        np.testing.assert_allclose(getattr(many, key), getattr(one, key), rtol=1e-12, atol=1e-13, err_msg=key)
    # Error control: each device runs its lanes one after another, as one device does.
    adaptive = dict(V=[1.1, 2.0, 1.1], tau=[1e-3, 1e-2], t_final=0.4, window=(0.25, 1.0), save_dt=0.05, chunk=5,
                    progress=False)
    many_a = peeljax.sweep(**adaptive)
    one_a = peeljax.sweep(**{**adaptive, "chunk": 8}, devices=jax.devices()[:1])
    for key in ("status", "accepted_steps", "rejected_steps", "events", "window_count"):
        np.testing.assert_array_equal(getattr(many_a, key), getattr(one_a, key), err_msg=key)
    for key in ("t_stop", "v_mean", "v_std", "v_min", "v_max", "ys"):
        np.testing.assert_allclose(getattr(many_a, key), getattr(one_a, key), rtol=1e-12, atol=1e-13, err_msg=key)
    print(json.dumps({"ok": True, "completed": many.completed.tolist()}))
    """
)


@pytest.mark.slow
def test_four_devices_identical_to_one():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    run = subprocess.run(
        [sys.executable, "-c", SHARDED], env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert run.returncode == 0, run.stderr[-3000:]
    record = json.loads(run.stdout.strip().splitlines()[-1])
    assert record["ok"] and record["completed"] == [False, True, True, True, False, True]


def test_stop_reason_codes_are_known(plain):
    assert set(plain.status.tolist()) <= {int(r) for r in StopReason}
