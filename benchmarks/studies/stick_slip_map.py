"""Where does the homogenized ODE show stick-slip that the error-controlled α-method completes
when every run stops at its first fold (``fold="stop"``, the paper's behaviour)?

Carried through the folds (``fold="jump"``, the default since runs jump at the folds of φ)
the runs keep stick-slipping: see ``peeljax.stick_slip_map`` and ``docs/theory.md``. A sweep over V ∈ [0.3, 10] m/s × τ ∈ [1e-4, 0.5] s (24 × 24 log-spaced, t ∈ [0, 3] s, the
paper's φ and initial data, rtol 1e-6): for each (V, τ), completed or where it stopped, and
the stick-slip events (upward crossings of v̂, the maximum of φ) in the window [1.5, 3] s.
Prints the counts and every completed run with events.

    python benchmarks/studies/stick_slip_map.py      # ~10 s on 2 cores

The table goes to ``benchmarks/studies/results/stick_slip_map.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

import peeljax as pj

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine
from machine import write_result  # noqa: E402


def main(argv=None) -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)  # --help; no options
    Vs, taus = np.geomspace(0.3, 10.0, 24), np.geomspace(1e-4, 0.5, 24)
    r = pj.sweep(
        V=Vs, tau=taus, t_final=3.0, window=(0.5, 1.0), progress=False, chunk=Vs.size * taus.size, fold="stop"
    )
    swinging = r.completed & (r.events > 0)
    lines = [
        "# Stick-slip that completes, error control (rtol 1e-6)",
        "",
        f"jax {jax.__version__}, {len(jax.devices())} {jax.devices()[0].platform} "
        "device(s). V ∈ [0.3, 10] m/s × τ ∈ [1e-4, 0.5] s, 24 × 24 log-spaced, t ∈ [0, 3] s, events in [1.5, 3] s.",
        "",
        f"- completed: {int(r.completed.sum())} of {len(r)}; stopped: "
        + ", ".join(f"{reason} {r.reasons.count(reason)}" for reason in sorted(set(r.reasons)) if reason != "completed"),
        f"- completed with at least one event: {int(swinging.sum())}; with ≥ 3 events: "
        f"{int(np.sum(r.completed & (r.events >= 3)))}",
        "- largest τ that stopped, by V: "
        + ", ".join(
            f"{V:.3g}: {r.tau[(r.V == V) & ~r.completed].max():.2g}" for V in Vs[::4] if np.any((r.V == V) & ~r.completed)
        ),
        "",
        "| V | τ | events | v_min | v_max | v_std | v̂ |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]  # fmt: skip
    for i in np.flatnonzero(swinging):
        lines.append(
            f"| {r.V[i]:.3g} | {r.tau[i]:.3g} | {r.events[i]} | {r.v_min[i]:.3g} | {r.v_max[i]:.3g} | "
            f"{r.v_std[i]:.3g} | {r.v_slip[i]:.3g} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    path = Path(__file__).resolve().parent / "results" / "stick_slip_map.md"
    write_result(path, text)


if __name__ == "__main__":
    main()
