"""``peeljax fit --table``: a stick-slip table fitted end to end (uncertainty, stop reason, plot),
and bad input refused (exit 2, the option named) before anything is compiled."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli

from peeljax import AdhesionLaw


@pytest.fixture
def table_csv(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text("V,F_mean,period\n1.1,244,0.022\n1.5,251,0.015\n")
    return path


@pytest.fixture
def no_fit(monkeypatch):
    """Fail the test if the table fit (or its compiled programs) is reached."""
    import peeljax.cli.fit  # noqa: F401 - imported first: it reads fit_stick_slip's defaults

    reason = "compiled before the input was checked"
    forbid(monkeypatch, "peeljax.fit.table", "fit_stick_slip", "_solve", reason=reason)
    forbid(monkeypatch, "peeljax.plots.fit", "model_statistics", reason=reason)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--table", "MISSING"], ["--table", "does not exist"]),
        (["--table", "TABLE", "--data", "x.npz"], ["--table", "--data"]),
        (["--table", "TABLE", "--starts", "0"], ["--starts", ">= 1"]),
        (["--table", "TABLE", "--window", "-1"], ["--window", "> 0"]),
        (["--table", "TABLE", "--transient", "-0.5"], ["--transient"]),
        (["--table", "TABLE", "--max-iterations", "0"], ["--max-iterations"]),
        (["--table", "TABLE", "--tau", "-1"], ["--tau"]),
        (["--table", "TABLE", "--free", "c99"], ["--free", "c99"]),
        (["--table", "TABLE", "--statistics", "F_slip"], ["--statistics", "F_slip"]),
        (["--table", "TABLE", "--V", "1.1"], ["--V", "--table"]),
        (["--table", "TABLE", "--plot", "fit.xyz"], ["--plot", "xyz"]),
        (["--data", "x.npz", "--out", "o.json", "--window", "1"], ["--data", "x.npz", "does not exist"]),
        ([], ["--data", "--table"]),
    ],
)
def test_bad_table_input_refused(tmp_path, table_csv, no_fit, options, words):
    argv = [{"MISSING": str(tmp_path / "missing.csv"), "TABLE": str(table_csv)}.get(o, o) for o in options]
    code, out, err = run_cli(["fit", *argv])
    assert_refused(code, err, *words, stdout=out)


def test_bad_table_file_names_the_line(tmp_path, no_fit):
    bad = tmp_path / "bad.csv"
    bad.write_text("V,F_mean\n1.1,244\n1.5,abc\n")
    code, out, err = run_cli(["fit", "--table", str(bad)])
    assert_refused(code, err, "--table", "line 3", stdout=out)


@pytest.mark.slow
def test_fit_table_end_to_end(tmp_path):
    """A 2-row table made by the model itself (φ with c1 = 420, window statistics of runs from rest)
    fitted from the paper's c1 = 400 with ``--method window`` (the command line's plumbing: the
    orbit method's fits are tested in tests/test_fit_attractors.py)."""
    from peeljax.fit.synthetic import model_statistics

    V = [1.1, 1.5]
    stats, _ = model_statistics(AdhesionLaw(c1=420.0), V, method="window", transient=0.2, window=0.3)
    lines = ["V,F_mean,F_slip,period"] + [
        ",".join(repr(float(x)) for x in (V[i], stats["F_mean"][i], stats["F_slip"][i], stats["period"][i]))
        for i in range(2)
    ]
    assert all(np.isfinite(stats[s]).all() for s in ("F_mean", "F_slip", "period"))
    table = tmp_path / "table.csv"
    table.write_text("\n".join(lines) + "\n")
    out, png = tmp_path / "fitted.json", tmp_path / "fit.png"
    code, stdout, err = run_cli(
        ["fit", "--table", str(table), "--method", "window", "--free", "c1", "--transient", "0.2", "--window", "0.3",
         "--max-iterations", "3", "--out", str(out), "--plot", str(png), "--json"]
    )  # fmt: skip
    assert code == 0, err
    assert "Levenberg-Marquardt: iteration 1, loss" in err  # progress on stderr (no --no-progress)
    record = json.loads(stdout)
    assert record["stop_reason"]
    assert record["uncertainty"]["names"] == ["c1"]
    assert len(record["uncertainty"]["standard_errors"]) == 1
    assert len(record["residuals"]) == 6
    assert record["final_loss"] <= record["initial_loss"]
    assert record["c1"] == pytest.approx(420.0, rel=0.02)
    saved = json.loads(out.read_text())
    assert saved["uncertainty"]["names"] == ["c1"] and saved["settings"]["table"] == str(table)
    assert AdhesionLaw.from_json(out).c1 == pytest.approx(record["c1"])
    assert png.read_bytes().startswith(PNG_MAGIC)


RECORD = "docs/examples/peel_V=1.1.csv"  # t, F only: what a load cell gives (the paper's φ, V = 1.1)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--dt", "0.01"], ["--dt", "force records"]),
        (["--learning-rate", "0.1"], ["--learning-rate", "force records"]),
        (["--transient", "2"], ["--transient", "[0, 1)"]),
        (["--tau", "-1"], ["--tau"]),
        (["--statistics", "F_max"], ["--statistics", "F_max"]),
    ],
)
def test_bad_force_record_input_refused(no_fit, options, words):
    """`fit --data` with t and F only goes through the records' statistics; its options are
    checked before anything compiles."""
    code, out, err = run_cli(["fit", "--data", RECORD, "--out", "o.json", *options])
    assert_refused(code, err, *words, stdout=out)


def test_table_options_are_refused_with_runs_that_have_v(tmp_path, no_fit):
    record = tmp_path / "run_V=1.1.csv"
    record.write_text("t,F,v\n0,130,1e-9\n0.1,140,1e-8\n0.2,150,1e-7\n")
    code, out, err = run_cli(["fit", "--data", str(record), "--out", "o.json", "--window", "1"])
    assert_refused(code, err, "--window", "point-by-point", stdout=out)


@pytest.mark.slow
def test_a_force_record_fits_from_the_command_line(tmp_path):
    """The docs' own force record (t, F at 2 kHz, made with the paper's φ: c1 = 400), fitted from
    c1 = 440 through its statistics at τ = 0 (issue 28: it ended in a traceback before)."""
    start = tmp_path / "start.json"
    AdhesionLaw(c1=440.0).to_json(start)
    out = tmp_path / "fitted.json"
    code, stdout, err = run_cli(
        ["fit", "--data", RECORD, "--phi", str(start), "--free", "c1", "--max-iterations", "4",
         "--out", str(out), "--json"]
    )  # fmt: skip
    assert code == 0, err
    assert "fitted by statistics" in err
    record = json.loads(stdout)
    assert record["uncertainty"]["names"] == ["c1"]
    # the record's window is still in the transient from rest: fitted by runs from rest over it
    assert "not settled" in record["settings"]["records"][0]["why"]
    lo, hi = record["intervals_95"]["c1"][0]
    assert lo <= 400.0 <= hi and record["c1"] == pytest.approx(400.0, rel=0.02)
    assert json.loads(out.read_text())["settings"]["data"] == [RECORD]
