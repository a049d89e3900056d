"""A sweep over several processes on this machine (JAX's distributed runtime) against one process.

    python benchmarks/distributed_scaling.py                 # 1 process x 2 devices vs 2 processes x 1 device
    python benchmarks/distributed_scaling.py --processes 2 4 # 4 oversubscribes a 2-core machine (flagged)
    python benchmarks/distributed_scaling.py --quick         # a smaller sweep

Each configuration runs the same :func:`peeljax.sweep` on the same total number of CPU devices
(one per core): P processes started together on 127.0.0.1 (a free port), each with one device
(``XLA_FLAGS=--xla_force_host_platform_device_count=1``), each calling
``jax.distributed.initialize`` and then ``peeljax.sweep(..., out=<shared folder>)`` twice, the
second time into a fresh ``out`` (compiled already: the run alone); the baseline is one process
with P devices and no distributed runtime. The script prints per configuration: process
start-up and joining, the first sweep (compile + run), the second (run only, each chunk's
gather and process 0's writes included), the whole command, and the ratios to the baseline;
and it checks that every configuration gives the same statuses, event and jump counts.

One run each: on a shared machine the numbers are noisy (the load average is printed). The
script is the multi-process path run by hand (``tests/test_distributed.py`` runs it through the
command line); it needs nothing but peeljax.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path


# ---------------------------------------------------------------------------- one process of a configuration
def _worker(args) -> None:
    start = time.perf_counter()
    import jax

    if args.num_processes > 1:
        jax.distributed.initialize(
            coordinator_address=args.coordinator, num_processes=args.num_processes, process_id=args.process_id
        )
    joined = time.perf_counter()
    import numpy as np

    import peeljax

    sweep = json.loads(args.sweep)
    times = []
    for name in ("first.npz", "second.npz"):
        begin = time.perf_counter()
        result = peeljax.sweep(**sweep, out=str(Path(args.folder) / name), progress=False)
        times.append(time.perf_counter() - begin)
    record = {
        "process": jax.process_index(),
        "devices": len(jax.devices()),
        "local_devices": len(jax.local_devices()),
        "start_s": joined - start,
        "first_s": times[0],
        "second_s": times[1],
        "status": np.asarray(result.status).tolist(),
        "events": np.asarray(result.events).tolist(),
        "jump_count": None if result.jumps is None else np.asarray(result.jumps["jump_count"]).tolist(),
        "v_mean": np.asarray(result.v_mean).tolist(),
    }
    print(json.dumps(record), flush=True)


# ---------------------------------------------------------------------------- the driver
def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _run(processes: int, devices: int, sweep: dict, timeout: float) -> dict:
    """``processes`` workers with ``devices`` CPU devices each; their records and the command's wall time."""
    port = _free_port()
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        procs = [
            subprocess.Popen(
                [sys.executable, __file__, "--worker", "--coordinator", f"127.0.0.1:{port}",
                 "--num-processes", str(processes), "--process-id", str(i), "--folder", folder,
                 "--sweep", json.dumps(sweep)],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
            for i in range(processes)
        ]
        records = []
        try:
            for i, proc in enumerate(procs):
                out, err = proc.communicate(timeout=timeout)
                if proc.returncode != 0:
                    raise RuntimeError(f"process {i} of {processes} failed:\n{err[-3000:]}")
                # the last line: gloo prints its own lines on stdout
                records.append(json.loads([line for line in out.splitlines() if line.startswith("{")][-1]))
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
        wall = time.perf_counter() - start
    return {"records": records, "wall_s": wall}


def _load() -> str:
    try:
        return ", ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--processes", type=int, nargs="+", default=[2], help="process counts to run (default 2)")
    parser.add_argument("--quick", action="store_true", help="a smaller sweep (8 V, 0.5 s)")
    parser.add_argument("--timeout", type=float, default=1200, help="seconds per configuration (default 1200)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--coordinator", help=argparse.SUPPRESS)
    parser.add_argument("--num-processes", dest="num_processes", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--process-id", dest="process_id", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--folder", help=argparse.SUPPRESS)
    parser.add_argument("--sweep", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        _worker(args)
        return 0
    if any(p < 2 for p in args.processes):
        parser.error("--processes: counts >= 2 (one process is the baseline, always run)")

    # The DAE (tau = 0), error control: every lane goes through the folds of phi, the costly
    # lanes (large V, many jumps) dealt over the devices like cards.
    n_v, t_final = (8, 0.5) if args.quick else (32, 1.5)
    sweep = {"V": [1.0 + 3.0 * i / (n_v - 1) for i in range(n_v)], "tau": 0.0, "t_final": t_final, "rtol": 1e-6,
             "chunk": n_v // 2}  # fmt: skip
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"# peeljax.sweep over processes: {n_v} V in [1, 4] m/s, tau = 0, t_final = {t_final} s, rtol 1e-6, "
          f"chunk {n_v // 2} (2 chunks); {cores} cores; load average {_load()} (one run each: noisy)")  # fmt: skip
    print()
    print("| configuration | start-up + join [s] | 1st sweep: compile + run [s] | 2nd sweep: run [s] | command [s] "
          "| run vs 1 process | command vs 1 process |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    reference, worst = None, 0.0
    for processes in args.processes:
        baseline = _run(1, processes, sweep, args.timeout)
        multi = _run(processes, 1, sweep, args.timeout)
        rows = ((f"1 process x {processes} devices", baseline), (f"{processes} processes x 1 device", multi))
        for label, run in rows:
            records = run["records"]
            start = max(r["start_s"] for r in records)
            first = max(r["first_s"] for r in records)
            second = max(r["second_s"] for r in records)
            base = max(r["second_s"] for r in baseline["records"])
            note = f" (oversubscribed: {processes} devices on {cores} cores)" if processes > cores else ""
            print(f"| {label}{note} | {start:.2f} | {first:.2f} | {second:.3f} | {run['wall_s']:.2f} | "
                  f"{second / base:.2f} | {run['wall_s'] / baseline['wall_s']:.2f} |")  # fmt: skip
            for record in records:
                assert record["devices"] == processes, record["devices"]
                summary = (record["status"], record["events"], record["jump_count"])
                reference = (summary, record["v_mean"]) if reference is None else reference
                if summary != reference[0]:
                    raise AssertionError(f"{label}, process {record['process']}: other statuses, events or jumps")
                worst = max(worst, max(abs(a - b) / abs(b) for a, b in zip(record["v_mean"], reference[1], strict=True)))
    print()
    print(f"results: statuses, event counts and jump counts equal in every configuration and process; v_mean to "
          f"{worst:.1e} relative")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
