"""The least resolvable τ (τ*) with error control beside uniform meshes of shrinking step.

For V = 1.1, 2, 4 m/s (t ∈ [0, 3] s, τ searched in [1e-4, 1] to 5 %), ``peeljax.least_tau``
on the error-controlled α-method at several tolerances and on uniform meshes h = 1/82 … 1/1312.
It prints τ*, where the run just below τ* stopped, and the search's wall time.

    python benchmarks/studies/least_tau_mesh.py        # ~1 min on 2 cores

The table goes to ``benchmarks/studies/results/least_tau_mesh.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax

import peeljax as pj

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine
from machine import write_result  # noqa: E402

VELOCITIES = (1.1, 2.0, 4.0)
SETTINGS = (
    ("error control, rtol 1e-4", {"rtol": 1e-4, "atol": 1e-7}),
    ("error control, rtol 1e-6 (default)", {}),
    ("error control, rtol 1e-8", {"rtol": 1e-8, "atol": 1e-11}),
    ("uniform mesh h = 1/82", {"dt": 1 / 82}),
    ("uniform mesh h = 1/328", {"dt": 1 / 328}),
    ("uniform mesh h = 1/1312", {"dt": 1 / 1312}),
)


def main(argv=None) -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)  # --help; no options
    lines = [
        "# τ* with error control and on uniform meshes",
        "",
        f"jax {jax.__version__}, {len(jax.devices())} "
        f"{jax.devices()[0].platform} device(s). τ searched in [1e-4, 1] to tau_rtol = 0.05, t ∈ [0, 3] s.",
        "",
        "| engine | " + " | ".join(f"τ* at V = {V:g}" for V in VELOCITIES) + " | "
        + " | ".join(f"stop below τ* at V = {V:g} [s]" for V in VELOCITIES) + " | search s |",
        "|---|" + "---:|" * (2 * len(VELOCITIES) + 1),
    ]  # fmt: skip
    for name, options in SETTINGS:
        start = time.perf_counter()
        found = pj.least_tau(V=VELOCITIES, **options)
        seconds = time.perf_counter() - start
        taus = " | ".join(f"{t:.3g}" + ("" if ok else " (not bracketed)") for t, ok in zip(found.tau_star, found.found))
        stops = " | ".join(f"{t:.3g}" for t in found.t_stop_below)
        lines.append(f"| {name} | {taus} | {stops} | {seconds:.1f} |")
        print(lines[-1], flush=True)
    lines += [
        "",
        "Search s includes compilation (one program per engine and batch shape).",
    ]
    path = Path(__file__).resolve().parent / "results" / "least_tau_mesh.md"
    write_result(path, "\n".join(lines) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
