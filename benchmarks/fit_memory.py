"""The memory a point-by-point fit's compiled program takes per sample of its records.

``peeljax.fit.fit_adhesion`` compiles one program that evaluates the model at every sample time
of the observations, forward and for the gradient, so its memory grows with the samples it is
given. This script runs ``fit_adhesion(steps=1, free=["c1"])`` on a record of n samples of v over
[0, 0.15] s (V = 1.1 m/s, τ = 0.01 s, error control), each n in a fresh process, and reports the
process's peak resident memory: the slope between the sizes is the bytes per sample behind
``peeljax.fit.records.FIT_BYTES_PER_SAMPLE`` and ``MAX_FIT_SAMPLES`` (the budget a record must fit,
else ``peeljax fit --data`` refuses it and offers ``--decimate``). Written to
``benchmarks/results/fit_memory.md``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_model, write_result  # noqa: E402

RESULT = Path(__file__).resolve().parent / "results" / "fit_memory.md"


def one(n: int) -> None:
    """In this process: the fit on n samples; prints ``n peak_MB seconds``."""
    import numpy as np

    import peeljax as pj
    from peeljax.fit import Observation, fit_adhesion

    t = np.linspace(0.0, 0.15, n)
    sol = pj.simulate(V=1.1, tau=0.01, t_final=0.15, ts=t)
    observation = Observation(V=1.1, t=np.asarray(sol.ts), v=np.asarray(sol.v))
    begin = time.perf_counter()
    fit_adhesion([observation], tau=0.01, steps=1, progress=False, free=["c1"])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"{observation.t.size} {peak / 1e6:.1f} {time.perf_counter() - begin:.1f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[2000, 32000])
    parser.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--no-write", dest="write", action="store_false")
    args = parser.parse_args(argv)
    if args.one is not None:
        one(args.one)
        return 0
    rows = []
    for n in args.sizes:
        load = os.getloadavg()[0]
        done = subprocess.run([sys.executable, __file__, "--one", str(n)], capture_output=True, text=True, check=True)
        samples, peak, seconds = done.stdout.split()[-3:]
        rows.append((int(samples), float(peak), float(seconds), load))
    (n0, p0, *_), (n1, p1, *_) = rows[0], rows[-1]
    slope = (p1 - p0) * 1e6 / (n1 - n0)
    lines = [
        f"CPU: {cpu_model()}, {os.cpu_count()} cores (shared: the load is the 1-minute load average at the start)",
        "",
        "| samples | peak resident memory [MB] | fit (compile + 1 step) [s] | load |",
        "|---:|---:|---:|---:|",
        *(f"| {n} | {peak:.0f} | {seconds:.0f} | {load:.1f} |" for n, peak, seconds, load in rows),
        "",
        f"Slope: {slope / 1e3:.0f} kB per sample ({n0} to {n1} samples).",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_result(RESULT, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
