"""What a new user runs into (issue 21): output too large for memory, damaged files, Ctrl-C,
misspelled or partial inputs, negative numbers, long runs, a saved run loaded back.

Each refusal is checked for its exit status (2, or 130 for Ctrl-C), a message naming the option
or the file, no traceback, and that nothing was written or lost that should not be.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_refused, forbid, run_cli

import peeljax as pj
from peeljax import COEFFICIENT_NAMES, AdhesionLaw, Solution, StopReason
from peeljax.cli import build_parser
from peeljax.cli.simulate import validate_run, write_npz
from peeljax.sweeps import engine

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def no_compilation(no_compilation, monkeypatch):
    """conftest's, and the command line's own calls of the integrators fail the test too."""
    reason = "the request reached the integrator: it must be refused before compiling"
    forbid(monkeypatch, "peeljax.cli.simulate", "simulate", "simulate_reference", reason=reason)


@pytest.fixture
def small_memory(monkeypatch):
    """A memory limit of 1 GB whatever the machine, so that the refusals do not depend on its RAM."""
    monkeypatch.setattr("peeljax._memory.memory_limit", lambda: 1e9)


# ---------------------------------------------------------------------------- memory
def test_simulate_cli_refuses_output_that_would_exhaust_memory(no_compilation, tmp_path):
    out = tmp_path / "tiny.npz"
    start = time.perf_counter()
    code, stdout, err = run_cli(["simulate", "--save-dt", "1e-9", "--t-final", "3", "--out", str(out)])
    message = assert_refused(code, err, "--save-dt 1e-09", "would take 1.2e+03 GB", "memory limit", stdout=stdout)
    assert "3e+09 output times" in message and "larger --save-dt" in message
    assert time.perf_counter() - start < 5  # the times themselves (24 GB) are never made
    assert "Traceback" not in err and not out.exists()


def test_simulate_cli_refuses_a_uniform_mesh_too_large(no_compilation, small_memory):
    code, stdout, err = run_cli(["simulate", "--dt", "3e-8", "--t-final", "3"])
    assert_refused(
        code, err, "--dt 3e-08", "would take 15 GB", "1e+08 mesh points", "memory limit of 1 GB", stdout=stdout
    )


def test_simulate_api_refuses_before_compiling(no_compilation):
    with pytest.raises(ValueError, match=r"would take .* GB \(1000 output times.*fewer output times ts"):
        pj.simulate(t_final=3.0, ts=np.linspace(0, 3, 1000), memory_limit=1e4)
    with pytest.raises(ValueError, match=r"1e\+09 rows of accepted steps .*a smaller max_steps"):
        pj.simulate(t_final=3.0, max_steps=10**9, memory_limit=1e9)
    with pytest.raises(ValueError, match=r"a record of 1000000000 jumps.*a smaller max_jumps"):
        pj.simulate(tau=0.0, t_final=3.0, max_jumps=10**9, memory_limit=1e9)
    with pytest.raises(ValueError, match=r"mesh points .*a larger dt"):
        pj.simulate(dt=1e-7, t_final=3.0, memory_limit=1e8)
    with pytest.raises(ValueError, match=r"would take .*a larger dt"):
        pj.simulate_reference(dt=1e-7, t_final=3.0, memory_limit=1e8)


def test_sweep_refuses_before_making_the_save_times(no_compilation):
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"the sweep's output would take .* GB .*larger save_dt, now 1e-12"):
        pj.sweep(V=[1.1], tau=[0.01], t_final=3.0, save_dt=1e-12, progress=False)
    assert time.perf_counter() - start < 5  # 3e12 save times are counted, not made


# ---------------------------------------------------------------------------- the .npz of simulate, loaded back
def _solution(stopped: bool = False) -> Solution:
    """A hand-made error-controlled run (stats step_size NaN, as error control reports it)."""
    ts = jnp.linspace(0.0, 0.1, 11)
    valid = jnp.arange(11) <= (5 if stopped else 10)
    ys = jnp.stack([1e-3 * ts, 10 * ts, 0.3 + 0.01 * ts, 1e-3 + ts], axis=1)
    return Solution(
        ts=ts,
        ys=jnp.where(valid[:, None], ys, jnp.nan),
        valid=valid,
        status=jnp.asarray(int(StopReason.STALLED if stopped else StopReason.COMPLETED)),
        t_stop=jnp.asarray(0.05 if stopped else 0.1),
        stats={"accepted_steps": jnp.asarray(12), "step_size": jnp.asarray(jnp.nan), "steps": jnp.asarray(12)},
        diagnostics=None,
    )


def _strict(text: str):
    def refuse(constant):
        raise AssertionError(f"not strict JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize("stopped", [False, True])
def test_npz_stats_are_strict_json_and_the_run_loads_back(stopped, tmp_path):
    path = tmp_path / "run.npz"
    config = validate_run(build_parser().parse_args(["simulate", "--V", "2", "--tau", "0.05", "--t-final", "0.1"]))
    solution = _solution(stopped)
    write_npz(str(path), solution, config)
    with np.load(path, allow_pickle=False) as data:
        stats = _strict(str(data["stats_json"]))  # NaN is null, as in --json
    assert stats["step_size"] is None and stats["accepted_steps"] == 12
    run = pj.load(path)
    assert isinstance(run, Solution)
    with pytest.raises(AttributeError, match=r"Solution.load was removed: use peeljax.load\(path\)"):
        pj.Solution.load(path)  # it made solution.py and saved.py import each other
    np.testing.assert_array_equal(run.ts, solution.ts)
    np.testing.assert_array_equal(run.ys, solution.ys)
    np.testing.assert_array_equal(run.valid, solution.valid)
    assert int(run.status) == int(solution.status) and run.reason == solution.reason
    assert float(run.t_stop) == float(solution.t_stop) and math.isnan(float(run.stats["step_size"]))
    assert run.V == 2.0 and run.tau == 0.05 and run.model.adhesion.coefficients() == AdhesionLaw().coefficients()
    assert run.summary()["status"] == ("stopped" if stopped else "completed")
    assert len(repr(run).splitlines()) == 1 and str(path) in repr(run)
    analysis = pj.analyze(run)  # V, tau and the model from the file
    assert analysis.V == 2.0 and analysis.tau == 0.05 and analysis.completed is not stopped
    assert np.isfinite(analysis.schur[analysis.valid]).all()
    shown = repr(analysis)
    assert 2 <= len(shown.splitlines()) <= 5 and len(shown) < 800, shown
    assert "V = 2 m/s" in shown and "stick" in shown


def test_load_refuses_malformed_files_naming_them(tmp_path):
    cases = {
        "random.npz": lambda p: p.write_bytes(os.urandom(2000)),
        "empty.npz": lambda p: p.write_bytes(b""),
        "text.npz": lambda p: p.write_text("t,v\n0,1\n"),
        "other.npz": lambda p: np.savez(p, V=np.ones(3)),
        "lengths.npz": lambda p: np.savez(
            p,
            **{k: np.zeros(2 if k == "u" else 3) for k in ("t", "alpha", "omega", "u", "v")},
            status=np.asarray("completed"),
            t_stop=np.float64(1.0),
        ),
        "objects.npz": lambda p: np.savez(p, t=np.array([{"a": 1}], dtype=object)),
    }
    for name, make in cases.items():
        path = tmp_path / name
        make(path)
        with pytest.raises(ValueError) as error:
            pj.load(path)
        message = str(error.value)
        assert repr(str(path)) in message, message
        assert "pickled" not in message, message
    with pytest.raises(ValueError, match="does not start as a zip archive"):
        pj.load(tmp_path / "random.npz")
    with pytest.raises(ValueError, match="malformed: missing"):
        pj.load(tmp_path / "other.npz")
    with pytest.raises(ValueError, match="1-D of one length"):
        pj.load(tmp_path / "lengths.npz")
    with pytest.raises(FileNotFoundError, match="no such file"):
        pj.load(tmp_path / "missing.npz")
    # a damaged file names every kind pj.load reads, orbits and diagrams among them
    (tmp_path / "damaged.npz").write_bytes(b"PK\x03\x04 not the rest of a zip archive")
    with pytest.raises(ValueError, match="damaged") as error:
        pj.load(tmp_path / "damaged.npz")
    assert all(kind in str(error.value) for kind in ("a run", "an orbit", "an orbit diagram", "a sweep", "a stick slip map"))


def test_a_damaged_run_file_is_refused(tmp_path):
    path = tmp_path / "run.npz"
    config = validate_run(build_parser().parse_args(["simulate", "--t-final", "0.1"]))
    write_npz(str(path), _solution(), config)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"run.npz' is not a readable .npz file: it is damaged \(truncated"):
        pj.load(path)


# ---------------------------------------------------------------------------- --phi
@pytest.mark.parametrize(
    ("data", "named"),
    [({"c1": 448, "C3": 100}, "['C3']"), ({"c9": 1.0, "p_1": 0.3}, "['c9', 'p_1']"), ({"c1 ": 400}, "['c1 ']")],
)
def test_phi_with_unknown_coefficients_is_refused(data, named, no_compilation, tmp_path):
    path = tmp_path / "phi.json"
    path.write_text(json.dumps(data))
    code, out, err = run_cli(["simulate", "--phi", str(path), "--t-final", "0.1"])
    assert_refused(code, err, "--phi", str(path), named, ", ".join(COEFFICIENT_NAMES), stdout=out)
    assert "Traceback" not in err
    code, out, err = run_cli(["sweep", "--phi", str(path), "--t-final", "0.1", "--tau", "0.01"])
    assert_refused(code, err, "--phi", named, stdout=out)


def test_phi_notes_and_a_fit_result_are_accepted():
    law = AdhesionLaw.from_dict(
        {"c1": 440.0, "note": "fitted", "V": 1.1, "loss_history": [1.0, 0.5], "settings": {"tau": 0.1}}
    )
    assert law.coefficients() == {**AdhesionLaw().coefficients(), "c1": 440.0}


def test_a_partial_phi_file_says_which_coefficients_keep_the_paper_values(tmp_path):
    path = tmp_path / "phi.json"
    path.write_text('{"c1": 448, "c3": 117}')
    kept = [name for name in COEFFICIENT_NAMES if name not in ("c1", "c3")]
    args = build_parser().parse_args(["simulate", "--phi", str(path)])
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        config = validate_run(args)
    assert config.phi_defaults == tuple(kept)
    assert config.model.adhesion.coefficients()["c1"] == 448.0
    (line,) = err.getvalue().splitlines()
    assert line == f"peeljax: note: --phi {path} sets c1, c3; {', '.join(kept)} keep the paper's values"


@pytest.mark.slow
def test_a_partial_phi_file_is_named_in_the_json_output(tmp_path):
    path = tmp_path / "phi.json"
    path.write_text('{"c1": 448}')
    code, out, err = run_cli(["simulate", "--phi", str(path), "--t-final", "0.02", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["phi_paper_defaults"] == list(COEFFICIENT_NAMES[1:])
    assert "p1, c2, p2" in err and "keep the paper's values" in err
    code, out, err = run_cli(["simulate", "--t-final", "0.02", "--json"])
    assert json.loads(out)["phi_paper_defaults"] is None and "note" not in err


# ---------------------------------------------------------------------------- negative numbers, --version
NEGATIVE = [
    (["simulate", "--rtol", "-1e-6"], "rtol must lie in (0, 1), got -1e-06"),
    (["simulate", "--atol", "-1E-9"], "atol must lie in (0, inf)"),
    (["simulate", "--V", "-inf"], "V must be finite"),
    (["simulate", "--tau", "-nan"], "tau must be finite"),
    (["simulate", "--t-final", "-3"], "--t-final must be > 0"),
    (["simulate", "--save-dt", "-.5"], "--save-dt must lie in (0, --t-final]"),
    (["simulate", "--transient", "-1e0"], "--transient must lie in [0, --t-final)"),
    (["sweep", "--rtol", "-1e-6"], "--rtol must lie in (0, 1)"),
    (["sweep", "--V", "1", "-2e0"], "--V must be > 0 (allowed range: (0, inf))"),
    (["sweep", "--tau", "-1e-3", "--n-tau", "2"], "--tau"),
]


@pytest.mark.parametrize(("argv", "words"), NEGATIVE, ids=[" ".join(a) for a, _ in NEGATIVE])
def test_negative_numbers_reach_the_range_check(argv, words, no_compilation):
    code, out, err = run_cli(argv)
    assert_refused(code, err, words, stdout=out)
    assert "expected one argument" not in err and "Traceback" not in err


def test_version():
    code, out, _err = run_cli(["--version"])
    assert code == 0 and out.strip() == f"peeljax {pj.__version__}"


# ---------------------------------------------------------------------------- long runs: the default dtmin
def test_stalled_message_names_dtmin_as_a_cause():
    message = StopReason.STALLED.message
    assert "step size collapsed" in message and "impasse point" in message and "dtmin itself is too large" in message


def test_dtmin_not_below_t_final(no_compilation):
    with pytest.raises(ValueError, match=r"dtmin must be < t_final"):
        pj.simulate(t_final=3.0, dtmin=3.0)


@pytest.mark.slow
def test_a_long_run_is_not_stopped_by_the_default_dtmin():
    """The first step from the paper's start is ~1e-11 s whatever t_final: the old default
    1e-12·t_final (1e-3 s at t_final = 1e9) stopped the run at t = 0."""
    for t_final in (1e5, 1e9):
        sol = pj.simulate(t_final=t_final, ts=np.array([0.0, t_final]))
        assert sol.status_name == "completed", (t_final, sol.reason)
    # (the default starts with Tsit5, whose first step is larger; the α-method's is ~1e-11 s)
    alpha = pj.simulate(t_final=1e9, ts=np.array([0.0, 1e9]), solver="alpha")
    assert alpha.status_name == "completed" and float(alpha.stats["step_size_min"]) < 1e-10
    stalled = pj.simulate(t_final=1e9, ts=np.array([0.0, 1e9]), dtmin=1e-3)  # the old default, given
    assert int(stalled.status) == StopReason.STALLED and float(stalled.t_stop) == 0.0
    assert "dtmin itself is too large" in stalled.reason


@pytest.mark.slow
def test_cli_long_run_completes():
    code, out, err = run_cli(["simulate", "--t-final", "1e9", "--save-dt", "1e8", "--json"])
    record = json.loads(out)
    assert code == 0 and record["status"] == "completed" and record["t_stop"] == 1e9, err


# ---------------------------------------------------------------------------- sweeps: damaged files, Ctrl-C, modes
# 8 trajectories in chunks of 2 (rounded up to the device count: 4 chunks on 2 cores, 2 on 4)
SWEEP = ["sweep", "--V", "1.1", "2", "3", "4", "--tau", "1e-3", "1e-2", "--n-tau", "2", "--dt", "0.01",
         "--t-final", "0.4", "--chunk", "2", "--save-every", "5", "--window", "0.25", "1", "--no-progress", "--json"]  # fmt: skip


def _sweep(out: Path) -> tuple[int, str, str]:
    return run_cli([*SWEEP, "--out", str(out)])


def _n_chunks(out: Path) -> int:
    return json.loads((Path(str(out) + ".chunks") / "meta.json").read_text())["n_chunks"]


@pytest.fixture(scope="module")
def clean_sweep(tmp_path_factory):
    """The sweep run once, uninterrupted: what every resumed run must equal."""
    out = tmp_path_factory.mktemp("clean") / "sweep.npz"
    code, stdout, err = _sweep(out)
    assert code == 0, err
    if _n_chunks(out) < 2:
        pytest.skip("one chunk on this many devices: nothing to resume from")
    return out, json.loads(stdout)


def test_sweep_outputs_get_the_umask_mode(clean_sweep):
    out, _ = clean_sweep
    mask = os.umask(0o022)
    os.umask(mask)
    for path in (out, *sorted(Path(str(out) + ".chunks").glob("chunk_*.npz"))):
        assert os.stat(path).st_mode & 0o777 == 0o666 & ~mask, path


@pytest.mark.parametrize("damage", ["truncated", "random"])
@pytest.mark.parametrize("which", ["merged", "chunk"])
def test_resume_refuses_a_damaged_file_naming_it(which, damage, clean_sweep, tmp_path, monkeypatch):
    import shutil

    source, _ = clean_sweep
    out = tmp_path / "sweep.npz"
    shutil.copy(source, out)
    shutil.copytree(str(source) + ".chunks", str(out) + ".chunks")
    chunk = Path(str(out) + ".chunks") / "chunk_00001.npz"  # the last of at least 2
    if which == "chunk":
        out.unlink()
    target = out if which == "merged" else chunk
    data = target.read_bytes()
    broken = data[: len(data) // 2] if damage == "truncated" else os.urandom(len(data))
    target.write_bytes(broken)
    forbid(monkeypatch, engine, "run_batch", reason="a damaged file must be refused before running")
    code, stdout, err = _sweep(out)
    message = assert_refused(code, err, repr(str(target)), "not a readable .npz file", "delete it", stdout=stdout)
    assert ("damaged (truncated" in message) if damage == "truncated" else ("does not start as a zip" in message)
    assert "pickled" not in message and "Traceback" not in err
    assert target.read_bytes() == broken  # nothing deleted or rewritten
    if which == "chunk":
        assert (Path(str(out) + ".chunks") / "chunk_00000.npz").read_bytes() == (
            Path(str(source) + ".chunks") / "chunk_00000.npz"
        ).read_bytes()


def test_ctrl_c_saves_one_line_and_a_rerun_resumes_to_the_clean_result(clean_sweep, tmp_path, monkeypatch):
    _, clean = clean_sweep
    out = tmp_path / "sweep.npz"
    calls = []
    original = engine.run_batch

    def interrupted(*args, **kwargs):
        if calls:
            raise KeyboardInterrupt
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(engine, "run_batch", interrupted)
    code, stdout, err = _sweep(out)
    assert code == 130 and stdout == "" and "Traceback" not in err
    line = err.strip().splitlines()[-1]
    chunks, n = str(out) + ".chunks", _n_chunks(clean_sweep[0])
    assert line == f"peeljax: interrupted: 1 of {n} chunks saved in {chunks!r}; rerun the same command to resume"
    assert not out.exists() and len(list(Path(chunks).glob("chunk_*.npz"))) == 1
    assert not list(Path(chunks).glob("*.tmp"))  # the chunk being written when interrupted is not left half-done
    monkeypatch.setattr(engine, "run_batch", original)
    code, stdout, err = _sweep(out)
    assert code == 0, err
    assert f"resumed: 1 of {n} chunks loaded from {chunks!r}" in err
    record = json.loads(stdout)
    assert record["computed_chunks"] == list(range(1, n))
    assert record["trajectories"] == clean["trajectories"]
    with np.load(out, allow_pickle=False) as resumed, np.load(clean_sweep[0], allow_pickle=False) as full:
        for key in full.files:
            if key != "meta_json":
                np.testing.assert_array_equal(resumed[key], full[key], err_msg=key)


def test_ctrl_c_without_out_says_nothing_was_saved(monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(engine, "run_batch", interrupted)
    code, stdout, err = run_cli(SWEEP)
    assert code == 130 and stdout == "" and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("peeljax: interrupted: nothing was saved (no --out)")


def test_ctrl_c_elsewhere_exits_130_in_one_line(monkeypatch):
    def interrupted(config):
        raise KeyboardInterrupt

    monkeypatch.setattr("peeljax.cli.simulate.run", interrupted)
    code, stdout, err = run_cli(["simulate", "--t-final", "0.1"])
    assert code == 130 and stdout == "" and err.strip().splitlines()[-1] == "peeljax: interrupted"


@pytest.mark.slow
def test_a_real_sigint_during_a_sweep(tmp_path):
    """SIGINT to the running command: exit 130, one line, no traceback, nothing half-written.

    The signal is sent as soon as the command has announced the sweep (while it compiles or
    runs its first chunks), not on a chunk file's appearance: in CI the whole sweep finished
    between two polls of the file, twice."""
    out = tmp_path / "sweep.npz"
    argv = ["sweep", "--V", *map(str, np.linspace(1.0, 4.0, 64)), "--tau", "0.01", "--dt", "0.0002", "--t-final", "3",
            "--chunk", "2", "--no-progress", "--out", str(out)]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "peeljax.cli", *argv],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = process.stderr.readline()
    assert first.startswith("peeljax: sweep of 64 trajectories"), first
    process.send_signal(signal.SIGINT)
    stdout, rest = process.communicate(timeout=240)
    stderr = first + rest
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr and stdout == ""
    last = stderr.strip().splitlines()[-1]
    # before the sweep began: "peeljax: interrupted"; during it: how many chunks are saved
    assert last == "peeljax: interrupted" or (
        last.startswith("peeljax: interrupted: ") and "chunks saved in" in last and "rerun the same command" in last
    ), stderr
    assert not list(tmp_path.glob("**/*.tmp"))


# ---------------------------------------------------------------------------- one story in the docs
def test_docs_call_the_uniform_mesh_cycles_an_artefact():
    from peeljax.figures import CAPTIONS, MESH_NOTE

    assert "artefact" in MESH_NOTE and "--stick-slip-map" in MESH_NOTE and "--tau 0" in MESH_NOTE
    assert "uniform mesh" in CAPTIONS["bifurcation_V"] and "coarse mesh" in CAPTIONS["fig5_v_V2"]
    reproduction = (REPO / "docs" / "reproduction.md").read_text(encoding="utf-8")
    assert "still run on the paper's uniform mesh" not in reproduction
    assert "artefact" in reproduction and "05_stick_slip.ipynb" in reproduction
    notebook = (REPO / "notebooks" / "03_sweeps.ipynb").read_text(encoding="utf-8")
    assert "stick-slip amplitude" not in notebook and "05_stick_slip.ipynb" in notebook


@pytest.mark.parametrize("call", ["simulate, jumps merged", "simulate, none", "Simulator", "sweep", "periodic_orbit", "analyze"])
def test_a_result_is_freed_once_dropped(call):
    """Nothing keeps a result alive after the caller drops it. ``simulate``'s host-side copies
    (the jump rows merged, the rows added for the bucket cut) once did: equinox records each
    module it makes as initialising until its ``__init__`` ends, and a copy made by
    ``copy.copy`` never ran one, so every run (its arrays too) was kept for the life of the process."""
    import gc
    import weakref

    ts = np.linspace(0.0, 0.5, 6)
    grid = np.linspace(0.0, 1.5, 11)  # 11 rows: a bucket of 12, cut on the host
    make = {
        "simulate, jumps merged": lambda: pj.simulate(V=1.1, tau=0.0, t_final=1.5, ts=grid),
        "simulate, none": lambda: pj.simulate(V=1.1, tau=0.01, t_final=1.5, ts=grid),
        "Simulator": lambda: pj.Simulator(t_final=0.5, ts=ts)(1.1, 0.0),
        "sweep": lambda: pj.sweep(V=[1.1, 2.0], tau=[0.01], t_final=0.5, progress=False),
        "periodic_orbit": lambda: pj.periodic_orbit(V=1.1),
        "analyze": lambda: pj.analyze(pj.simulate(V=1.1, tau=0.0, t_final=1.5)),
    }[call]
    result = make()
    if call.startswith("simulate"):  # both paths: jump rows merged, and none to merge
        assert (int(result.jumps.count) > 0) == (call == "simulate, jumps merged")
    kept = weakref.ref(result)
    del result
    gc.collect()
    assert kept() is None
