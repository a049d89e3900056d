"""``peeljax orbit``: one orbit's summary, JSON, file and figure; bad input refused before
anything compiles; the exit status of each outcome.

In-process (``peeljax.cli.main``): the command shoots with the Python API's own compiled
programs, so the one real orbit here (V = 1.1, the paper's φ) compiles once for the module
(and not again after tests/test_orbits.py in the same process). Outcomes that need no
shooting (no orbit, no convergence, Ctrl-C) replace ``periodic_orbit``.
"""

from __future__ import annotations

import json

import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli

import peeljax as pj
import peeljax.orbits
from peeljax.orbits import OrbitStatus, SavedOrbit

V = 1.1
STATS = ("F_mean", "F_slip", "F_stick", "period", "slip_duration")


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """``peeljax orbit --V 1.1 --json --out --plot`` once, for the module."""
    folder = tmp_path_factory.mktemp("orbit")
    npz, png = folder / "orbit.npz", folder / "orbit.png"
    code, out, err = run_cli(["orbit", "--V", str(V), "--json", "--out", str(npz), "--plot", str(png), "--no-progress"])
    return {"code": code, "stdout": out, "stderr": err, "npz": npz, "png": png}


@pytest.mark.slow
def test_the_orbit_is_the_python_apis_in_one_json_object(shot):
    assert shot["code"] == 0, shot["stderr"]
    record = json.loads(shot["stdout"])  # stdout is exactly one JSON object
    orbit = pj.periodic_orbit(V=V)  # the same compiled programs: the same numbers
    expected = orbit.as_dict()
    for key in ("period", "slips_per_period", "stable", "multipliers", "statistics", "status", "newton_iterations",
                "residual", "section"):  # fmt: skip
        assert record[key] == expected[key], key
    assert record["status"] == "converged" and record["slips_per_period"] == 8 and record["stable"] is True
    assert record["residual"] <= 1e-10 and 1 <= record["newton_iterations"] <= 8
    assert set(record["statistics"]) == set(STATS)
    assert set(record["test_functions"]) == {"fold", "period_doubling", "torus"}
    assert record["settings"]["rtol"] == 1e-8 and record["settings"]["transient"] == 3.0
    assert record["out"] == str(shot["npz"]) and record["plot"] == str(shot["png"])


@pytest.mark.slow
def test_out_is_read_back_as_the_orbit_and_plot_is_a_figure(shot):
    record = json.loads(shot["stdout"])
    back = pj.load(shot["npz"])
    assert isinstance(back, SavedOrbit) and back.as_dict() == {k: record[k] for k in back.as_dict()}
    assert back.settings["rtol"] == 1e-8 and back.settings["max_iterations"] == 20
    assert shot["png"].read_bytes()[:8] == PNG_MAGIC


@pytest.mark.slow
def test_the_summary_says_period_events_stability_and_statistics(shot):
    code, out, err = run_cli(["orbit", "--V", str(V)])  # compiled by the fixture already
    assert code == 0, err
    out.encode("ascii")  # plain ASCII whatever the terminal
    record = json.loads(shot["stdout"])
    assert f"period T = {record['period']:.7g} s with 8 stick -> slip events per period" in out
    assert "stable: Floquet multipliers" in out and "converged: the return map's fixed point was found" in out
    assert f"F_slip {record['statistics']['F_slip']:.6g} N" in out and "time between slips" in out
    assert "compiling first" in err and "done in" in err


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--V", "-1"], ["--V", "(0, inf)"]),
        (["--slips", "0"], ["--slips", "[1, 1000]"]),
        (["--slips", "100000"], ["--slips", "[1, 1000]"]),
        (["--transient", "0"], ["--transient", "(0, inf)"]),
        (["--max-iterations", "0"], ["--max-iterations", "[1, 1000]"]),
        (["--rtol", "2"], ["--rtol", "(0, 1)"]),
        (["--atol", "-1e-9"], ["--atol", "(0, inf)"]),
        (["--geometry", "round"], ["--geometry"]),
        (["--phi", "/nonexistent/phi.json"], ["--phi"]),
        (["--plot", "orbit.xyz"], ["--plot", "unknown image format"]),
        (["--out", "/nonexistent/folder/orbit.npz"], ["--out", "does not exist"]),
        (["--out", "orbit.csv"], ["--out", "writes FILE.npz"]),
    ],
)
def test_bad_input_exits_2_before_anything_compiles(argv, words, monkeypatch, no_compilation):
    forbid(monkeypatch, peeljax.orbits, "periodic_orbit", reason="shot before the input was checked")
    code, out, err = run_cli(["orbit", *argv])
    assert_refused(code, err, *words, stdout=out)


def test_V_is_one_number_or_a_range(no_compilation):
    # argparse's own refusal: its usage, then the line
    code, out, err = run_cli(["orbit", "--V", "0.3:1:2:4"])
    assert code == 2 and out == "" and "argument --V: '0.3:1:2:4'" in err and "START:STOP or START:STOP:SEEDS" in err
    code, out, err = run_cli(["orbit", "--V", "0.3:1:x"])
    assert code == 2 and "SEEDS must be an integer in [2, " in err
    code, out, err = run_cli(["orbit", "--V", "1.2:0.9"])  # the range checked before anything runs
    assert_refused(code, err, "--V START:STOP must have 0 < START < STOP, got 1.2:0.9", stdout=out)


def test_no_orbit_to_shoot_for_exits_2_with_the_reason(tmp_path):
    # φ has no fold at V = 6 m/s (steady peeling): said before any shooting
    code, out, err = run_cli(["orbit", "--V", "6", "--out", str(tmp_path / "o.npz")])
    line = assert_refused(code, err, "no orbit to shoot for at V = 6 m/s", "phi has no fold", stdout=out)
    assert "start:" not in line and not (tmp_path / "o.npz").exists()


def _not_converged() -> pj.PeriodicOrbit:
    """An orbit whose Newton did not converge (its fields as shooting leaves them: finite)."""
    from test_orbit_files import _orbit

    return _orbit(status=OrbitStatus.NOT_CONVERGED)


def test_an_orbit_that_did_not_converge_exits_1_saying_why(monkeypatch, tmp_path):
    monkeypatch.setattr(peeljax.orbits, "periodic_orbit", lambda *args, **kwargs: _not_converged())
    npz, png = tmp_path / "o.npz", tmp_path / "o.png"
    code, out, err = run_cli(["orbit", "--out", str(npz), "--plot", str(png)])
    assert code == 1
    assert "not_converged: Newton's method did not converge within max_iterations" in out
    assert "at Newton's last point: not an orbit" in out
    assert "the orbit did not converge (not_converged)" in err and "no figure" in err
    assert pj.load(npz).status_name == "not_converged" and not png.exists()  # the file records the failure
    code, out, err = run_cli(["orbit", "--json"])
    assert code == 1 and json.loads(out)["status"] == "not_converged" and json.loads(out)["plot"] is None


def test_a_refusal_of_the_library_is_one_line_exit_2(monkeypatch):
    def refuses(*args, **kwargs):
        raise ValueError("start: a single run of the DAE with jumps is needed")

    monkeypatch.setattr(peeljax.orbits, "periodic_orbit", refuses)
    code, out, err = run_cli(["orbit"])
    assert_refused(code, err, "a single run of the DAE with jumps is needed", stdout=out)


def test_ctrl_c_exits_130_in_one_line(monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(peeljax.orbits, "periodic_orbit", interrupted)
    code, out, err = run_cli(["orbit"])
    assert code == 130 and out == "" and len(err.strip().splitlines()) == 2  # the note of what runs, the line


def test_help_gives_every_default_and_the_exit_codes():
    code, out, _ = run_cli(["orbit", "--help"])
    assert code == 0
    text = " ".join(out.split())
    for words in ("Exit status: 0 the orbit converged", "1 it did not", "2 bad input", "130 interrupted",
                  "(default 1.1)", "(default 3)", "(default 20)", "(default 1e-08", "(default: the repeat's"):  # fmt: skip
        assert words in text, words


@pytest.mark.slow
def test_the_figure_draws_into_the_users_axes(shot):
    """plot_orbit on a loaded orbit: into four axes of the user's (the trajectory compiled by
    the fixture's --plot), refused for a batch or a failed orbit."""
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from peeljax.plots import plot_orbit

    if shot["code"] != 0:
        pytest.fail(shot["stderr"])
    fig = Figure()
    axes = fig.subplots(2, 2).ravel()
    assert plot_orbit(pj.load(shot["npz"]), axes=axes) is fig
    assert axes[0].get_yscale() == "log" and axes[2].get_xscale() == "log"
    assert len(axes[1].get_lines()) >= 6  # F(t), slips, re-sticks, F_mean, F_slip, F_stick
    # where the tension F meets the force G φ balances, the legend says which is which
    labels = [t.get_text() for t in axes[1].get_legend().get_texts()]
    assert any(label.startswith("F_slip") and "G = " in label and "φ's maximum" in label for label in labels)
    assert any(label.startswith("F_stick") and "G = " in label and "φ's minimum" in label for label in labels)
    with pytest.raises(ValueError, match="did not converge"):
        plot_orbit(_not_converged())
    with pytest.raises(ValueError, match="4 Axes"):
        plot_orbit(pj.load(shot["npz"]), axes=axes[:3])
