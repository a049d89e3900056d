"""The ``peeljax`` command line: outputs of a short run, and bad input rejected before compiling.

A compile costs several seconds, so the runs are few and short (0.2 s of 20 steps) and one
run's outputs serve several tests.
"""

from __future__ import annotations

import importlib
import json
import math
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli, run_cli_writing

from peeljax import AdhesionLaw, PeelingModel, Solution, StopReason, cli
from peeljax.cli import build_parser, summarize, validate_run, write_npz

SHORT = ["--t-final", "0.2", "--dt", "0.01"]
REQUIRED_JSON_KEYS = {
    "status", "reason", "t_stop", "steps", "v_final", "v_min", "v_max", "wall_time_s",
    "V", "tau", "dt", "method", "stats",
}  # fmt: skip


@pytest.fixture(scope="module")
def alpha_run(tmp_path_factory):
    """One short α-method run writing every output."""
    return run_cli_writing(tmp_path_factory.mktemp("alpha_run"), ["simulate", *SHORT])


# ---------------------------------------------------------------------------- a good run
def test_exit_code_zero(alpha_run):
    assert alpha_run["code"] == 0, alpha_run["stderr"]


def test_npz_loads_without_pickle(alpha_run):
    with np.load(alpha_run["npz"], allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    series = ("t", "alpha", "omega", "u", "v", "F")
    for key in series:
        assert arrays[key].ndim == 1 and arrays[key].dtype == np.float64, key
    assert len({arrays[key].shape for key in (*series, "valid")}) == 1
    assert arrays["t"].shape == (21,)
    assert arrays["t"][0] == 0.0
    assert str(arrays["status"]) in {"completed", "stopped"}
    assert arrays["status"].ndim == 0 and arrays["status"].dtype.kind == "U"
    assert str(arrays["geometry"]) == "paper" and str(arrays["method"]) == "alpha"
    for key in ("V", "tau", "dt", "t_final", "rho", "t_stop"):
        assert arrays[key].ndim == 0, key
    assert float(arrays["V"]) == 1.1 and float(arrays["tau"]) == 0.01 and float(arrays["rho"]) == 0.0
    assert float(arrays["dt"]) == pytest.approx(0.01) and float(arrays["t_final"]) == 0.2
    assert arrays["v"][0] == pytest.approx(1.1e-10)  # the initial state is included


def test_npz_tension_and_phi(alpha_run):
    with np.load(alpha_run["npz"], allow_pickle=False) as data:
        valid, u, F = data["valid"], data["u"], data["F"]
        phi = json.loads(str(data["phi_json"]))
    model = PeelingModel()
    np.testing.assert_allclose(F[valid], float(model.k / model.l) * u[valid])
    assert np.all(np.isnan(F[~valid]))
    assert phi == AdhesionLaw().coefficients()


def test_json_output(alpha_run):
    lines = alpha_run["stdout"].strip().splitlines()
    assert len(lines) == 1, "--json must print exactly one JSON object and nothing else"
    record = json.loads(lines[0])
    assert REQUIRED_JSON_KEYS <= record.keys()
    assert record["status"] in {"completed", "stopped"}
    assert record["method"] == "alpha" and record["V"] == 1.1 and record["tau"] == 0.01
    assert record["dt"] == pytest.approx(0.01)
    assert record["wall_time_s"] > 0
    assert record["v_min"] <= record["v_final"] <= record["v_max"]
    assert "newton_iterations" in record["stats"]


def test_png_written(alpha_run):
    assert alpha_run["png"].read_bytes()[:8] == PNG_MAGIC


def test_human_summary(alpha_run):
    # Same mesh and model as alpha_run: JAX's cache serves it without recompiling.
    code, out, _err = run_cli(["simulate", *SHORT])
    assert code == 0
    assert "V = 1.1 m/s" in out and ("completed" in out or "stopped" in out)
    assert not out.lstrip().startswith("{")


def test_diffrax_method(tmp_path):
    npz = tmp_path / "ref.npz"
    code, out, err = run_cli(["simulate", "--method", "diffrax", *SHORT, "--rtol", "1e-6", "--out", str(npz), "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["method"] == "diffrax" and record["status"] in {"completed", "stopped"}
    assert record["rtol"] == 1e-6 and record["atol"] == 1e-10
    with np.load(npz, allow_pickle=False) as data:
        assert str(data["method"]) == "diffrax"
        assert data["t"].shape == data["v"].shape == (21,)
        assert float(data["dt"]) == pytest.approx(0.01)
        assert math.isnan(float(data["rho"]))


# Error control (no --dt): bad tolerances exit 2 naming the option.
BAD_TOLERANCES = [
    (["--rtol", "0"], "rtol", "(0, 1)"),
    (["--rtol", "1"], "rtol", "(0, 1)"),
    (["--rtol", "nan"], "rtol", "(0, 1)"),
    (["--atol=-1e-9"], "atol", "(0, inf)"),
    (["--atol", "nan"], "atol", "(0, inf)"),
    (["--save-dt", "1"], "save-dt", "(0, 0.2]"),
]


@pytest.mark.parametrize(("options", "name", "allowed"), BAD_TOLERANCES, ids=[" ".join(o) for o, *_ in BAD_TOLERANCES])
def test_bad_tolerances_exit_2_before_compiling(options, name, allowed, no_compilation):
    code, _out, err = run_cli(["simulate", "--t-final", "0.2", *options])
    assert_refused(code, err, name, allowed)


def test_error_control_is_the_default(tmp_path):
    npz = tmp_path / "run.npz"
    code, out, err = run_cli(["simulate", "--t-final", "0.2", "--rtol", "1e-5", "--out", str(npz), "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["rtol"] == 1e-5 and record["atol"] == 1e-9 and record["dt"] is None
    assert record["steps"] == record["accepted_steps"] > 0 and record["rejected_steps"] >= 0
    with np.load(npz, allow_pickle=False) as data:
        # the accepted steps, only the valid rows
        assert data["t"].shape == (record["accepted_steps"] + 1,) and bool(data["valid"].all())
        assert data["t"][0] == 0.0 and data["t"][-1] == pytest.approx(0.2) and np.all(np.diff(data["t"]) > 0)
        assert math.isnan(float(data["dt"])) and float(data["rtol"]) == 1e-5


def test_save_dt_gives_the_output_grid(tmp_path):
    npz = tmp_path / "run.npz"
    code, out, err = run_cli(["simulate", "--t-final", "0.25", "--save-dt", "0.1", "--out", str(npz), "--json"])
    assert code == 0, err
    with np.load(npz, allow_pickle=False) as data:
        np.testing.assert_allclose(data["t"], [0.0, 0.1, 0.2, 0.25])
    assert "accepted_steps" in json.loads(out) and "rejected_steps" in json.loads(out)


def test_diffrax_output_on_save_dt(tmp_path):
    npz = tmp_path / "ref.npz"
    code, _out, err = run_cli(
        ["simulate", "--method", "diffrax", "--t-final", "0.25", "--save-dt", "0.1", "--out", str(npz)]
    )
    assert code == 0, err
    with np.load(npz, allow_pickle=False) as data:
        np.testing.assert_allclose(data["t"], [0.0, 0.1, 0.2, 0.25])
        assert str(data["method"]) == "diffrax"


def test_uniform_mesh_reports_accepted_and_rejected_steps(alpha_run):
    record = json.loads(alpha_run["stdout"])
    assert record["accepted_steps"] == record["steps"] == 20 and record["rejected_steps"] >= 0


@pytest.mark.slow
def test_module_entry_point_prints_one_json_object():
    result = subprocess.run(
        [sys.executable, "-m", "peeljax.cli", "simulate", "--json", *SHORT],
        check=False,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    record = json.loads(result.stdout)  # fails on anything besides one JSON document
    assert isinstance(record, dict) and REQUIRED_JSON_KEYS <= record.keys()


# ---------------------------------------------------------------------------- bad input
@pytest.fixture
def no_compilation(no_compilation, monkeypatch):
    """conftest's ``no_compilation``, and the command line's own calls of the integrators fail the test too."""
    reason = "bad input reached the integrator: it must be rejected before compilation"
    forbid(monkeypatch, "peeljax.cli.simulate", "simulate", "simulate_reference", reason=reason)


@pytest.fixture
def malformed_phi(tmp_path):
    path = tmp_path / "phi.json"
    path.write_text('{"c1": 400.0, "p1": ')
    return str(path)


# (options, the parameter the message must name, the allowed range or choices it must state)
BAD_INPUT = [
    (["--tau", "0"], "tau", "(0, 1e+06]"),
    (["--tau=-1"], "tau", "(0, 1e+06]"),
    (["--V", "0"], "V", "(0, inf)"),
    (["--dt", "0"], "dt", "(0, inf)"),
    (["--t-final", "0"], "t_final", "(0, inf)"),
    (["--dt", "1", "--t-final", "0.5"], "dt", "(0, 0.5]"),
    (["--rho", "1"], "rho", "[0, 1)"),
    (["--rho=-0.1"], "rho", "[0, 1)"),
    (["--V", "nan"], "V", "(0, inf)"),
    (["--tau", "inf"], "tau", "(0, 1e+06]"),
    (["--tau", "1e300"], "tau", "(0, 1e+06]"),
    (["--geometry", "foo"], "geometry", "paper, full"),
    (["--method", "foo"], "method", "alpha, diffrax"),
    (["--y0", "0", "0", "0.001", "0"], "y0", "(0, inf)"),
    (["--phi", "MALFORMED"], "--phi", "not valid JSON"),
    (["--rtol", "1e-6"], "--rtol", "uniform mesh"),  # error control with the uniform mesh (SHORT has --dt)
    (["--method", "diffrax", "--atol", "0"], "atol", "(0, inf)"),
    (["--save-dt", "0.1"], "--save-dt", "uniform mesh"),
    (["--save-dt", "0"], "save-dt", "(0, 0.2]"),
    (["--out", "/nonexistent-folder/run.npz"], "--out", "does not exist"),
]


@pytest.mark.parametrize(("options", "name", "allowed"), BAD_INPUT, ids=[" ".join(o) for o, *_ in BAD_INPUT])
def test_bad_input_exits_2_before_compiling(options, name, allowed, no_compilation, malformed_phi):
    options = [malformed_phi if option == "MALFORMED" else option for option in options]
    code, out, err = run_cli(["simulate", *SHORT, *options])
    assert_refused(code, err, name, allowed, stdout=out)


@pytest.mark.parametrize("argv", [[], ["simulate", "--nope"], ["simulate", "--tau", "abc"], ["frobnicate"]])
def test_argparse_errors_exit_2(argv, no_compilation):
    code, _out, err = run_cli(argv)
    assert code == 2
    assert "error" in err


def test_help_exits_0():
    code, out, _err = run_cli(["simulate", "--help"])
    assert code == 0
    assert "--t-final" in out


def test_valid_phi_file_is_used(tmp_path):
    path = tmp_path / "phi.json"
    AdhesionLaw(c1=420.0).to_json(path)
    config = validate_run(build_parser().parse_args(["simulate", "--phi", str(path), "--geometry", "full"]))
    assert config.model.adhesion.coefficients()["c1"] == 420.0
    assert config.model.geometry == "full" and config.rho == 0.0 and config.rtol == 1e-6 and config.adaptive


# ---------------------------------------------------------------------------- a stopped run's outputs
def _stopped_solution(all_invalid: bool = False) -> Solution:
    """A hand-made stopped trajectory: the writers need no integration to be tested."""
    ts = jnp.linspace(0.0, 1.0, 11)
    valid = jnp.zeros(11, bool) if all_invalid else jnp.arange(11) <= 5
    ys = jnp.stack([0.01 * ts, ts, 0.3 + 0.01 * ts, 1e-10 + ts], axis=1)
    return Solution(
        ts=ts,
        ys=jnp.where(valid[:, None], ys, jnp.nan),
        valid=valid,
        status=jnp.asarray(int(StopReason.IMPASSE)),
        t_stop=jnp.asarray(0.0 if all_invalid else 0.5),
        stats={"steps": jnp.asarray(0 if all_invalid else 5), "step_size": jnp.asarray(0.1)},
        diagnostics=None,
    )


def test_stopped_run_outputs(tmp_path):
    from peeljax.plots import plot_run

    solution = _stopped_solution()
    config = validate_run(build_parser().parse_args(["simulate", "--t-final", "1", "--dt", "0.1"]))
    write_npz(str(tmp_path / "stopped.npz"), solution, config)
    with np.load(tmp_path / "stopped.npz", allow_pickle=False) as data:
        assert str(data["status"]) == "stopped" and "impasse" in str(data["reason"])
        assert float(data["t_stop"]) == 0.5
        assert np.all(np.isnan(data["v"][6:])) and np.all(np.isnan(data["F"][6:]))
        assert np.all(np.isfinite(data["F"][:6]))
    figure = plot_run(solution, config.model, V=1.1, path=tmp_path / "stopped.png")
    assert (tmp_path / "stopped.png").read_bytes()[:8] == PNG_MAGIC
    assert any("stopped at t = 0.5" in text.get_text() for text in figure.axes[0].texts)


def test_summary_of_a_run_rejected_at_the_start():
    record = summarize(_stopped_solution(all_invalid=True))
    assert record["status"] == "stopped" and record["steps"] == 0 and math.isnan(record["v_final"])
    json.dumps(cli.json_safe(record), allow_nan=False)  # strict JSON: NaN became null


# ---------------------------------------------------------------------------- outputs that cannot be written
@pytest.fixture
def nothing_runs(monkeypatch):
    """Any simulation, sweep or figure run fails the test: the refusal must come first."""
    reason = "an unwritable output reached the computation"
    forbid(monkeypatch, "peeljax.cli.simulate", "run", reason=reason)
    forbid(monkeypatch, "peeljax.cli.sweep", "_run_sweep", reason=reason)
    forbid(monkeypatch, "peeljax.figures", "write_figures", reason=reason)


UNWRITABLE = [
    (["simulate", "--t-final", "0.1", "--out", "/proc/x.npz"], "--out", "cannot write"),
    (["simulate", "--t-final", "0.1", "--plot", "/proc/x.png"], "--plot", "cannot write"),
    (["sweep", "--V", "1.1", "--tau", "0.01", "0.1", "--n-tau", "2", "--dt", "0.01", "--t-final", "0.1",
      "--out", "/proc/s.npz"], "--out", "cannot write"),
    (["figures", "--out", "/proc/nope"], "--out", "cannot write"),
    (["simulate", "--t-final", "0.1", "--out", "AFILE/sub/x.npz"], "--out", "is a file, not a folder"),
    (["figures", "--out", "AFILE/sub"], "--out", "is a file, not a folder"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "option", "words"), UNWRITABLE, ids=[" ".join(a[:1] + a[-2:]) for a, *_ in UNWRITABLE]
)
def test_unwritable_output_exits_2_before_computing(argv, option, words, nothing_runs, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    argv = [arg.replace("AFILE", str(afile)) for arg in argv]
    code, _out, err = run_cli(argv)
    assert_refused(code, err, option, words)


def test_a_write_error_after_the_run_is_reported_not_raised(monkeypatch, tmp_path):
    cli_simulate = importlib.import_module("peeljax.cli.simulate")

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(cli_simulate, "write_npz", disk_full)
    code, out, err = run_cli(["simulate", *SHORT, "--out", str(tmp_path / "run.npz"), "--json"])
    assert code == 1
    record = json.loads(out)  # the run's result still comes out
    assert record["status"] in {"completed", "stopped"} and record["out"] is None
    assert "could not write --out" in err and "No space left on device" in err


@pytest.mark.parametrize(
    ("coefficient", "value", "allowed"), [("c1", -5.0, "(0, inf)"), ("p9", 0.0, "(0, inf)"), ("c7", -1.0, "[0, inf)")]
)
def test_phi_outside_the_family_domain_exits_2(coefficient, value, allowed, no_compilation, tmp_path):
    path = tmp_path / "phi.json"
    path.write_text(json.dumps({coefficient: value}))
    code, _out, err = run_cli(["simulate", *SHORT, "--phi", str(path)])
    assert_refused(code, err, repr(coefficient), allowed)


def test_a_v_without_stick_slip_is_said(tmp_path):
    code, out, err = run_cli(["simulate", "--V", "20", "--t-final", "0.05", "--json"])
    assert code == 0, err
    assert "no maximum" in json.loads(out)["note"]
    code, out, err = run_cli(["simulate", "--V", "1.1", "--t-final", "0.05", "--json"])
    assert code == 0 and "note" not in json.loads(out)
