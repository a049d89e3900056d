"""Bytes a sweep lane returns: the ring buffer and the loop's cycle statistics against the old whole record.

For a τ = 0 sweep chunk (``peeljax.sweeps.engine.run_batch``, the default error control and
fold events), the bytes of every array the compiled chunk returns, per lane, from the output
shapes (``jax.eval_shape``: exact, nothing runs):

* ``ring``: the sweep's lanes as they are (the last ``max_jumps`` = 64 jumps in a ring buffer,
  the window's cycle statistics accumulated in the loop);
* ``whole record``: each lane's whole record of 2048 slots (the sweep's record before, with which
  a lane stopped when it filled), no statistics.

    python benchmarks/lane_bytes.py        # writes results/lane_bytes.md
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import peeljax as pj
from peeljax.sweeps import engine
from peeljax.sweeps.integrators import DEFAULT_SWEEP_MAX_JUMPS, sweep_plan

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import write_result  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
LANES = 256


def output_bytes(integrator, lanes: int = LANES) -> dict[str, float]:
    """Bytes per lane of each part of the chunk's output (jumps, cycle statistics, the rest)."""
    V = jnp.linspace(0.2, 8.0, lanes)
    shapes = jax.eval_shape(
        lambda V: engine.run_batch(
            pj.PeelingModel(), integrator, V, jnp.zeros(lanes), {}, jnp.asarray(3.0), jnp.asarray([0.5, 1.0]), None,
            None, 1, None, True, "paper",
        ),
        V,
    )  # fmt: skip

    def size(tree) -> float:
        return sum(np.prod(leaf.shape) * leaf.dtype.itemsize for leaf in jax.tree_util.tree_leaves(tree)) / lanes

    parts = {"jumps": size(shapes.jumps), "cycles": size(shapes.cycles)}
    parts["summaries"] = size(dataclasses.replace(shapes, jumps=None, cycles=None))
    parts["total"] = sum(parts.values())
    return parts


def main() -> None:
    plan = sweep_plan(None, 0.0, None, 3.0, None, None, None, None, None, None, dae=True)
    ring = plan.integrator
    whole = dataclasses.replace(ring, events=dataclasses.replace(ring.events, max_jumps=2048, ring=False))
    before = output_bytes(whole)
    before["cycles"] = 0.0  # the old lanes accumulated none (the engine now adds them to any record)
    before["total"] = before["jumps"] + before["summaries"]
    rows = [
        (f"ring of {DEFAULT_SWEEP_MAX_JUMPS} + cycle statistics (now)", output_bytes(ring)),
        ("whole record of 2048 slots, no statistics (before)", before),
    ]
    lines = [
        "| lane keeps | jump slots [B] | cycle statistics [B] | summaries [B] | total [B/lane] |",
        "|---|---|---|---|---|",
        *(
            f"| {name} | {p['jumps']:.0f} | {p['cycles']:.0f} | {p['summaries']:.0f} | {p['total']:.0f} |"
            for name, p in rows
        ),
    ]
    text = "\n".join([
        "# Bytes a sweep lane returns (tau = 0, error control, fold events)",
        "",
        f"Per lane, from the output shapes of a {LANES}-lane chunk (jax.eval_shape, jax {jax.__version__}); the "
        "jump slots hold t, up, v_before, v_after, G, F and the count.",
        "",
        *lines,
        "",
    ])  # fmt: skip
    out = write_result(RESULTS / "lane_bytes.md", text)
    print(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
