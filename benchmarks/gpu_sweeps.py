"""The V-map at 10⁴, 10⁵ and 10⁶ lanes and the P3 batch at 1024 lanes on one device (a GPU).

* **V-map**: :func:`peeljax.stick_slip_map` of the DAE (τ = 0) over N values of V in
  [0.2, 8] m/s from the paper's start, [0, ``--t-final``] s (default 0.3 s, statistics after
  half of it), in chunks of ``--chunk`` lanes (default: 10⁴ on a GPU, 512 on a CPU), each lane
  keeping its window's cycle statistics and its last ``--max-jumps`` jumps (default 64);
* **P3**: :func:`peeljax.sweep` of the homogenized ODE over the 1024 (V, τ) of
  ``compare_problems.p3_grid(256)`` (V = 1.1, 2, 4, 8 m/s × 256 τ in [0.005, 0.5] s), [0, 3] s,
  saving v every 10 ms (the P3 problem of ``compare.py``).

Each row: the first call (compilation included: for the V-map, the sweep of one chunk) and a
second call (the run: the map of all N lanes); lanes per second; completed and stick-slipping
lanes; the host bytes per lane of the sweep's result and of the map (their arrays' ``nbytes``); the peak resident memory of this process (``ru_maxrss``) and, on a GPU, the
device's peak bytes in use. The device is named in the table.

    python benchmarks/gpu_sweeps.py                       # on a GPU: writes results/gpu_sweeps.md
    python benchmarks/gpu_sweeps.py --smoke               # CPU-sized (V-map 64 and 256 lanes, P3 16)
    /usr/bin/time -v python benchmarks/gpu_sweeps.py --sizes 100000 --no-p3   # the 10⁵-lane map on a CPU

``--out``: the table's file (default ``results/gpu_sweeps.md``, ``gpu_sweeps_smoke.md`` with ``--smoke``).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
from pathlib import Path

import jax
import numpy as np

import peeljax as pj

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_problems import P3_SAVE_DT, p3_grid  # noqa: E402
from machine import cpu_model, load_average, timed, write_result  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def device_name() -> str:
    device = jax.devices()[0]
    if device.platform == "cpu":
        return f"CPU: {cpu_model()}, {os.cpu_count()} cores ({len(jax.devices())} JAX devices)"
    return f"{device.platform.upper()}: {device.device_kind} ({len(jax.devices())} device(s))"


def peak_rss_mib() -> float:
    """This process's peak resident memory so far [MiB] (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def device_peak_mib() -> float:
    """The device's peak bytes in use [MiB] (NaN where the backend keeps no such statistic: CPUs)."""
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use", float("nan")) / 2**20


def nbytes(value) -> int:
    """Host bytes of a result's arrays (dicts and dataclass fields followed)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, dict):
        return sum(nbytes(v) for v in value.values())
    if hasattr(value, "__dataclass_fields__"):
        return sum(nbytes(getattr(value, name)) for name in value.__dataclass_fields__)
    return 0


def v_map(n: int, t_final: float, chunk: int, max_jumps: int) -> dict:
    V = np.linspace(0.2, 8.0, n)
    options = dict(tau=0.0, t_final=t_final, chunk=chunk, max_jumps=max_jumps, progress=False)
    # one chunk of the map's sweep (the same compiled program): compiles it, and its host bytes a lane
    lanes, first = timed(pj.sweep, V=V[:chunk], grid="pairs", window=(0.5, 1.0), **options)
    smap, run = timed(pj.stick_slip_map, V=V, starts=("paper",), **options)
    return row(f"V-map, {n} lanes", n, chunk, first, run, smap, int(smap.stick_slip.sum()), nbytes(lanes) / lanes.V.size)


def p3(n_tau: int, chunk: int, t_final: float = 3.0) -> dict:
    V, tau = p3_grid(n_tau)
    options = dict(V=V, tau=tau, grid="pairs", t_final=t_final, save_dt=P3_SAVE_DT, chunk=chunk, progress=False)
    _, first = timed(pj.sweep, **options)
    result, run = timed(pj.sweep, **options)
    stick_slip = int((result.events > 0).sum())
    return row(f"P3, {V.size} lanes", V.size, chunk, first, run, result, stick_slip, nbytes(result) / V.size)


def row(case, n, chunk, first, run, result, stick_slip, sweep_bytes_per_lane) -> dict:
    """A row of the table: ``result`` the map or the sweep (its completed lanes and host bytes a lane)."""
    return {
        "case": case,
        "lanes": n,
        "chunk": min(chunk, n),
        "first_s": first,
        "run_s": run,
        "lanes_per_s": n / run,
        "completed": int(result.completed.sum()),
        "stick_slip": stick_slip,
        "bytes_per_lane": nbytes(result) / n,
        "sweep_bytes_per_lane": sweep_bytes_per_lane,
        "rss_mib": peak_rss_mib(),
        "device_mib": device_peak_mib(),
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| case | chunk | first call [s] | run [s] | lanes/s | completed | stick-slip | host bytes/lane: sweep, map "
        "| peak RSS [MiB] | device peak [MiB] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['chunk']} | {r['first_s']:.3g} | {r['run_s']:.3g} | {r['lanes_per_s']:.4g} | "
            f"{r['completed']} | {r['stick_slip']} | {r['sweep_bytes_per_lane']:.0f}, {r['bytes_per_lane']:.0f} | "
            f"{r['rss_mib']:.0f} | {r['device_mib']:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--smoke", action="store_true", help="CPU-sized: V-map 16 and 64 lanes over 0.1 s, P3 8 lanes over 0.3 s"
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=None, help="V-map lanes (default 1e4 1e5 1e6)")
    parser.add_argument("--t-final", type=float, default=None, help="the V-map's end time [s] (default 0.3)")
    parser.add_argument("--chunk", type=int, default=None, help="lanes per compiled chunk")
    parser.add_argument("--max-jumps", type=int, default=64, help="jumps each V-map lane keeps (default 64)")
    parser.add_argument("--no-p3", action="store_true", help="leave out the P3 batch")
    parser.add_argument("--out", type=Path, default=None, help="the table's file")
    args = parser.parse_args(argv)
    gpu = jax.devices()[0].platform != "cpu"
    sizes = args.sizes or ([16, 64] if args.smoke else [10_000, 100_000, 1_000_000])
    t_final = args.t_final or (0.1 if args.smoke else 0.3)
    chunk = args.chunk or (16 if args.smoke else 10_000 if gpu else 512)
    n_tau, p3_t_final = (2, 0.3) if args.smoke else (256, 3.0)
    rows = []
    for n in sizes:
        rows.append(v_map(n, t_final, min(chunk, n), args.max_jumps))
        print(rows[-1], flush=True)
    if not args.no_p3:
        rows.append(p3(n_tau, 1024 if gpu else 256, p3_t_final))
        print(rows[-1], flush=True)
    load = load_average()
    text = "\n".join([
        "# Sweeps on one device: the V-map at many lanes, P3 at 1024",
        "",
        f"Device: {device_name()}; jax {jax.__version__}, {platform.machine()}; load {load:.1f} at the end. "
        f"V-map: tau = 0, the paper's start, [0, {t_final:g}] s, statistics after {t_final / 2:g} s, "
        f"{args.max_jumps} jumps kept a lane. P3: 4 V x {n_tau} tau, [0, {p3_t_final:g}] s, v saved every "
        f"{P3_SAVE_DT:g} s. 'first call' includes the compilation; 'run' is a second call (the V-map compiled on one "
        "chunk first).",
        "",
        table(rows),
        "",
    ])  # fmt: skip
    out = args.out or RESULTS / ("gpu_sweeps_smoke.md" if args.smoke else "gpu_sweeps.md")
    write_result(out, text)
    print(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
