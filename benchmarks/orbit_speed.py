"""One periodic stick-slip orbit after compilation, beside the run that found its repeat.

V = 1.1 m/s, τ = 0, the paper's φ and start. The run is ``pj.simulate(V=1.1, tau=0, t_final=3)``
(the 3 s run whose second half shows the repeat: 8 stick → slip events, T ≈ 0.218 s); the orbit
is ``pj.periodic_orbit(V=1.1, start=run)``: the repeat read from the run, φ's folds checked,
then Newton on the return map from the state at the run's last slip (each iteration two
forward-mode passes through one period, one per section direction), then the check that k is
the orbit's least number of slips (a shooting of at most two Newton iterations per divisor of
k). Also timed: its two parts alone, the compiled shooting
and the host-side reading of the run's repeat. Each is called once first (compilation, timed
apart), then the four are called round-robin ``--repeats`` times; medians and minima, with the
load average of the machine beside them (the timings are taken on shared cores).

    python benchmarks/orbit_speed.py [--repeats 25]   # writes results/orbit_speed.md
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import peeljax as pj
from peeljax.orbits.api import compiled_orbit, orbit_shooting, start_from_run

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_model, write_result  # noqa: E402

V = 1.1
T_RUN = 3.0


def _run():
    return jax.block_until_ready(pj.simulate(V=V, tau=0, t_final=T_RUN))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=25, help="round-robin calls of each after compilation (default 25)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "orbit_speed.md"))
    args = parser.parse_args(argv)
    load_before = os.getloadavg()

    began = time.perf_counter()
    run = _run()
    first_run = time.perf_counter() - began
    s0, k, T = start_from_run(run)
    shooting = orbit_shooting()
    model = pj.PeelingModel()
    shoot = lambda: jax.block_until_ready(  # noqa: E731  (the compiled program alone, as periodic_orbit calls it)
        compiled_orbit(shooting, model, jnp.asarray(V), jnp.asarray(s0), jnp.asarray(k, jnp.int32), jnp.asarray(3.0 * T))
    )
    orbit_call = lambda: jax.block_until_ready(pj.periodic_orbit(V=V, start=run))  # noqa: E731
    began = time.perf_counter()
    orbit = orbit_call()
    first_orbit = time.perf_counter() - began
    assert orbit.status_name == "converged", orbit.reason
    shoot()  # the same program as orbit_call's (a cache hit)

    repeat = lambda: start_from_run(run)  # noqa: E731  (host side: the run's repeat and its last slip)
    times = {"run": [], "orbit": [], "shooting": [], "repeat": []}
    for _ in range(args.repeats):
        for name, call in (("run", _run), ("orbit", orbit_call), ("shooting", shoot), ("repeat", repeat)):
            began = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - began)
    load_after = os.getloadavg()
    med = {name: statistics.median(values) for name, values in times.items()}
    spread = {name: (min(values), max(values)) for name, values in times.items()}
    iterations, steps = int(orbit.iterations), int(orbit.steps)

    rows = [
        (f"the 3 s run (`pj.simulate(V=1.1, tau=0, t_final=3)`, {int(run.stats['jumps'])} jumps)", "run", first_run),
        ("one orbit from its end (`pj.periodic_orbit(V=1.1, start=run)`)", "orbit", first_orbit),
        ("  its compiled shooting alone (Newton on the return map)", "shooting", None),
        ("  its reading of the run's repeat alone (`start_from_run`, numpy)", "repeat", None),
    ]
    lines = [
        f"One periodic orbit at V = {V} m/s (τ = 0, the paper's φ): {int(orbit.slips)} stick → slip events per period, "
        f"T = {float(orbit.period):.7f} s, {iterations} Newton iterations (each two forward-mode passes through one "
        f"period, one per section direction: {steps} step attempts at rtol 1e-8), residual "
        f"{float(orbit.residual):.1e}. The orbit's time beyond its two parts timed alone is mostly the "
        f"check that k is its least number of slips (a shooting of at most two Newton iterations per "
        f"divisor of k).",
        "",
        f"{args.repeats} round-robin calls of each after compilation, one process; machine: {cpu_model()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}, JAX {jax.__version__}, backend "
        f"{jax.default_backend()}; load average {load_before[0]:.1f} before, {load_after[0]:.1f} after (shared cores).",
        "",
        "| what | median | min–max | first call (compiles) |",
        "|---|---:|---:|---:|",
    ]
    for label, name, first in rows:
        lo, hi = spread[name]
        first_text = "–" if first is None else f"{first:.1f} s"
        lines.append(f"| {label} | {1e3 * med[name]:.1f} ms | {1e3 * lo:.1f}–{1e3 * hi:.1f} ms | {first_text} |")
    lines += [
        "",
        f"One orbit / the 3 s run: {med['orbit'] / med['run']:.2f}× (medians), "
        f"{spread['orbit'][0] / spread['run'][0]:.2f}× (minima: the least disturbed calls on shared cores).",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_result(args.out, text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
