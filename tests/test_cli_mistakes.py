"""Realistic mistakes of a new user, each refused in one line that names the option and what
it takes, before anything compiles (found by running every command's --help and a few wrong
command lines per command).

Before: ``fit --table t.csv --steps 10`` (or ``--optimizer``, ``--patience``) ran the whole
table fit with the option silently ignored; ``--out sweep.csv`` wrote a numpy file under a CSV
name; ``--max-steps 1e5`` got "invalid int value"; ``--method Tsit5`` (diffrax's spelling)
got no hint; ``tau-star --save-dt`` was "unrecognized arguments"; ``peeljax`` alone named no
command; a folder given to --table or
--data "does not exist"; ``--table runs.npz`` was told to "give .npz files the suffix .npz".
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import forbid, run_cli

TABLE = "V,F_mean,period\n1.1,330,0.1\n2,340,0.05\n4,350,0.02\n"
FORCE_RECORD = "t,F\n0,330\n0.1,340\n0.2,335\n"

# (command line ({table}, {record}, {tmp}: files in the test's folder), what stderr's last line says)
MISTAKES = [
    ([], "peeljax: error: give a command: simulate, sweep, tau-star"),
    (["fit", "--table", "{table}", "--steps", "10"],
     "peeljax: error: --steps does not apply to --table (its counterpart there is --max-iterations)"),
    (["fit", "--table", "{table}", "--optimizer", "lbfgs"], "peeljax: error: --optimizer does not apply to --table"),
    (["fit", "--table", "{table}", "--patience", "5"], "peeljax: error: --patience does not apply to --table"),
    (["fit", "--data", "{record}", "--V", "1.1", "--out", "{tmp}/f.json", "--steps", "10"],
     "peeljax: error: --steps does not apply to force records (t, F): fitted by their statistics or point by point (its counterpart there is --max-iterations)"),
    (["simulate", "--out", "{tmp}/run.txt"],
     "peeljax: error: --out '{tmp}/run.txt': peeljax simulate writes FILE.npz (numpy) or FILE.csv (text), not a .txt file"),
    (["sweep", "--out", "{tmp}/sweep.csv"],
     "peeljax sweep writes FILE.npz (numpy) or FILE.nc (netCDF), not a .csv file"),
    (["fit", "--table", "{table}", "--out", "{tmp}/fitted.npz"], "peeljax fit writes FILE.json (JSON), not a .npz file"),
    (["simulate", "--max-steps", "1e5"], "error: argument --max-steps: '1e5' is not an integer: write 100000"),
    (["sweep", "--chunk", "2.5"], "error: argument --chunk: '2.5' is not an integer"),
    (["simulate", "--t-final", "3s"], "error: argument --t-final: '3s' is not a number"),
    (["simulate", "--method", "Tsit5"], "got 'Tsit5'; did you mean 'tsit5'?"),
    (["simulate", "--geometry", "ful"], "got 'ful'; did you mean 'full'?"),
    (["fit", "--table", "{table}", "--free", "C1", "c33"], "allowed: c1, p1, c2, p2, c3, c4, c5, p5, c6, c7, p7, "
     "c8, p8, p9; did you mean 'c1', 'c3'?"),
    (["fit", "--table", "{tmp}"], "peeljax: error: --table: '{tmp}' is a folder, expected a file"),
    (["fit", "--data", "{tmp}", "--out", "{tmp}/f.json"], "peeljax: error: --data: '{tmp}' is a folder, expected a file"),
    (["fit", "--table", "{runs}"], "a stick-slip table is text (CSV or whitespace columns V, F_mean, ...); runs in "
     "an .npz are fitted with --data"),
    (["tau-star", "--save-dt", "0.1"],
     "unrecognized option --save-dt (an option of peeljax simulate and sweep, not of peeljax tau-star)"),
]  # fmt: skip


@pytest.fixture
def nothing_runs(no_compilation, monkeypatch):
    reason = "the mistake reached a computation: it must be refused first"
    forbid(monkeypatch, "peeljax.cli.simulate", "run", reason=reason)
    forbid(monkeypatch, "peeljax.cli.fit", "_table_command", reason=reason)
    forbid(monkeypatch, "peeljax.fit", "fit_adhesion", reason=reason)


@pytest.mark.parametrize(("argv", "said"), MISTAKES, ids=[" ".join(argv) for argv, _ in MISTAKES])
def test_a_mistake_is_refused_in_one_line_before_anything_runs(argv, said, tmp_path, nothing_runs):
    (tmp_path / "t.csv").write_text(TABLE)
    (tmp_path / "r.csv").write_text(FORCE_RECORD)
    np.savez(tmp_path / "runs.npz", t=np.linspace(0.0, 1.0, 5), v=np.ones(5), V=1.1)
    names = {"table": str(tmp_path / "t.csv"), "record": str(tmp_path / "r.csv"), "tmp": str(tmp_path),
             "runs": str(tmp_path / "runs.npz")}  # fmt: skip
    code, out, err = run_cli([word.format(**names) for word in argv])
    assert code == 2 and out == "", err
    assert said.format(**names) in err.strip().splitlines()[-1], err
    assert {p.name for p in tmp_path.iterdir()} == {"t.csv", "r.csv", "runs.npz"}  # nothing written
