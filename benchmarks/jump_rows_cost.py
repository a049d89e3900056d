"""The cost of keeping both sides of every jump in a run's rows (``ErrorControl(save_jumps=...)``).

V = 1.1 m/s, τ = 0 (the DAE with jumps, 66 in 1 s), ``simulate``'s integrator, the same compiled
run with ``save_jumps`` True and False, round-robin in one process (medians of ``--repeats``
calls after compiling), on the accepted steps and with dense output at 1001 times. The rows a
dense output keeps for ``max_jumps`` jumps are evaluated once at the end (J_t and the DAE's v at
each row): ``--max-jumps`` shows that part of the cost.

    python benchmarks/jump_rows_cost.py [--repeats 5] [--max-jumps 10000]

Measured (2 shared cores, load 8–9, medians of 9): accepted steps 59.5 ms with the rows, 59.7 ms
without (1.00); dense output 32.1 ms against 22.5 ms (1.43) with the 20 000 rows of
max_jumps = 10 000, 20.2 against 19.7 ms (1.02) with max_jumps = 100. Writing the state before
and the one after a jump with two updates of each output array per step made XLA copy the
arrays at every step: 1105 ms against 84 ms; one two-row update keeps it in place.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import jax
import numpy as np

from peeljax._arrays import float_array
from peeljax.integrators.select import integrator_for, resolve_max_steps
from peeljax.simulate import _prepare, _run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--max-jumps", dest="max_jumps", type=int, default=10_000)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()}")
    ode, y0 = _prepare(None, 1.1, 0.0, None, None, allow_dae=True)
    t_final = float_array(1.0)
    for label, ts in (("accepted steps", None), ("dense output, 1001 times", np.linspace(0.0, 1.0, 1001))):
        base = integrator_for(None, t_final=1.0, fold="jump", max_jumps=args.max_jumps, dae=True,
                              max_steps=resolve_max_steps(None, keeps_steps=ts is None))  # fmt: skip
        variants = {flag: dataclasses.replace(base, save_jumps=flag) for flag in (True, False)}
        for integrator in variants.values():  # compile
            jax.block_until_ready(_run(integrator, ode, y0, t_final, ts))
        times = {flag: [] for flag in variants}
        for _ in range(args.repeats):
            for flag, integrator in variants.items():
                start = time.perf_counter()
                jax.block_until_ready(_run(integrator, ode, y0, t_final, ts))
                times[flag].append(time.perf_counter() - start)
        with_rows, without = (statistics.median(times[flag]) for flag in (True, False))
        print(f"{label}: with the jump rows {with_rows * 1e3:.1f} ms, without {without * 1e3:.1f} ms, "
              f"ratio {with_rows / without:.3f}")  # fmt: skip
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
