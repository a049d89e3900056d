"""A sweep over several processes (JAX's distributed runtime), run for real on this machine.

Two ``peeljax sweep`` processes, coordinator on 127.0.0.1 at a free port, one CPU device each,
write one ``--out`` in a shared folder; the merged file equals a one-process sweep on two
devices, and an interrupted multi-process sweep resumes to the same file. The process options
are checked before anything is joined or compiled, and a process that cannot reach its
coordinator exits 2 with a message after ``--distributed-timeout``.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import assert_refused, forbid, run_cli

import peeljax
from peeljax.cli import build_parser
from peeljax.cli.sweep import distributed_settings, join_processes
from peeljax.sweeps.distributed import DEFAULT_TIMEOUT

# The smallest sweep that shows it: 4 lanes of the DAE (tau = 0: each lane jumps at the folds of
# φ, 4 to 60 jumps in 0.2 s), 2 chunks of 2 lanes, one lane a device per chunk.
V = [1.1, 2.0, 3.0, 4.0]
SWEEP = ["sweep", "--V", *map(str, V), "--tau", "0", "--t-final", "0.2", "--rtol", "1e-4", "--chunk", "2",
         "--no-progress", "--json"]  # fmt: skip
EXACT = ("status", "events", "accepted_steps", "rejected_steps", "newton_iterations", "window_count", "jump_count",
         "jump_up", "jump_t", "jump_v_before", "jump_v_after", "jump_G")  # fmt: skip
# The tolerance docs/sweeps.md states for the other floats (measured: bit for bit on this machine).
RTOL = 1e-12


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _start(argv: list[str], n: int, cache: Path) -> list[subprocess.Popen]:
    """``peeljax <argv>`` as processes 0..n-1 of one sweep, started together, one CPU device each.

    ``cache``: JAX's persistent compilation cache, so that a rerun's process 0 loads its program.
    """
    port = _free_port()
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1", JAX_COMPILATION_CACHE_DIR=str(cache))
    return [
        subprocess.Popen(
            [sys.executable, "-m", "peeljax.cli", *argv, "--coordinator", f"127.0.0.1:{port}",
             "--num-processes", str(n), "--process-id", str(i)],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        for i in range(n)
    ]


def _finish(procs: list[subprocess.Popen], timeout: float = 300) -> list[subprocess.CompletedProcess]:
    """Wait for every process; each must exit 0 (a failed one must not leave the others waiting)."""
    done = []
    try:
        for i, proc in enumerate(procs):
            out, err = proc.communicate(timeout=timeout)
            done.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
            assert proc.returncode == 0, f"process {i}: {err[-3000:]}"
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return done


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


@pytest.mark.slow
def test_two_processes_equal_one_and_resume(tmp_path, monkeypatch):
    multi, cache = tmp_path / "multi.npz", tmp_path / "cache"
    first = _finish(_start([*SWEEP, "--out", str(multi)], 2, cache))
    record = json.loads(first[0].stdout)  # stdout: the JSON object only
    assert record["n"] == len(V) and record["computed_chunks"] == [0, 1]
    assert first[1].stdout == ""  # process 0 reports, the others compute their share
    chunks = tmp_path / "multi.npz.chunks"
    assert sorted(p.name for p in chunks.iterdir()) == ["chunk_00000.npz", "chunk_00001.npz", "meta.json"]
    before = _arrays(multi)

    # Interrupted after the first chunk: chunk 0 and the folder are left, no merged file. The
    # rerun (2 processes) goes on while this process runs the one-process sweep.
    multi.unlink()
    (chunks / "chunk_00001.npz").unlink()
    rerun = _start([*SWEEP, "--out", str(multi)], 2, cache)

    # One process on two devices (the same chunks): it never joins, broadcasts or gathers.
    why = "a one-process sweep did multi-process work"
    forbid(monkeypatch, jax.distributed, "initialize", reason=why)
    forbid(monkeypatch, "jax.experimental.multihost_utils", "process_allgather", "broadcast_one_to_all", reason=why)
    forbid(monkeypatch, "peeljax.sweeps.api", "check_same_settings", "open_shared_store", reason=why)
    single = tmp_path / "single.npz"
    try:
        peeljax.sweep(V=V, tau=0.0, t_final=0.2, rtol=1e-4, chunk=2, out=single, progress=False,
                      devices=jax.devices()[:2])  # fmt: skip
    finally:
        resumed = _finish(rerun)
    got, want = dict(before), _arrays(single)
    assert json.loads(str(got.pop("meta_json"))) == json.loads(str(want.pop("meta_json")))  # same settings
    assert got.keys() == want.keys()
    assert want["jump_count"].min() >= 4 and want["events"].max() > 0  # the lanes jump
    for key in got:
        if key in EXACT or got[key].dtype.kind != "f":
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)
        else:
            np.testing.assert_allclose(got[key], want[key], rtol=RTOL, atol=0, err_msg=key)

    assert json.loads(resumed[0].stdout)["computed_chunks"] == [1]
    after = _arrays(multi)
    assert after.keys() == before.keys()
    for key in after:
        np.testing.assert_array_equal(after[key], before[key], err_msg=key)


@pytest.mark.slow
def test_unreachable_coordinator_fails_after_timeout():
    port = _free_port()  # nothing listens there
    start = time.perf_counter()
    run = subprocess.run(
        [sys.executable, "-m", "peeljax.cli", *SWEEP, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
         "--process-id", "1", "--distributed-timeout", "1"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    wall = time.perf_counter() - start
    assert run.returncode == 2, run.stderr
    assert run.stdout == "" and "Traceback" not in run.stderr
    message = run.stderr.strip().splitlines()[-1]
    assert message.startswith("peeljax: error: process 1 of 2, coordinator 127.0.0.1:")
    assert f"127.0.0.1:{port}" in message and "--distributed-timeout 1 s" in message
    assert wall < 60  # no hang: the process's start-up, 1 s, the message


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--coordinator", "localhost", "--num-processes", "2", "--process-id", "0"], ["--coordinator", "HOST:PORT"]),
        (["--coordinator", "h:70000", "--num-processes", "2", "--process-id", "0"], ["--coordinator", "[1, 65535]"]),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "2"], ["--process-id", "[0, 1]"]),
        (["--coordinator", "h:1", "--num-processes", "0", "--process-id", "0"], ["--num-processes", ">= 1"]),
        (["--coordinator", "h:1", "--num-processes", "2"], ["--process-id", "is needed"]),
        (["--num-processes", "2", "--process-id", "1"], ["--coordinator", "is needed"]),
        (["--distributed", "--distributed-timeout", "0"], ["--distributed-timeout", "> 0"]),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "0", "--stick-slip-map"],
         ["--stick-slip-map"]),
    ],
)  # fmt: skip
def test_process_options_refused_before_anything_runs(options, words, monkeypatch, no_compilation):
    for name in ("JAX_COORDINATOR_ADDRESS", "SLURM_JOB_ID", "SLURM_PROCID", "SLURM_NTASKS"):
        monkeypatch.delenv(name, raising=False)
    forbid(monkeypatch, jax.distributed, "initialize", reason="joined before the options were checked")
    code, out, err = run_cli([*SWEEP, *options])
    assert_refused(code, err, *words, stdout=out)


def _args(*options: str):
    return build_parser().parse_args([*SWEEP, *options])


def test_one_process_joins_nothing(monkeypatch):
    monkeypatch.delenv("SLURM_PROCID", raising=False)
    forbid(monkeypatch, jax.distributed, "initialize", reason="a one-process sweep joined a runtime")
    for options in ([], ["--coordinator", "h:1", "--num-processes", "1", "--process-id", "0"]):
        args = _args(*options)
        assert distributed_settings(args) is None
        assert join_processes(None, args) is None
    assert _args().distributed_timeout == DEFAULT_TIMEOUT


def test_slurm_srun_detected(monkeypatch, capsys):
    """Under ``srun -n 4`` JAX's detection gives the job's first node, SLURM_NTASKS, SLURM_PROCID."""
    slurm = {"SLURM_JOB_ID": "4242", "SLURM_STEP_NODELIST": "node[007-010]", "SLURM_NTASKS": "4",
             "SLURM_PROCID": "2", "SLURM_LOCALID": "0"}  # fmt: skip
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    monkeypatch.delenv("JAX_COORDINATOR_ADDRESS", raising=False)
    monkeypatch.delenv("JAX_COORDINATOR_PORT", raising=False)
    processes = distributed_settings(_args("--distributed"))
    assert (processes.num_processes, processes.process_id) == (4, 2)
    assert processes.coordinator == f"node007:{4242 % 2**12 + 65535 - 2**12 + 1}"
    # srun without --distributed: four whole sweeps, and a note that says so
    assert distributed_settings(_args()) is None
    assert "SLURM started 4 tasks" in capsys.readouterr().err
