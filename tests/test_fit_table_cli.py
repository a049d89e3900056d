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
    reason = "compiled before the input was checked"
    forbid(monkeypatch, "peeljax.fit.table", "fit_stick_slip", "_solve", reason=reason)
    forbid(monkeypatch, "peeljax.fit.plots", "model_statistics", reason=reason)


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
        (["--data", "x.npz", "--out", "o.json", "--window", "1"], ["--window", "--data"]),
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
    """A 2-row table made by the model itself (φ with c1 = 420) fitted from the paper's c1 = 400."""
    from peeljax.fit.plots import model_statistics

    V = [1.1, 1.5]
    stats, _ = model_statistics(AdhesionLaw(c1=420.0), V, transient=0.2, window=0.3)
    lines = ["V,F_mean,F_slip,period"] + [
        ",".join(repr(float(x)) for x in (V[i], stats["F_mean"][i], stats["F_slip"][i], stats["period"][i]))
        for i in range(2)
    ]
    assert all(np.isfinite(stats[s]).all() for s in ("F_mean", "F_slip", "period"))
    table = tmp_path / "table.csv"
    table.write_text("\n".join(lines) + "\n")
    out, png = tmp_path / "fitted.json", tmp_path / "fit.png"
    code, stdout, err = run_cli(
        ["fit", "--table", str(table), "--free", "c1", "--transient", "0.2", "--window", "0.3",
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
