"""``peeljax fit``: a ``simulate --out`` file fitted end to end, data layouts, and bad input
rejected (exit 2) before anything is compiled."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli

from peeljax import AdhesionLaw
from peeljax.adhesion import COEFFICIENT_NAMES
from peeljax.measurements.records import load_observations

SHORT = ["--t-final", "0.2", "--save-dt", "0.01", "--tau", "0.1"]


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A short run with a perturbed φ written by ``peeljax simulate --out``, and its t, F, v as a
    CSV text record (V in the name): the fits below take both files (one compiled fit for both)."""
    folder = tmp_path_factory.mktemp("fit_cli")
    phi = folder / "true.json"
    AdhesionLaw(c1=440.0).to_json(phi)
    npz = folder / "observed.npz"
    code, _, err = run_cli(["simulate", *SHORT, "--V", "1.1", "--phi", str(phi), "--out", str(npz)])
    assert code == 0, err
    with np.load(npz) as data:
        rows = np.column_stack([data["t"], data["F"], data["v"]])
    csv = folder / "peel_V=1.1.csv"
    csv.write_text("# t [s], F [N], v [m/s]\nt,F,v\n" + "\n".join(",".join(repr(float(x)) for x in row) for row in rows))
    return folder, npz, csv


@pytest.mark.slow
def test_fit_a_simulate_file_and_a_csv_end_to_end(simulated):
    """simulate --out → fit --data run.npz --data peel_V=1.1.csv (the same run's t, F, v as text, V
    in the name), both in one fit: fitted.json readable by --phi, loss falls, plot written. (One
    compiled fit serves both readers: each such fit compiles for minutes on 2 cores.)"""
    folder, npz, csv = simulated
    out, png = folder / "fitted.json", folder / "fit.png"
    code, stdout, err = run_cli(
        ["fit", "--data", str(npz), "--data", str(csv), "--out", str(out), "--free", "c1", "--steps", "25",
         "--optimizer", "lbfgs", "--plot", str(png), "--json", "--no-progress"]
    )  # fmt: skip
    assert code == 0, err
    assert "to 2 run(s) (V = 1.1, 1.1)" in err
    summary = json.loads(stdout)
    record = json.loads(out.read_text())
    assert set(COEFFICIENT_NAMES) <= set(record)
    assert record["settings"]["data"] == [str(npz), str(csv)]
    assert record["settings"]["V"] == [1.1, 1.1]
    assert record["settings"]["tau"] == pytest.approx(0.1)  # taken from the .npz file (the text has none)
    assert record["settings"]["dt"] is None  # error control (the default), not the data's spacing
    assert record["settings"]["rtol"] == 1e-6
    assert len(record["loss_history"]) == summary["steps"] + 1 and 1 <= summary["steps"] <= 25
    # Noise-free data from c1 = 440 (the start, the paper's 400, is 10 % off): L-BFGS must find it.
    assert record["c1"] == pytest.approx(440.0, rel=1e-4)
    assert record["final_loss"] < 1e-6 * record["initial_loss"]
    assert record["start"]["c1"] == 400.0
    law = AdhesionLaw.from_json(out)  # also the --phi layout
    assert float(law.c1) == record["c1"]
    assert record["v_range"][0] < record["v_range"][1]
    assert png.read_bytes().startswith(PNG_MAGIC)


def test_data_layouts(tmp_path):
    """Single-V files (t, v, V, F with own times) and multi-V files (V_0, t_0, v_0, …)."""
    t = np.linspace(0, 1, 11)
    single = tmp_path / "one.npz"
    np.savez(single, t=t, v=t + 1, V=np.float64(2.0), F=t[:5], t_F=t[:5], tau=0.05, dt=0.1)
    multi = tmp_path / "many.npz"
    np.savez(multi, V_0=1.1, t_0=t, v_0=t, V_1=4.0, t_1=t[:6], v_1=t[:6], alpha_1=t[:6])
    observations, defaults = load_observations([str(single), str(multi)])
    assert [o.V for o in observations] == [2.0, 1.1, 4.0]
    assert observations[0].series("F")[0].shape == (5,)
    assert observations[2].series("alpha") is not None and observations[1].series("alpha") is None
    assert defaults == {"tau": 0.05, "dt": 0.1}


@pytest.fixture
def no_fit(monkeypatch):
    """Bad input must fail before anything is fitted or compiled."""
    forbid(monkeypatch, "peeljax.fit", "fit_adhesion", reason="fit_adhesion must not run for bad input")


@pytest.fixture
def good_npz(tmp_path):
    path = tmp_path / "good.npz"
    t = np.linspace(0, 0.2, 21)
    np.savez(path, t=t, v=t + 0.1, V=1.1)
    return str(path)


def _bad_files(tmp_path):
    t = np.linspace(0, 1, 5)
    files = {}
    files["missing_v"] = tmp_path / "a.npz"
    np.savez(files["missing_v"], t=t, V=1.0)
    files["pickled"] = tmp_path / "b.npz"
    np.savez(files["pickled"], t=t, v=np.array([{"a": 1}] * 5, dtype=object), V=1.0)
    files["lengths"] = tmp_path / "c.npz"
    np.savez(files["lengths"], t=t, v=t[:3], V=1.0)
    files["negative_V"] = tmp_path / "d.npz"
    np.savez(files["negative_V"], t=t, v=t, V=-1.0)
    files["text"] = tmp_path / "e.npz"
    files["text"].write_text("not an npz")
    files["infinite_v"] = tmp_path / "f.npz"
    np.savez(files["infinite_v"], t=t, v=np.where(t > 0.1, np.inf, 1.0), V=1.0)
    files["unordered_t"] = tmp_path / "g.npz"
    np.savez(files["unordered_t"], t=t[::-1], v=t, V=1.0)
    files["negative_F"] = tmp_path / "h.npz"
    np.savez(files["negative_F"], t=t, v=t + 0.1, F=np.where(t > 0.5, -5.0, 200.0), V=1.0)
    return files


BAD = [
    (["--steps", "0"], "--steps", "[1, inf)"),
    (["--tau", "0"], "--tau", "(0, 1e+06]"),
    (["--dt", "5"], "dt", "(0, 0.2]"),
    (["--optimizer", "sgd"], "--optimizer", "adam, lbfgs"),
    (["--free", "c1", "zz"], "--free", "c1, p1"),
    (["--learning-rate", "-1"], "--learning-rate", "(0, inf)"),
    (["--out", "/nonexistent-folder/x.json"], "--out", "does not exist"),
    (["--plot", "fit.xyz"], "--plot", "png"),
    (["--data", "/nonexistent.npz"], "--data", "does not exist"),
    (["--data", "missing_v"], "--data", "missing 'v'"),
    (["--data", "pickled"], "--data", "without pickles"),
    (["--data", "lengths"], "--data", "one length"),
    (["--data", "negative_V"], "V", "(0, inf)"),
    (["--data", "text"], "--data", "without pickles"),
    (["--rtol", "2"], "rtol", "(0, 1)"),
    (["--dt", "0.01", "--atol", "1e-9"], "--atol", "--dt"),
    (["--data", "infinite_v"], "--data", "infinite"),
    (["--data", "unordered_t"], "--data", "increase strictly"),
    (["--data", "negative_F"], "--data", ">= 0 N"),
]


def test_a_tau_0_run_file_is_read_and_asks_for_tau(tmp_path, monkeypatch):
    """``simulate --tau 0 --out`` writes two rows at each jump (``after_jump``): fit --data reads
    them as one, the left limit, and reaches the fit with strictly increasing times; without --tau
    it says the runs were at τ = 0 and fits at the default τ (the homogenized ODE)."""
    run = tmp_path / "rec.npz"
    code, _, err = run_cli(["simulate", "--V", "1.1", "--tau", "0", "--t-final", "0.3", "--save-dt", "0.001",
                            "--out", str(run)])  # fmt: skip
    assert code == 0, err
    with np.load(run, allow_pickle=False) as data:
        assert data["after_jump"].sum() >= 2
    seen = {}

    class Reached(Exception):
        pass

    def fake(observations, **kwargs):
        seen["observations"], seen["tau"] = observations, kwargs.get("tau")
        raise Reached

    monkeypatch.setattr("peeljax.fit.fit_adhesion", fake)
    with pytest.raises(Reached):
        run_cli(["fit", "--data", str(run), "--free", "c1", "--out", str(tmp_path / "f.json")])
    assert seen["tau"] == 0.01
    with pytest.raises(Reached):
        run_cli(["fit", "--data", str(run), "--free", "c1", "--tau", "1e-3", "--out", str(tmp_path / "f.json")])
    (observation,) = seen["observations"]
    assert np.all(np.diff(observation.t) > 0) and seen["tau"] == 1e-3



def test_simulate_out_csv_is_a_text_record_of_the_run(tmp_path):
    """``simulate --out run.csv``: the run's rows as text with a header and units; read back as a
    force record, its left limits are those of the same run's .npz."""
    from peeljax.fit import read_force_record
    from peeljax.measurements.records import read_npz

    argv = ["simulate", "--V", "1.1", "--tau", "0", "--t-final", "0.3", "--save-dt", "0.001"]
    for name in ("run.csv", "run.npz"):
        code, _, err = run_cli([*argv, "--out", str(tmp_path / name)])
        assert code == 0, err
    lines = (tmp_path / "run.csv").read_text().splitlines()
    assert lines[0].startswith("# peeljax run: V = 1.1 m/s, tau = 0.0 s, completed")
    assert lines[2] == "t [s],alpha [rad],omega [rad/s],u [m],v [m/s],F [N],G [N],V [m/s],after_jump"
    with np.load(tmp_path / "run.npz", allow_pickle=False) as data:
        assert len(lines) - 3 == data["t"].size and sum(line.endswith(",1") for line in lines) == data["after_jump"].sum()
    text = read_force_record(tmp_path / "run.csv")
    (npz,), _ = read_npz(tmp_path / "run.npz")
    assert text.V == 1.1
    for quantity in ("v", "F", "alpha"):
        np.testing.assert_array_equal(text.series(quantity)[0], npz.series(quantity)[0])
        np.testing.assert_allclose(text.series(quantity)[1], npz.series(quantity)[1], rtol=0, atol=0)


@pytest.mark.parametrize(("options", "name", "allowed"), BAD, ids=[" ".join(o) for o, *_ in BAD])
def test_bad_input_exits_2_before_fitting(options, name, allowed, no_fit, good_npz, tmp_path):
    files = _bad_files(tmp_path)
    options = [str(files[o]) if o in files else o for o in options]
    data = [] if "--data" in options else ["--data", good_npz]
    out = [] if "--out" in options else ["--out", str(tmp_path / "fitted.json")]
    code, stdout, stderr = run_cli(["fit", *data, *out, *options])
    assert_refused(code, stderr, name, allowed, stdout=stdout)


def test_a_record_too_short_to_determine_a_coefficient_says_so_and_what_length_would():
    """After a records fit: a coefficient known to worse than 5 % is named, with the length of
    record that would give 1 % (the error falls like 1/sqrt(length))."""
    from types import SimpleNamespace

    from peeljax.fit.records_fit import poorly_determined
    from peeljax.fit import Observation

    record = Observation(V=1.1, t=np.linspace(0.0, 0.002, 5), v=None, F=np.full(5, 250.0))

    def result(errors):
        uncertainty = SimpleNamespace(names=("c1", "c6"), values=np.array([400.0, 415.0]), standard_errors=np.array(errors))
        return SimpleNamespace(uncertainty=uncertainty)

    line = poorly_determined(result([40.0, 2.0]), [record])
    assert "c1 to 10 %" in line and "c6" not in line and "about 0.2 s of record (100x the 0.002 s given)" in line, line
    assert "c6 not at all" in poorly_determined(result([1.0, np.inf]), [record])
    assert poorly_determined(result([1.0, 2.0]), [record]) is None  # 0.25 % and 0.5 %: said nothing
    assert poorly_determined(SimpleNamespace(), [record]) is None


@pytest.mark.slow
def test_an_interrupted_fit_writes_its_best_iterate_so_far(simulated, monkeypatch, capsys):
    """Ctrl-C after a few iterations of ``fit --data``: exit 130, --out holds the best iterate so
    far (a file --phi reads, its stop_reason saying so), and the line on stderr says what it holds.
    Slow: beside the end-to-end fit above, whose compiled update it shares (the same two files, free
    set and optimizer, L-BFGS: JAX's compilation cache hands it over, its compilation being
    nearly all of either test's time; the default optimizer, Adam, compiled a second program;
    with one file of the two it compiled its own, 154 s in CI)."""
    from peeljax.fit import trajectory

    folder, npz, csv = simulated
    real, calls = trajectory._update, []

    def interrupted_on_the_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(trajectory, "_update", interrupted_on_the_third)
    out = folder / "interrupted.json"
    code = run_cli(["fit", "--data", str(npz), "--data", str(csv), "--out", str(out), "--free", "c1", "--steps", "10",
                    "--optimizer", "lbfgs", "--no-progress"])[0]  # fmt: skip
    assert code == 130
    record = json.loads(out.read_text())
    assert record["stop_reason"] == "interrupted after 1 iterations" and len(record["loss_history"]) == 2
    assert record["final_loss"] == min(record["loss_history"])
    assert AdhesionLaw.from_json(out).c1 == pytest.approx(record["c1"])


def test_fit_help_says_what_transient_does_with_data():
    _, out, _ = run_cli(["fit", "--help"])
    text = " ".join(out.split())
    assert "--data: of each force record" in text and "the record's second half" in text
