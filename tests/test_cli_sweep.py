"""``peeljax sweep`` and ``peeljax tau-star``: outputs, resume, and bad input rejected before compiling.

The sweep uses the batch shape of tests/test_sweep.py (4 trajectories of 40 steps, states
every 5 steps), so in one pytest process it compiles at most once.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from peeljax.cli import main
from peeljax.cli import sweep as sweep_cli
from peeljax.sweeps import LeastTau

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SWEEP = ["sweep", "--V", "1.1", "2", "--tau", "1e-3", "1e-2", "--n-tau", "2", "--dt", "0.01", "--t-final", "0.4",
         "--chunk", "4", "--save-every", "5", "--window", "0.25", "1", "--no-progress"]  # fmt: skip
NPZ_KEYS = {"V", "tau", "completed", "status", "t_stop", "v_mean", "v_std", "v_min", "v_max", "events", "ts", "ys"}


def run_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    npz, png = folder / "sweep.npz", folder / "map.png"
    code, out, err = run_main([*SWEEP, "--out", str(npz), "--plot", str(png), "--json"])
    return {"code": code, "stdout": out, "stderr": err, "npz": npz, "png": png}


def test_sweep_json_and_files(swept):
    assert swept["code"] == 0, swept["stderr"]
    record = json.loads(swept["stdout"])  # exactly one JSON object
    assert record["n"] == 4 and record["n_completed"] == 3 and record["computed_chunks"] == [0]
    assert record["tau"] == pytest.approx([1e-3, 1e-2])
    assert set(record["trajectories"]) >= {"V", "tau", "completed", "t_stop", "v_mean", "v_std", "events"}
    assert swept["png"].read_bytes()[:8] == PNG_MAGIC
    with np.load(swept["npz"], allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    assert NPZ_KEYS <= set(arrays)
    for key in NPZ_KEYS - {"ts", "ys"}:
        assert arrays[key].shape == (4,), key
    assert arrays["completed"].dtype == bool and arrays["completed"].tolist() == [False, True, True, True]
    np.testing.assert_allclose(arrays["V"], [1.1, 1.1, 2.0, 2.0])
    assert arrays["ys"].shape == (4, 9, 4)


def test_sweep_rerun_resumes_and_prints_table(swept):
    code, out, err = run_main([*SWEEP, "--out", str(swept["npz"])])
    assert code == 0, err
    assert "4 trajectories, 3 completed" in out
    assert "newton_failed" in out or "impasse" in out
    code, out, err = run_main([*SWEEP, "--out", str(swept["npz"]), "--json"])
    assert json.loads(out)["computed_chunks"] == []


def test_sweep_refuses_other_settings(swept):
    argv = [*SWEEP, "--out", str(swept["npz"])]
    argv[argv.index("0.4")] = "0.5"  # another t_final
    code, _out, err = run_main(argv)
    assert code == 2 and "different settings" in err and "t_final" in err


def test_tau_star_json(monkeypatch):
    def fake(kwargs):
        V = np.asarray(kwargs["V"])
        return LeastTau(V=V, tau_star=np.full(V.size, 2e-3), tau_below=np.full(V.size, 1.9e-3),
                        found=np.ones(V.size, bool), t_stop_below=np.full(V.size, 0.3), rounds=3, tested=[],
                        settings={})  # fmt: skip

    monkeypatch.setattr(sweep_cli, "_run_tau_star", fake)
    code, out, err = run_main(["tau-star", "--V", "1.1", "2", "4", "--dt", "0.01", "--t-final", "1", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["V"] == [1.1, 2.0, 4.0] and record["tau_star"] == [2e-3] * 3
    assert {"found", "tau_below", "rounds", "dt", "tau_rtol"} <= set(record)
    code, out, err = run_main(["tau-star", "--V", "1.1", "--dt", "0.01", "--t-final", "1"])
    assert code == 0 and "tau* = 0.002" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sweep", "--V"], "expected at least one argument"),
        (["sweep", "--V", "0"], "--V must be finite and > 0"),
        (["sweep", "--V", "nan"], "--V must be finite and > 0"),
        (["sweep", "--tau", "0", "1e-2"], "--tau must be finite and > 0"),
        (["sweep", "--tau", "inf"], "--tau must be finite and > 0"),
        (["sweep", "--tau", "1e-3", "--n-tau", "4"], "exactly two --tau values"),
        (["sweep", "--tau", "1e-1", "1e-3", "--n-tau", "4"], "LO < HI"),
        (["sweep", "--n-tau", "1"], "--n-tau must be an integer >= 2"),
        (["sweep", "--dt", "0"], "dt must be > 0"),
        (["sweep", "--dt", "5"], "dt must be <= t_final"),
        (["sweep", "--t-final", "nan"], "t_final must be finite"),
        (["sweep", "--rho", "1"], "rho"),
        (["sweep", "--chunk", "0"], "--chunk must be a positive integer"),
        (["sweep", "--window", "0.5", "2"], "--window"),
        (["sweep", "--save-every", "0"], "--save-every"),
        (["sweep", "--out", "/nonexistent/folder/x.npz"], "does not exist"),
        (["sweep", "--plot", "map.xyz"], "unknown image format"),
        (["tau-star", "--V", "1.1", "0"], "--V must be finite and > 0"),
        (["tau-star", "--tau-range", "1", "0.1"], "--tau-range"),
        (["tau-star", "--tau-rtol", "0"], "--tau-rtol"),
        (["tau-star", "--n-points", "1"], "--n-points"),
    ],
)
def test_bad_input_exits_2_without_compiling(argv, message, monkeypatch):
    def forbidden(kwargs):
        raise AssertionError("must not run")

    monkeypatch.setattr(sweep_cli, "_run_sweep", forbidden)
    monkeypatch.setattr(sweep_cli, "_run_tau_star", forbidden)
    code, out, err = run_main(argv)
    assert code == 2
    assert message in err, err
    assert out == ""
