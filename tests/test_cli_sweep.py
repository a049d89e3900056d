"""``peeljax sweep`` and ``peeljax tau-star``: outputs, resume, and bad input rejected before compiling.

The uniform-mesh sweep (``--dt``) uses the batch shape of tests/test_sweep.py (4 trajectories
of 40 steps, states every 5 steps), so in one pytest process it compiles at most once. The
error-controlled sweep (the default, no ``--dt``) and tau-star runs are as small: 4 lanes to
t = 0.4 s.
"""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest
from conftest import PNG_MAGIC, forbid, run_cli, run_cli_writing

from peeljax.cli import build_parser
from peeljax.cli import sweep as sweep_cli
from peeljax.cli import tau_star as tau_star_cli
from peeljax.sweeps import LeastTau, least_tau, sweep

SWEEP = ["sweep", "--V", "1.1", "2", "--tau", "1e-3", "1e-2", "--n-tau", "2", "--dt", "0.01", "--t-final", "0.4",
         "--chunk", "4", "--save-every", "5", "--transient", "0.1", "--window", "0.3", "--no-progress"]  # fmt: skip
SWEEP_ADAPTIVE = ["sweep", "--V", "1.1", "2", "--tau", "1e-3", "1e-2", "--t-final", "0.4", "--chunk", "4",
                  "--save-dt", "0.05", "--window", "0.25", "1", "--no-progress"]  # fmt: skip (the old --window W0 W1)
NPZ_KEYS = {"V", "tau", "completed", "status", "t_stop", "v_mean", "v_std", "v_min", "v_max", "events", "ts", "ys",
            "accepted_steps", "rejected_steps", "window_time"}  # fmt: skip


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    return run_cli_writing(tmp_path_factory.mktemp("sweep"), SWEEP)


def test_sweep_json_and_files(swept):
    assert swept["code"] == 0, swept["stderr"]
    record = json.loads(swept["stdout"])  # exactly one JSON object
    assert record["n"] == 4 and record["n_completed"] == 3 and record["computed_chunks"] == [0]
    assert record["tau"] == pytest.approx([1e-3, 1e-2])
    assert record["method"] == "alpha" and record["dt"] == 0.01 and record["rtol"] is None and record["atol"] is None
    assert record["save_every"] == 5 and record["save_dt"] is None
    assert record["window"] == [0.25, 1.0] and record["transient"] == pytest.approx(0.1)  # --transient 0.1 --window 0.3
    assert set(record["trajectories"]) >= {"V", "tau", "completed", "t_stop", "v_mean", "v_std", "events",
                                           "accepted_steps", "rejected_steps", "window_time"}  # fmt: skip
    assert record["trajectories"]["rejected_steps"] == [0, 0, 0, 0]  # the uniform mesh rejects nothing
    assert "uniform mesh dt = 0.01 s (40 steps)" in swept["stderr"]
    assert swept["png"].read_bytes()[:8] == PNG_MAGIC
    with np.load(swept["npz"], allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    assert NPZ_KEYS <= set(arrays)
    for key in NPZ_KEYS - {"ts", "ys"}:
        assert arrays[key].shape == (4,), key
    assert arrays["completed"].dtype == bool and arrays["completed"].tolist() == [False, True, True, True]
    np.testing.assert_allclose(arrays["V"], [1.1, 1.1, 2.0, 2.0])
    assert arrays["ys"].shape == (4, 9, 4)
    settings = json.loads(str(arrays["meta_json"]))["settings"]
    assert settings["dt"] == 0.01 and settings["n_steps"] == 40 and settings["save_every"] == 5
    assert "method" not in settings and "rtol" not in settings


def test_sweep_rerun_resumes_and_prints_table(swept):
    code, out, err = run_cli([*SWEEP, "--out", str(swept["npz"])])
    assert code == 0, err
    assert "4 trajectories, 3 completed" in out
    assert "uniform mesh dt = 0.01 s (40 steps)" in out
    assert "newton_failed" in out or "impasse" in out
    code, out, err = run_cli([*SWEEP, "--out", str(swept["npz"]), "--json"])
    assert json.loads(out)["computed_chunks"] == []


def test_sweep_refuses_other_settings(swept):
    argv = [*SWEEP, "--out", str(swept["npz"])]
    argv[argv.index("0.4")] = "0.5"  # another t_final
    code, _out, err = run_cli(argv)
    assert code == 2 and "made with a different --t-final;" in err and "choose another --out" in err, err


def test_sweep_refusal_names_what_the_user_changed(swept, no_compilation):
    """Another --n-tau (and, without --chunk, the batch size that follows from the grid): the
    refusal named ``chunk``, which the user never set; it names --tau/--n-tau."""
    argv = [*SWEEP, "--out", str(swept["npz"])]
    argv[argv.index("--n-tau") + 1] = "3"
    del argv[argv.index("--chunk") : argv.index("--chunk") + 2]
    code, out, err = run_cli(argv)
    line = err.strip().splitlines()[-1]
    assert code == 2 and out == "" and line.startswith("peeljax: error: ")
    assert line.split(" was made with ")[1].split(";")[0] == "a different --tau/--n-tau", line


@pytest.fixture(scope="module")
def swept_adaptive(tmp_path_factory):
    return run_cli_writing(tmp_path_factory.mktemp("sweep_adaptive"), SWEEP_ADAPTIVE)


def test_sweep_without_dt_runs_error_control(swept_adaptive):
    assert swept_adaptive["code"] == 0, swept_adaptive["stderr"]
    assert "error control rtol = 1e-06, atol = 1e-09" in swept_adaptive["stderr"]
    assert "--window 0.25 1 (fractions of t_final) is deprecated" in swept_adaptive["stderr"]
    assert "give --transient 0.1 --window 0.3" in swept_adaptive["stderr"]
    record = json.loads(swept_adaptive["stdout"])
    assert record["n"] == 4 and record["computed_chunks"] == [0]
    assert record["method"] == "switching-tsit5-alpha" and record["dt"] is None
    assert record["rtol"] == 1e-6 and record["atol"] == 1e-9
    assert record["save_dt"] == 0.05 and record["save_every"] is None
    trajectories = record["trajectories"]
    assert all(steps > 0 for steps in trajectories["accepted_steps"])
    assert all(0 <= time <= 0.3 + 1e-12 for time in trajectories["window_time"])  # the window is [0.1, 0.4] s
    completed = np.asarray(trajectories["completed"])
    assert completed.any()
    np.testing.assert_allclose(np.asarray(trajectories["window_time"])[completed], 0.3)
    assert swept_adaptive["png"].read_bytes()[:8] == PNG_MAGIC
    with np.load(swept_adaptive["npz"], allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    assert NPZ_KEYS <= set(arrays)
    settings = json.loads(str(arrays["meta_json"]))["settings"]
    assert settings["method"] == "switching-tsit5-alpha" and settings["rtol"] == 1e-6 and settings["atol"] == 1e-9
    assert settings["save_dt"] == 0.05 and "dt" not in settings
    np.testing.assert_allclose(arrays["ts"], np.linspace(0.0, 0.4, 9))
    assert arrays["ys"].shape == (4, 9, 4)
    np.testing.assert_array_equal(arrays["accepted_steps"], trajectories["accepted_steps"])


def test_sweep_error_control_table_names_tolerances(swept_adaptive):
    code, out, err = run_cli([*SWEEP_ADAPTIVE, "--out", str(swept_adaptive["npz"])])  # loaded, not recomputed
    assert code == 0, err
    assert "switching-tsit5-alpha, error control rtol = 1e-06, atol = 1e-09" in out
    assert "rejected" in out.splitlines()[2]  # the table's header
    # other tolerances are other settings: refused for this --out, before anything runs
    code, _out, err = run_cli([*SWEEP_ADAPTIVE, "--out", str(swept_adaptive["npz"]), "--rtol", "1e-4"])
    assert code == 2 and "made with a different --rtol;" in err


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        ([], {"dt": None, "rtol": 1e-6, "atol": 1e-9, "save_dt": None, "save_every": None}),
        (["--rtol", "1e-4", "--atol", "1e-8", "--save-dt", "0.1"],
         {"dt": None, "rtol": 1e-4, "atol": 1e-8, "save_dt": 0.1, "save_every": None}),
        (["--dt", "0.01", "--save-every", "4"], {"dt": 0.01, "rtol": None, "atol": None, "save_dt": None, "save_every": 4}),
    ],
)  # fmt: skip
def test_sweep_options_reach_the_api(extra, expected):
    args = build_parser().parse_args(["sweep", "--t-final", "0.4", *extra])
    kwargs = sweep_cli.validate_sweep(args)
    assert {key: kwargs[key] for key in expected} == expected
    sweep_settings = inspect.signature(sweep).parameters
    assert set(kwargs) <= set(sweep_settings)


def test_tau_star_without_dt_runs_error_control():
    argv = ["tau-star", "--V", "1.1", "--tau-range", "1e-3", "1e-2", "--n-points", "4", "--tau-rtol", "0.2",
            "--t-final", "0.4", "--json"]  # fmt: skip
    code, out, err = run_cli(argv)
    assert code == 0, err
    assert "error control rtol = 1e-06, atol = 1e-09" in err
    record = json.loads(out)
    assert record["method"] == "switching-tsit5-alpha" and record["dt"] is None
    assert record["rtol"] == 1e-6 and record["atol"] == 1e-9 and record["tau_rtol"] == 0.2
    assert record["found"] == [True]
    assert 1e-3 < record["tau_star"][0] <= 1e-2
    assert record["tau_below"][0] == pytest.approx(record["tau_star"][0] * 0.8, rel=1e-9)
    args = build_parser().parse_args(["tau-star", "--rtol", "1e-5", "--atol", "1e-10"])
    kwargs = tau_star_cli.validate_tau_star(args)
    assert (kwargs["dt"], kwargs["rtol"], kwargs["atol"]) == (None, 1e-5, 1e-10)
    assert set(kwargs) <= set(inspect.signature(least_tau).parameters)


def test_tau_star_json(monkeypatch):
    def fake(kwargs):
        V = np.asarray(kwargs["V"])
        return LeastTau(V=V, tau_star=np.full(V.size, 2e-3), tau_below=np.full(V.size, 1.9e-3),
                        found=np.ones(V.size, bool), t_stop_below=np.full(V.size, 0.3), rounds=3, tested=[],
                        settings={})  # fmt: skip

    monkeypatch.setattr(tau_star_cli, "_run_tau_star", fake)
    code, out, err = run_cli(["tau-star", "--V", "1.1", "2", "4", "--dt", "0.01", "--t-final", "1", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["V"] == [1.1, 2.0, 4.0] and record["tau_star"] == [2e-3] * 3
    assert {"found", "tau_below", "rounds", "dt", "tau_rtol", "method", "rtol", "atol"} <= set(record)
    assert record["dt"] == 0.01 and record["method"] == "alpha" and record["rtol"] is None
    code, out, err = run_cli(["tau-star", "--V", "1.1", "--dt", "0.01", "--t-final", "1"])
    assert code == 0 and "tau* = 0.002" in out
    assert "uniform mesh dt = 0.01 s (100 steps)" in out
    code, out, err = run_cli(["tau-star", "--V", "1.1", "--t-final", "1", "--rtol", "1e-5"])
    assert code == 0 and "error control rtol = 1e-05, atol = 1e-09" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sweep", "--V"], "expected at least one argument"),
        (["sweep", "--V", "0"], "--V must be > 0 (allowed range: (0, inf))"),
        (["sweep", "--V", "nan"], "--V must be finite (allowed range: (0, inf))"),
        (["sweep", "--tau", "0", "1e-2"], "--tau must be finite and > 0"),
        (["sweep", "--tau", "inf"], "--tau must be finite (allowed range: (0, 1e+06])"),
        (["sweep", "--tau", "1e-3", "--n-tau", "4"], "exactly two --tau values"),
        (["sweep", "--tau", "1e-1", "1e-3", "--n-tau", "4"], "LO < HI"),
        (["sweep", "--n-tau", "1"], "--n-tau must be an integer >= 2"),
        (["sweep", "--dt", "0"], "dt must be > 0"),
        (["sweep", "--dt", "5"], "--dt must be <= --t-final"),
        (["sweep", "--t-final", "nan"], "--t-final must be finite"),
        (["sweep", "--rho", "1"], "rho"),
        (["sweep", "--chunk", "0"], "--chunk must be a positive integer"),
        (["sweep", "--window", "0.5", "2"], "--window"),
        (["sweep", "--dt", "0.01", "--save-every", "0"], "--save-every must be an integer in [1, 300]"),
        (["sweep", "--save-every", "5"], "--save-every counts uniform-mesh steps (--dt given)"),
        (["sweep", "--dt", "0.01", "--rtol", "1e-4"], "--rtol applies to error control (no --dt); it cannot be combined with --dt"),
        (["sweep", "--dt", "0.01", "--atol", "1e-8"], "--atol applies to error control (no --dt)"),
        (["sweep", "--dt", "0.01", "--save-dt", "0.1"], "--save-dt applies to error control (no --dt)"),
        (["sweep", "--dt", "0.01", "--rtol", "1e-4", "--atol", "1e-8"], "--rtol applies to error control (no --dt)"),
        (["sweep", "--rtol", "0"], "--rtol must lie in (0, 1)"),
        (["sweep", "--rtol", "1"], "--rtol must lie in (0, 1)"),
        (["sweep", "--atol=-1e-9"], "--atol must lie in (0, inf)"),
        (["sweep", "--atol", "nan"], "--atol must lie in (0, inf)"),
        (["sweep", "--save-dt", "0"], "--save-dt must be > 0 (allowed range: (0, inf))"),
        (["sweep", "--save-dt", "5"], "--save-dt must lie in (0, --t-final]"),
        (["sweep", "--save-dt", "1e-12"], "the limit is 1e7"),
        (["sweep", "--window", "0.5", "0.5"], "0 <= W0 < W1 <= 1"),
        (["sweep", "--t-final", "0"], "--t-final must be > 0"),
        (["sweep", "--out", "/nonexistent/folder/x.npz"], "does not exist"),
        (["sweep", "--plot", "map.xyz"], "unknown image format"),
        (["tau-star", "--V", "1.1", "0"], "--V must be > 0 (allowed range: (0, inf))"),
        (["tau-star", "--tau-range", "1", "0.1"], "--tau-range"),
        (["tau-star", "--tau-rtol", "0"], "--tau-rtol"),
        (["tau-star", "--n-points", "1"], "--n-points"),
        (["tau-star", "--dt", "0.01", "--rtol", "1e-4"], "--rtol applies to error control (no --dt); it cannot be combined"),
        (["tau-star", "--dt", "0.01", "--atol", "1e-8"], "--atol applies to error control (no --dt)"),
        (["tau-star", "--rtol", "2"], "--rtol must lie in (0, 1)"),
        (["tau-star", "--save-dt", "0.1"], "unrecognized option --save-dt"),
        (["tau-star", "--save-every", "2"], "unrecognized option --save-every"),
    ],
)
def test_bad_input_exits_2_without_compiling(argv, message, monkeypatch):
    forbid(monkeypatch, sweep_cli, "_run_sweep", reason="must not run")
    forbid(monkeypatch, tau_star_cli, "_run_tau_star", reason="must not run")
    code, out, err = run_cli(argv)
    assert code == 2
    assert message in err, err
    assert out == ""
