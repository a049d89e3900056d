"""The ``peeljax`` command line: outputs of a short run, and bad input rejected before compiling.

A compile costs several seconds, so the runs are few and short (0.2 s of 20 steps) and one
run's outputs serve several tests.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
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
    (["--t-final", "0"], "--t-final", "(0, inf)"),
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
    (["--rtol", "1e-6"], "--rtol", "cannot be combined with --dt"),  # error control with the uniform mesh (SHORT has --dt)
    (["--method", "diffrax", "--atol", "0"], "atol", "(0, inf)"),
    (["--save-dt", "0.1"], "--save-dt", "cannot be combined with --dt"),  # the library's rule (SHORT has --dt)
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


# (command line, what the last line of stderr must say): each names the closest option or command
MISSPELLED = [
    (["simulate", "--t-finl", "3"], "peeljax simulate: error: unrecognized option --t-finl (did you mean --t-final?)"),
    (["simulate", "--t-finl=3"], "unrecognized option --t-finl (did you mean --t-final?)"),
    (["sweep", "--chunkk", "2"], "peeljax sweep: error: unrecognized option --chunkk (did you mean --chunk?)"),
    (["simulate", "-V", "2"], "unrecognized option -V (did you mean --V?)"),
    (["fit", "--tabel", "t.csv"], "unrecognized option --tabel (did you mean --table?)"),
    (["simulte", "--V", "1"], "invalid choice: 'simulte'; did you mean 'simulate'?"),
    (["--verison"], "peeljax: error: unrecognized option --verison (did you mean --version?)"),
    (["--simulate"], "unrecognized option --simulate (did you mean the command simulate, without dashes?)"),
    (["simulate", "1.1"], "unexpected value '1.1': every value follows its option (e.g. --V 1.1)"),
    (["simulate", "--t-final", "3", "4"], "unexpected value '4'"),
]  # fmt: skip


@pytest.mark.parametrize(("argv", "said"), MISSPELLED, ids=[" ".join(argv) for argv, _ in MISSPELLED])
def test_a_misspelled_option_or_command_gets_the_closest_one(argv, said, no_compilation):
    """Was argparse's bare "unrecognized arguments: --t-finl 3" (and nothing for a misspelled
    top-level option but "the following arguments are required: COMMAND")."""
    code, out, err = run_cli(argv)
    assert code == 2 and out == ""
    assert said in err.strip().splitlines()[-1], err


def test_stats_line_shows_only_what_the_run_has():
    from peeljax.cli._common import stats_text

    error_control = {"accepted_steps": 158, "jumps": 18, "max_newton_iterations": 0, "newton_iterations": 0,
                     "rejected_steps": 94, "step_size": math.nan, "step_size_max": 0.020652057620860295,
                     "steps": 158, "steps_cut_at_folds": 0}  # fmt: skip (an explicit stepper's stats)
    assert stats_text(error_control, jumps_said=True) == (
        "accepted_steps 158, rejected_steps 94, step_size_max 0.02065, steps_cut_at_folds 0"
    )
    uniform = {"accepted_steps": 20, "max_newton_iterations": 3, "newton_iterations": 41, "step_size": 0.01, "steps": 20}
    assert stats_text(uniform) == "accepted_steps 20, max_newton_iterations 3, newton_iterations 41, step_size 0.01"


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


# ---------------------------------------------------------------------------- one vocabulary (issues 29, 30)
def test_V_takes_a_range_and_suggests_spaces(no_compilation):
    from peeljax.cli import sweep as sweep_cli

    args = build_parser().parse_args(["sweep", "--V", "0.2:8:40", "1.1", "--tau", "0.01", "--t-final", "0.3"])
    V = sweep_cli.validate_sweep(args)["V"]
    np.testing.assert_allclose(V, [*np.linspace(0.2, 8.0, 40), 1.1])
    for argv, words in (
        (["sweep", "--V", "1,2"], ["--V", "'1,2'", "--V 1 2"]),
        (["simulate", "--V", "1,2"], ["--V", "one value"]),
        (["simulate", "--V", "0.2:8:40"], ["--V", "peeljax sweep"]),
        (["sweep", "--V", "0.2:8"], ["--V", "START:STOP:COUNT"]),
        (["sweep", "--V", "1:2:1"], ["--V", "COUNT", "[2, 1000000]"]),
        (["sweep", "--V", "-1:2:3"], ["--V", "(0, inf)"]),
        (["sweep", "--tau", "1e-3,1e-1"], ["--tau", "--tau 1e-3 1e-1"]),
        (["fit", "--data", "x.npz", "--V", "1,2"], ["--V", "--V 1 2"]),
    ):
        code, out, err = run_cli(argv)
        assert code == 2 and out == "" and "Traceback" not in err, err
        last = err.strip().splitlines()[-1]
        assert all(word in last for word in words), last


@pytest.mark.parametrize(("value", "shown"), [("null", "got null"), ("true", "got true"), ('"abc"', 'got the string "abc"')])
def test_phi_says_what_it_got_in_json_terms(value, shown, tmp_path, no_compilation):
    path = tmp_path / "phi.json"
    path.write_text(f'{{"c1": {value}}}')
    code, out, err = run_cli(["simulate", *SHORT, "--phi", str(path)])
    message = assert_refused(code, err, "--phi", "'c1'", shown, stdout=out)
    assert "None" not in message and "True" not in message


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["simulate", "--max-jumps", "0"], ["--max-jumps"]),
        (["simulate", "--t-final", "0"], ["--t-final"]),
        (["simulate", "--max-steps", "0"], ["--max-steps"]),
        (["sweep", "--n-tau", "1"], ["--n-tau"]),
        (["tau-star", "--max-steps", "0"], ["--max-steps"]),
        (["fit", "--data", "x.npz", "--out", "x.json", "--learning-rate", "-1"], ["--learning-rate"]),
    ],
)
def test_refusals_name_options_not_python_parameters(argv, words, no_compilation):
    code, out, err = run_cli(argv)
    message = assert_refused(code, err, *words, stdout=out)
    assert not any(name in message for name in ("max_jumps", "t_final", "max_steps", "n_tau", "learning_rate"))


_PROCESS_OPTIONS = ("coordinator", "num_processes", "process_id")  # sweep's processes: peeljax/cli/_distributed.py


def test_help_states_every_default_and_the_shared_options():
    """Every option's help line states its default; --max-steps and --no-progress everywhere that runs."""
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    for name in ("simulate", "sweep", "tau-star", "fit"):
        actions = {a.option_strings[-1]: a for a in commands[name]._actions if a.option_strings}
        assert "--max-steps" in actions and "--no-progress" in actions, name
        for option, action in actions.items():
            if action.help in (None, argparse.SUPPRESS) or option in ("--help", "--version"):
                continue
            if action.nargs == 0 or action.dest in _PROCESS_OPTIONS:  # a flag: off unless given
                continue
            assert "default" in action.help, (name, option, action.help)
    y0 = next(a for a in commands["simulate"]._actions if "--y0" in a.option_strings)
    assert y0.metavar[3] == "v0" and "peeling velocity v0" in y0.help
    assert "t_final/2" in next(a for a in commands["simulate"]._actions if "--transient" in a.option_strings).help


def test_transient_and_window_mean_the_same_everywhere(no_compilation, capsys):
    """--transient T and --window W [s]: statistics over [T, T + W]; default the run's second half."""
    from peeljax.cli import sweep as sweep_cli
    from peeljax.cli import sweep_map as sweep_map_cli
    from peeljax.cli.fit_table import _table_window

    def window(*options):
        args = build_parser().parse_args(["sweep", "--V", "1.1", "--tau", "0.01", "--t-final", "2", *options])
        return sweep_cli.validate_sweep(args)["window"]

    assert window() == (0.5, 1.0)
    assert window("--transient", "0.5", "--window", "1") == pytest.approx((0.25, 0.75))
    assert window("--transient", "1.5") == pytest.approx((0.75, 1.0))
    assert window("--window", "0.25", "1") == (0.25, 1.0)  # the old form, W0 W1 fractions: a note names the new
    assert "--transient 0.5 --window 1.5" in capsys.readouterr().err
    simulate = validate_run(build_parser().parse_args(["simulate", "--tau", "0", "--t-final", "2"]))
    assert simulate.transient == 1.0
    args = build_parser().parse_args(["sweep", "--V", "1.1", "--stick-slip-map", "--t-final", "2"])
    assert sweep_map_cli.validate_map(args)["transient"] == 1.0

    def table(*options):
        return _table_window(build_parser().parse_args(["fit", "--table", "t.csv", *options]))

    assert table() == (0.5, 0.5) and table("--transient", "1") == (1.0, 1.0) and table("--window", "0.3") == (0.3, 0.3)
    assert table("--transient", "0.2", "--window", "0.3") == (0.2, 0.3)
    code, out, err = run_cli(["sweep", "--t-final", "2", "--transient", "1.5", "--window", "1"])
    assert_refused(code, err, "--window", "(0, 0.5]", stdout=out)


# ---------------------------------------------------------------------------- progress on stderr
def test_simulate_shows_progress_unless_no_progress(alpha_run):
    # the same compiled program as alpha_run: no new compilation
    code, _out, err = run_cli(["simulate", *SHORT])
    assert code == 0 and "simulating to t = 0.2 s: done in" in err
    code, _out, err = run_cli(["simulate", *SHORT, "--no-progress"])
    assert code == 0 and "done in" not in err and "still running" not in err
    assert "compiling first" in err  # what runs is always said


def test_elapsed_reports_while_a_compiled_run_goes_on(monkeypatch, capsys):
    import time

    from peeljax.cli import _common

    monkeypatch.setattr(_common, "HEARTBEAT_S", 0.02)
    with _common.Elapsed(True, "simulating to t = 30 s"):
        time.sleep(0.2)
    err = capsys.readouterr().err
    assert "simulating to t = 30 s: still running, 0 s elapsed" in err and "done in" in err
    with _common.Elapsed(False, "quiet"):
        time.sleep(0.1)
    assert capsys.readouterr().err == ""


class _Stop(Exception):
    """Raised by a stand-in for a fit once it has seen its arguments."""


def test_fits_show_iterations_and_loss_unless_no_progress(monkeypatch, tmp_path):
    import peeljax.fit as fit

    seen = {}

    def table_fit(*args, **kwargs):
        seen.update(kwargs)
        if kwargs.get("progress") is not None:
            kwargs["progress"](1, 2.5)
        raise _Stop

    def data_fit(*args, **kwargs):
        seen.update(kwargs)
        raise _Stop

    monkeypatch.setattr(fit, "fit_stick_slip", table_fit)
    monkeypatch.setattr(fit, "fit_adhesion", data_fit)
    table = tmp_path / "table.csv"
    table.write_text("V,F_mean\n1.1,5\n2,6\n3,7\n")
    for extra, shown in (([], True), (["--no-progress"], False)):
        seen.clear()
        err = io.StringIO()
        with pytest.raises(_Stop), contextlib.redirect_stderr(err):
            cli.main(["fit", "--table", str(table), "--free", "c1", *extra])
        assert ("progress" in seen) is shown
        assert ("iteration 1, loss 2.5" in err.getvalue()) is shown
    npz = tmp_path / "run.npz"
    np.savez(npz, t=np.linspace(0, 0.2, 21), v=np.linspace(0.1, 0.3, 21), V=1.1)
    for extra, shown in (([], True), (["--no-progress"], False)):
        with pytest.raises(_Stop):
            run_cli(["fit", "--data", str(npz), "--out", str(tmp_path / "f.json"), "--max-steps", "77", *extra])
        assert seen["progress"] is shown and seen["max_steps"] == 77  # the step budget reaches the fit


def test_trajectory_fit_prints_its_uncertainties(monkeypatch, tmp_path):
    import peeljax.fit as fit
    from peeljax.fit import FitResult
    from peeljax.fit.uncertainty import uncertainty_from_jacobian

    law = AdhesionLaw(c1=440.0)
    uncertainty = uncertainty_from_jacobian(np.array([[2.0], [1.0], [0.5]]), np.array([0.1, -0.1, 0.05]),
                                            [440.0], ["c1"], scaled=True)  # fmt: skip
    result = FitResult(
        adhesion=law, start=AdhesionLaw(), loss_history=np.array([1.0, 0.1]), initial_loss=1.0, final_loss=0.1,
        gradient_norm=1e-3, steps=1, stopped_early=False, v_range=(0.1, 2.0), free=("c1",), settings={},
        uncertainty=uncertainty,
    )  # fmt: skip
    monkeypatch.setattr(fit, "fit_adhesion", lambda *args, **kwargs: result)
    npz = tmp_path / "run.npz"
    np.savez(npz, t=np.linspace(0, 0.2, 21), v=np.linspace(0.1, 0.3, 21), V=1.1)
    argv = ["fit", "--data", str(npz), "--out", str(tmp_path / "f.json"), "--free", "c1", "--no-progress"]
    code, out, err = run_cli(argv)
    assert code == 0, err
    assert "+- std. error" in out and "c1" in out and f"{uncertainty.standard_errors[0]:.3g}" in out
    assert out.isascii()
    code, out, err = run_cli([*argv, "--json"])
    assert json.loads(out)["uncertainty"]["names"] == ["c1"]
