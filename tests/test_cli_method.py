"""``--method`` (the stepper of the one error-controlled loop) and ``--max-steps`` on the command line.

``peeljax simulate`` and ``peeljax sweep`` pass ``--method NAME`` as ``solver=NAME`` ("default":
None, the library's choice; "alpha": an ``AlphaMethod`` carrying ``--rho``); every stepper runs
error control, ``--tau 0`` and ``--fold`` included; ``--dt`` and ``--rho`` are the α-method's.
``--max-steps`` is error control's budget of step attempts (default: the library's); a run that
uses it up ends with a remedy line on stderr. Refusals come before anything compiles; the few
runs are short.
"""

from __future__ import annotations

import inspect
import json

import pytest
from conftest import assert_refused, forbid, run_cli

from peeljax import AlphaMethod, sweep
from peeljax.cli import build_parser, validate_run
from peeljax.cli import sweep as sweep_cli
from peeljax.cli import sweep_map as sweep_map_cli
from peeljax.cli import tau_star as tau_star_cli

REMEDY = "raise --max-steps (now {}) or loosen --rtol"


def _refused(argv: list[str], *words: str) -> str:
    code, out, err = run_cli(argv)
    assert "Traceback" not in err, err
    return assert_refused(code, err, *words, stdout=out)


@pytest.fixture
def nothing_runs(no_compilation, monkeypatch):
    """conftest's ``no_compilation``, and the command line's own calls of the integrators fail the test too."""
    reason = "bad input reached the integrator: it must be rejected before compilation"
    forbid(monkeypatch, "peeljax.cli.simulate", "simulate", "simulate_reference", reason=reason)
    forbid(monkeypatch, sweep_cli, "_run_sweep", reason=reason)
    forbid(monkeypatch, sweep_map_cli, "_run_map", reason=reason)
    forbid(monkeypatch, tau_star_cli, "_run_tau_star", reason=reason)


# ---------------------------------------------------------------------------- refusals, before compiling
SIMULATE_REFUSALS = [
    (["--method", "foo"], ["--method", "default", "tsit5", "kvaerno5", "diffrax"]),
    (["--method", "tsit5", "--dt", "0.01"], ["--dt", "--method tsit5", "--method alpha"]),
    (["--method", "dopri5", "--rho", "0.5"], ["--rho", "--method dopri5", "default or alpha"]),
    (["--method", "kvaerno5", "--rho", "2"], ["--rho", "--method kvaerno5"]),
    (["--max-steps", "0"], ["--max-steps", "[1, 2147483647]"]),
    (["--max-steps=-3"], ["--max-steps", "[1, 2147483647]"]),
    (["--max-steps", "10", "--dt", "0.01"], ["--max-steps", "[1, 2147483647]", "--dt"]),
    (["--method", "alpha", "--max-steps", "10", "--dt", "0.01"], ["--max-steps", "[1, 2147483647]", "--dt"]),
    (["--max-steps", "3000000000"], ["--max-steps", "[1, 2147483647]"]),
    (["--max-steps", "2000000000"], ["--max-steps", "memory", "--save-dt"]),  # the accepted steps' rows
    (["--tau", "0", "--method", "diffrax"], ["--tau 0", "--method diffrax", "kvaerno5"]),
    (["--fold", "jump", "--method", "diffrax"], ["--fold jump", "--method diffrax", "--fold stop"]),
    (["--tau", "0", "--dt", "0.01"], ["--tau 0", "--dt"]),
]


@pytest.mark.parametrize(("options", "words"), SIMULATE_REFUSALS, ids=[" ".join(o) for o, _ in SIMULATE_REFUSALS])
def test_simulate_refusals_name_the_option(options, words, nothing_runs):
    message = _refused(["simulate", "--t-final", "0.3", *options], *words)
    assert "max_steps" not in message  # the option, not the Python parameter


SWEEP_REFUSALS = [
    (["--method", "foo"], ["--method", "default", "tsit5"]),
    (["--method", "diffrax"], ["--method", "kvaerno5"]),  # the reference is simulate's, not a sweep's stepper
    (["--method", "tsit5", "--dt", "0.01"], ["--dt", "--method tsit5"]),
    (["--method", "kvaerno3", "--rho", "0.2"], ["--rho", "--method kvaerno3"]),
    (["--max-steps", "0"], ["--max-steps", "[1, 2147483647]"]),
    (["--max-steps", "50", "--dt", "0.01"], ["--max-steps", "[1, 2147483647]", "--dt"]),
    (["--max-steps", "3000000000"], ["--max-steps", "2147483647"]),
    (["--stick-slip-map", "--method", "dopri5", "--rho", "0.5"], ["--rho", "--method dopri5"]),
]


@pytest.mark.parametrize(("options", "words"), SWEEP_REFUSALS, ids=[" ".join(o) for o, _ in SWEEP_REFUSALS])
def test_sweep_refusals_name_the_option(options, words, nothing_runs):
    message = _refused(["sweep", "--V", "1.1", "--t-final", "0.3", *options], *words)
    assert "max_steps" not in message


def test_fit_max_steps_refusals(tmp_path, nothing_runs):
    table = tmp_path / "table.csv"
    table.write_text("V,F_mean\n1.1,5\n2,6\n3,7\n4,8\n")
    _refused(["fit", "--table", str(table), "--free", "c1", "--max-steps", "0"], "--max-steps", "[1, 2147483647]")
    data = ["fit", "--data", str(tmp_path / "run.npz"), "--out", str(tmp_path / "fit.json")]
    _refused([*data, "--max-steps", "0"], "--max-steps", "[1, 2147483647]")  # --data takes it too (error control)


# ---------------------------------------------------------------------------- options reach the API
def _config(*options: str):
    return validate_run(build_parser().parse_args(["simulate", "--t-final", "0.3", *options]))


def test_method_becomes_the_solver(nothing_runs):
    default = _config()
    assert default.method == "default" and default.solver is None and default.adaptive
    assert default.rho == 0.0 and default.max_steps is None  # None: the library's budget
    alpha = _config("--method", "alpha", "--rho", "0.5")
    assert isinstance(alpha.solver, AlphaMethod) and float(alpha.solver.rho) == 0.5
    for name in ("tsit5", "dopri5", "dopri8", "kvaerno3", "kvaerno4", "kvaerno5"):
        config = _config("--method", name, "--tau", "0", "--rtol", "1e-5", "--atol", "1e-8")
        assert config.solver == name and config.adaptive and config.dae and config.fold == "jump"
        assert config.rho is None and config.rtol == 1e-5 and config.atol == 1e-8
    for fold in ("stop", "follow"):
        assert _config("--method", "tsit5", "--fold", fold).fold == fold
    assert _config("--method", "tsit5", "--max-steps", "50").max_steps == 50
    uniform = _config("--dt", "0.01")
    assert uniform.uniform and not uniform.adaptive and uniform.solver is None
    reference = _config("--method", "diffrax", "--max-steps", "1000")  # diffrax's own budget
    assert reference.method == "diffrax" and not reference.adaptive and reference.max_steps == 1000


def test_sweep_method_and_max_steps_reach_the_api(nothing_runs):
    def kwargs(*options: str) -> dict:
        args = build_parser().parse_args(["sweep", "--V", "1.1", "--tau", "0", "--t-final", "0.3", *options])
        out = sweep_cli.validate_sweep(args)
        assert set(out) <= set(inspect.signature(sweep).parameters)
        return out

    default = kwargs()
    assert "solver" not in default and "max_steps" not in default  # the library's stepper and budget
    chosen = kwargs("--method", "tsit5", "--max-steps", "5000")
    assert chosen["solver"] == "tsit5" and chosen["max_steps"] == 5000
    assert isinstance(kwargs("--method", "alpha", "--rho", "0.5")["solver"], AlphaMethod)
    args = build_parser().parse_args(["sweep", "--V", "1.1", "--stick-slip-map", "--method", "kvaerno5"])
    assert sweep_map_cli.validate_map(args)["solver"] == "kvaerno5"


# ---------------------------------------------------------------------------- runs
def test_tsit5_runs_the_dae_through_its_jumps():
    """Needs the one error-controlled loop with any stepper (``solver="tsit5"`` at τ = 0)."""
    code, out, err = run_cli(["simulate", "--method", "tsit5", "--tau", "0", "--t-final", "0.3", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["status"] == "completed" and record["t_stop"] == pytest.approx(0.3)
    assert record["jumps"] > 0 and record["fold"] == "jump"
    assert record["method_option"] == "tsit5" and "alpha" not in record["method"]  # the stepper that ran
    assert record["rho"] is None and record["max_steps"] is None


def test_max_steps_stop_prints_the_remedy():
    code, out, err = run_cli(["simulate", "--tau", "0", "--t-final", "0.3", "--max-steps", "50", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["status"] == "stopped" and record["reason"] == "max_steps step attempts were used up before t_final"
    assert record["t_stop"] < 0.3 and record["max_steps"] == 50
    assert REMEDY.format(50) in err
    # the plain summary (the same compiled program): the remedy on the stop line, and no cycle count
    code, out, err = run_cli(["simulate", "--tau", "0", "--t-final", "0.3", "--max-steps", "50", "--transient", "0.2"])
    assert code == 0, err
    assert "step budget (50 step attempts, --max-steps) was used up before t_final: raise --max-steps" in out
    assert "before its transient ended (--transient 0.2 s): no cycle statistics" in out
    assert "none counted" not in out and "max_steps" not in out
    stats = next(line for line in out.splitlines() if line.startswith("stats: "))
    assert "nan" not in stats and "step_size_min" in stats, stats  # error control has no one step_size
    assert "newton" not in stats, stats  # the default stepper at tau 0 is explicit: no Newton iteration


def test_sweep_max_steps_stop_prints_the_remedy():
    argv = ["sweep", "--V", "1.1", "--tau", "0", "--t-final", "0.3", "--max-steps", "50", "--no-progress", "--json"]
    code, out, err = run_cli(argv)
    assert code == 0, err
    record = json.loads(out)
    assert record["trajectories"]["completed"] == [False] and record["max_steps"] == 50
    assert "1 of 1 trajectories stopped at their step budget" in err and REMEDY.format(50) in err
