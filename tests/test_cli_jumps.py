"""``peeljax simulate`` through the folds of φ: --tau 0 (the DAE), --fold, --max-jumps, --transient.

One run of the DAE (τ = 0, 0.5 s, about thirty jumps) writes every output and serves most tests;
the refusals of bad input are checked before anything compiles.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli, run_cli_writing

from peeljax import PeelingModel, Solution, StopReason, cycle_statistics
from peeljax.simulate import FIRST_MAX_JUMPS
from peeljax.solution import JumpRecord

DAE = ["simulate", "--tau", "0", "--t-final", "0.5"]
JUMP_KEYS = ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G")


def _npz(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def dae_run(tmp_path_factory):
    """The DAE over 0.5 s with jumps, writing --out, --plot and --json."""
    result = run_cli_writing(tmp_path_factory.mktemp("dae_run"), DAE)
    assert result["code"] == 0, result["stderr"]
    result["record"] = json.loads(result["stdout"])
    result["arrays"] = _npz(result["npz"])
    return result


# ---------------------------------------------------------------------------- a run with jumps
@pytest.mark.slow
def test_dae_run_completes_with_jumps(dae_run):
    record = dae_run["record"]
    assert record["status"] == "completed" and record["tau"] == 0.0
    # max_jumps: the record's size, grown to the run from the first (no --max-jumps given)
    assert record["fold"] == "jump" and record["max_jumps"] == FIRST_MAX_JUMPS
    assert record["jumps"] > 0 and record["jumps"] == record["stats"]["jumps"]


@pytest.mark.slow
def test_npz_holds_the_jumps(dae_run):
    arrays, record = dae_run["arrays"], dae_run["record"]
    for key in JUMP_KEYS:
        assert arrays[key].shape == (record["jumps"],), key
    assert arrays["jump_up"].dtype == bool and arrays["jump_t"].dtype == np.float64
    assert str(arrays["fold"]) == "jump" and int(arrays["max_jumps"]) == FIRST_MAX_JUMPS
    assert float(arrays["transient"]) == pytest.approx(0.5 / 2)
    t = arrays["jump_t"]
    assert np.all(np.isfinite(arrays["jump_G"])) and np.all(np.diff(t) > 0)
    assert 0 < t[0] and t[-1] <= float(arrays["t_stop"])
    # stick → slip first (the tape starts stuck), then alternating; v up and down accordingly
    up = arrays["jump_up"]
    assert up[0] and np.all(up[1:] != up[:-1])
    assert np.all(arrays["jump_v_after"][up] > arrays["jump_v_before"][up])
    assert np.all(arrays["jump_v_after"][~up] < arrays["jump_v_before"][~up])


@pytest.mark.slow
def test_G_is_continuous_across_the_jumps(dae_run):
    """The first row at a jump's time holds the state just before it (G there is the recorded G),
    the second the state just after it (after_jump: v jumped, G the same); the row after them is
    the end of the first step after the jump, on the other branch, with G moved on continuously
    from the jump's (down while slipping, up while sticking)."""
    arrays = dae_run["arrays"]
    G = np.asarray(PeelingModel().shear_force(np.stack([arrays["alpha"], arrays["omega"], arrays["u"]])))
    rows = np.searchsorted(arrays["t"], arrays["jump_t"])
    np.testing.assert_allclose(arrays["t"][rows], arrays["jump_t"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(G[rows], arrays["jump_G"], rtol=1e-9)
    # at a fold v moves like the square root of G's distance to it: a round-off in G there is ~1e-5 in v
    np.testing.assert_allclose(arrays["v"][rows], arrays["jump_v_before"], rtol=1e-3)
    np.testing.assert_array_equal(np.flatnonzero(arrays["after_jump"]), rows + 1)
    np.testing.assert_array_equal(arrays["t"][rows + 1], arrays["jump_t"])
    np.testing.assert_allclose(arrays["v"][rows + 1], arrays["jump_v_after"], rtol=1e-12)
    np.testing.assert_allclose(G[rows + 1], arrays["jump_G"], rtol=1e-9)
    up = arrays["jump_up"].astype(bool)
    split = np.sqrt(arrays["jump_v_before"][up][0] * arrays["jump_v_before"][~up][0])  # between the folds
    after = arrays["v"][rows + 2]
    assert np.all(after[up] > split) and np.all(after[~up] < split)
    assert np.all(G[rows + 2][up] < arrays["jump_G"][up]) and np.all(G[rows + 2][~up] > arrays["jump_G"][~up])
    # and it has not passed the other fold within that step (a slip ends where G reaches φ(v̌))
    assert np.all(G[rows + 2][up] > arrays["jump_G"][~up].min() - 1e-9)
    assert np.all(G[rows + 2][~up] < arrays["jump_G"][up].max() + 1e-9)


@pytest.mark.slow
def test_json_cycles_match_the_npz(dae_run):
    record, arrays = dae_run["record"], dae_run["arrays"]
    cycles = record["cycles"]
    assert cycles["transient"] == pytest.approx(0.5 / 2) and cycles["t_end"] == pytest.approx(record["t_stop"])
    assert 0 < cycles["jumps"] <= record["jumps"]
    # what the npz holds gives the same statistics
    again = cycle_statistics(arrays, float(arrays["t_stop"]), transient=float(arrays["transient"])).as_dict()
    assert json.loads(json.dumps(again)) == cycles


@pytest.mark.slow
def test_plot_with_jumps_is_the_stick_slip_figure(dae_run):
    assert dae_run["png"].read_bytes()[:8] == PNG_MAGIC


@pytest.mark.slow
def test_plain_summary_is_ascii_with_jumps_and_cycles(dae_run):
    # the same compiled program as dae_run (JAX's cache): no new compilation
    code, out, err = run_cli([*DAE])
    assert code == 0, err
    assert out.isascii(), [line for line in out.splitlines() if not line.isascii()]
    assert f"jumps at the folds of phi: {dae_run['record']['jumps']}" in out
    assert "cycles in [" in out and "stick -> slip" in out


@pytest.mark.slow
def test_max_jumps_stops_the_run(tmp_path):
    npz = tmp_path / "run.npz"
    code, out, err = run_cli([*DAE, "--max-jumps", "3", "--out", str(npz), "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["status"] == "stopped" and "max_jumps" in record["reason"]
    assert record["jumps"] == 3 and record["max_jumps"] == 3
    arrays = _npz(npz)
    assert str(arrays["reason"]) == StopReason.MAX_JUMPS.message
    assert all(arrays[key].shape == (3,) for key in JUMP_KEYS)
    assert int(arrays["max_jumps"]) == 3
    # the plain summary (the same compiled program) says it in options, not in the parameter max_jumps
    code, out, err = run_cli([*DAE, "--max-jumps", "3"])
    assert code == 0 and "the jump record is full (--max-jumps 3): raise --max-jumps to go on" in out, out
    assert "max_jumps" not in out


@pytest.mark.slow
def test_fold_stop_stops_at_the_first_fold(tmp_path):
    npz = tmp_path / "run.npz"
    code, out, err = run_cli([*DAE, "--fold", "stop", "--out", str(npz), "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["status"] == "stopped" and "fold" in record["reason"] and record["fold"] == "stop"
    assert record["jumps"] == 0 and 0.1 < record["t_stop"] < 0.2  # the first stick → slip, t ≈ 0.166 s
    assert record["cycles"] is None and "transient" in record["cycles_note"]  # stopped before it ended
    arrays = _npz(npz)
    assert all(arrays[key].shape == (0,) for key in JUMP_KEYS) and str(arrays["fold"]) == "stop"
    code, out, err = run_cli([*DAE, "--fold", "stop"])  # the plain summary names the options
    assert code == 0 and "a fold of phi was reached (--fold stop)" in out and "--fold jump carries" in out, out
    assert "fold='" not in out


@pytest.mark.slow
def test_uniform_mesh_has_no_jump_record(tmp_path):
    npz = tmp_path / "run.npz"
    code, out, err = run_cli(["simulate", "--t-final", "0.2", "--dt", "0.01", "--out", str(npz), "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["fold"] == "stop" and record["max_jumps"] is None
    assert "jumps" not in record and "cycles" not in record
    arrays = _npz(npz)
    assert not {*JUMP_KEYS, "fold", "max_jumps"} & arrays.keys()


def test_help_names_the_options():
    code, out, _err = run_cli(["simulate", "--help"])
    assert code == 0
    for option in ("--fold", "--max-jumps", "--transient", "DAE"):
        assert option in out, option


# ---------------------------------------------------------------------------- bad input
@pytest.fixture
def no_compilation(no_compilation, monkeypatch):
    """conftest's ``no_compilation``, and the command line's own calls of the integrators fail the test too."""
    reason = "bad input reached the integrator: it must be rejected before compilation"
    forbid(monkeypatch, "peeljax.cli.simulate", "simulate", "simulate_reference", reason=reason)


# (options, words the message must hold: the option and its allowed values or the way out)
BAD_INPUT = [
    (["--fold", "nope"], ["fold", "jump, stop, follow"]),
    (["--max-jumps", "0"], ["--max-jumps", "[1, 1e+07]"]),
    (["--max-jumps=-2"], ["--max-jumps", "[1, 1e+07]"]),
    (["--max-jumps", "100000000"], ["--max-jumps", "[1, 1e+07]", "allocated in full"]),
    (["--max-jumps", "10", "--dt", "0.01"], ["--max-jumps", "--dt"]),
    (["--fold", "follow", "--tau", "0"], ["--fold follow", "--tau 0"]),
    (["--fold", "jump", "--dt", "0.01"], ["--fold jump", "--dt", "--fold stop"]),
    (["--fold", "follow", "--method", "diffrax"], ["--fold follow", "--method diffrax", "--fold stop"]),
    (["--tau", "0", "--dt", "0.01"], ["--tau 0", "--dt", "(0, 1e+06]"]),
    (["--tau", "0", "--method", "diffrax"], ["--tau 0", "--method diffrax"]),
    (["--tau=-1"], ["tau", "[0, 1e+06]"]),
    (["--transient", "0.5"], ["--transient", "[0, 0.5)"]),
    (["--transient", "2"], ["--transient", "[0, 0.5)"]),
    (["--transient=-0.1"], ["--transient", "[0, 0.5)"]),
    (["--transient", "nan"], ["--transient", "[0, 0.5)"]),
]


@pytest.mark.parametrize(("options", "words"), BAD_INPUT, ids=[" ".join(o) for o, _ in BAD_INPUT])
def test_bad_input_exits_2_before_compiling(options, words, no_compilation):
    code, out, err = run_cli(["simulate", "--t-final", "0.5", *options])
    assert_refused(code, err, *words, stdout=out)


def test_fold_stop_is_allowed_on_the_uniform_mesh(no_compilation):
    from peeljax.cli import build_parser, validate_run

    config = validate_run(build_parser().parse_args(["simulate", "--dt", "0.01", "--fold", "stop"]))
    assert config.fold == "stop" and not config.adaptive
    config = validate_run(build_parser().parse_args(["simulate", "--tau", "0"]))
    assert config.fold == "jump" and config.dae and config.transient == pytest.approx(1.5)  # t_final/2


# ---------------------------------------------------------------------------- the figure, without a run
def _hand_made(with_jumps: bool) -> Solution:
    """A trajectory with two jumps, the second landing fully stuck (v = 0): no integration."""
    ts = jnp.array([0.0, 0.1, 0.1, 0.2, 0.2, 0.3])
    v = jnp.array([0.01, 0.5, 15.0, 8.5, 0.0, 0.0])
    u = jnp.array([0.30, 0.36, 0.36, 0.28, 0.28, 0.30])
    ys = jnp.stack([jnp.full(6, 0.05), jnp.zeros(6), u, v], axis=1)
    jumps = None
    if with_jumps:
        G = PeelingModel().shear_force(ys[jnp.array([1, 3]), :3].T)
        jumps = JumpRecord.empty(4).record(True, 0.1, True, 0.5, 15.0, G[0]).record(True, 0.2, False, 8.5, 0.0, G[1])
    return Solution(
        ts=ts, ys=ys, valid=jnp.ones(6, bool), status=jnp.asarray(0), t_stop=jnp.asarray(0.3),
        stats={"steps": jnp.asarray(5)}, diagnostics=None, jumps=jumps,
    )  # fmt: skip


def test_stick_slip_figure_of_a_hand_made_run(tmp_path):
    from peeljax.plots import plot_stick_slip

    figure = plot_stick_slip(_hand_made(True), PeelingModel(), 1.1, path=tmp_path / "f.png", transient=0.05)
    assert (tmp_path / "f.png").read_bytes()[:8] == PNG_MAGIC
    assert len(figure.axes) == 3
    texts = [text.get_text() for ax in figure.axes for text in ax.texts]
    assert any("fully stuck" in text for text in texts)
    assert any("v̂" in text for text in texts) and any("v̌" in text for text in texts)
    by_label = {ax.get_xlabel() or ax.get_ylabel(): ax for ax in figure.axes}
    assert by_label["peeling velocity v [m/s]"].get_xscale() == "log"  # the loop
    assert figure.axes[0].get_yscale() == "log"  # v(t)


def test_stick_slip_figure_needs_a_jump_record():
    from peeljax.plots import plot_stick_slip

    with pytest.raises(ValueError, match="no jump record"):
        plot_stick_slip(_hand_made(False), PeelingModel(), 1.1)


def test_new_stop_reasons_have_short_notes():
    from peeljax.plots import short_reason

    for reason, words in ((StopReason.MAX_JUMPS, "max_jumps"), (StopReason.FOLD, "fold")):
        solution = _hand_made(True)
        solution = Solution(**{**vars(solution), "status": jnp.asarray(int(reason))})
        assert words in short_reason(solution)
