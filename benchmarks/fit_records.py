"""Force records fitted as the instrument saw them, and point by point (docs/fitting.md, "Records
of every kind").

* ``--instrument``: records made from φ with c1 × 1.05 (τ = 0, 4 s from rest) at V = 1.1, 1.6,
  2.4 m/s, sampled at 1, 2, 5, 10 kHz, with and without white noise of 0.5 % of F; their
  statistics over [2, 4] s (found on F averaged over 0.6 ms, ``fit_records``' rule) against the
  orbit's exact statistics and against the model's record (:mod:`peeljax.measurements.instrument`).
* ``--fit RATE``: the three records at RATE kHz with 0.5 % noise, fitted for c1 from the paper's
  400 by :func:`peeljax.fit.fit_records` (the truth 420: within 2 standard errors and 1 %?);
  ``--draws N``: N draws of them, the errors' mean and spread and the coverage. Each draw has
  its own noise and its records their own start (uniform in [0, 1] s after draw 0's), as
  records taken on another day would: where in the attractor's period a window falls moves its
  statistics as much as the noise does.
* ``--points N``: a 1 s record at V = 1.1, τ = 0.01 (the transient from rest settling to steady
  peeling, 1 kHz) made with c1 = 420, N draws of 0.5 % noise, each fitted point by point from
  400: the coverage of the 95 % intervals.

    python benchmarks/fit_records.py --instrument | --fit 5 [--draws 10] | --points 40
"""

from __future__ import annotations

import argparse

import numpy as np

import peeljax as pj
from peeljax.fit import fit_records, record_statistics
from peeljax.measurements.instrument import Instrument, orbit_force, recorded_statistics
from peeljax.fit.records_fit import NOISE_FACTOR, SMOOTH
from peeljax.measurements.stick_slip_table import STATISTICS
from peeljax.fit.table import attractor_statistics
from peeljax.measurements.observations import Observation
from machine import timed

TRUTH = pj.AdhesionLaw(c1=420.0)
V = (1.1, 1.6, 2.4)


def record(V_i: float, rate: float, noise: float, seed: int, t_final: float = 4.0, tau: float = 0.0, start: float = 0.0):
    """(t, F) of a run from rest with φ = TRUTH, sampled at ``rate`` Hz over [start, start +
    t_final] (its times from 0), multiplicative noise."""
    model = pj.PeelingModel(adhesion=TRUTH)
    ts = start + np.arange(int(round(t_final * rate))) / rate
    sol = pj.simulate(model, V=V_i, tau=tau, t_final=start + t_final, ts=ts, rtol=1e-9, atol=1e-11)
    rows = ~np.asarray(sol.before_jump) & ~np.asarray(sol.after_jump) & np.asarray(sol.valid)  # the samples, not the jumps
    ys = np.asarray(sol.ys)[rows]
    F = np.asarray(model.tension(ys[:, 2], ys[:, 0]))
    return np.asarray(sol.ts)[rows] - start, F * (1 + noise * np.random.default_rng(seed).standard_normal(F.size))


def instrument() -> None:
    point, rows, _ = attractor_statistics(TRUTH, V, names=("c1",))
    model = pj.PeelingModel(adhesion=TRUTH)
    print("| V | rate | noise | slips found | " + " | ".join(f"{s}: record/exact, record/model" for s in STATISTICS[1:]) + " |")
    for i, V_i in enumerate(V):
        orbit = point.orbits[i]
        t_p, F_p = orbit_force(model, V_i, orbit["section"], float(orbit["period"]))
        for rate in (1e3, 2e3, 5e3, 1e4):
            for noise in (0.0, 0.005):
                t, F = record(V_i, rate, noise, seed=int(rate) + int(1e3 * noise))
                rec = record_statistics(t, F, transient=2.0, smooth=SMOOTH, noise_factor=NOISE_FACTOR)
                inst = Instrument.of_record(t, F, transient=2.0, smooth=SMOOTH, noise_factor=NOISE_FACTOR)
                seen = recorded_statistics(t_p, F_p, float(orbit["period"]), inst)
                cells = []
                for j, s in enumerate(STATISTICS[1:], start=1):
                    if s not in rec:
                        cells.append("—")
                        continue
                    cells.append(f"{rec[s] / point.values[i, j] - 1:+.2%}, {rec[s] / seen[s] - 1:+.2%}")
                print(f"| {V_i:g} | {rate / 1e3:g} kHz | {noise:.1%} | {rec['slips']} | " + " | ".join(cells) + " |", flush=True)


def fit(rate_khz: float, draws: int = 1) -> None:
    """The three records at ``rate_khz`` fitted for c1; with ``draws`` > 1, that many noise draws
    (draw 0 the record of the results file) and their summary: bias, spread, coverage."""
    z, covered, walls = [], [], []
    for draw in range(draws):
        observations = []
        # Each draw's records start at another time (draw 0 from rest): where in the attractor's
        # period a record's window falls moves its statistics as much as its noise does.
        start = 0.0 if draw == 0 else float(np.random.default_rng(draw).uniform(0.0, 1.0))
        for V_i in V:
            t, F = record(V_i, 1e3 * rate_khz, 0.005, seed=int(100 * V_i) + 1000 * draw, start=start)
            observations.append(Observation(V=V_i, t=t, v=None, F=F))
        result, wall = timed(fit_records, observations, free=("c1",))
        walls.append(wall)
        (value,), (se,) = result.uncertainty.values, result.uncertainty.standard_errors
        if draws == 1:
            print(result.summary())
        z.append((value - 420) / se)
        covered.append(result.covers({"c1": 420.0})["c1"])
        print(f"\n{rate_khz:g} kHz{f' draw {draw}' if draws > 1 else ''}: c1 = {value:.2f} ± {se:.2f} (truth 420: "
              f"{z[-1]:+.2f} SE, {value / 420 - 1:+.2%}); 95 % set {result.intervals()['c1']}; chi2/dof "
              f"{result.chi2_dof:.2f}; {walls[-1]:.0f} s", flush=True)  # fmt: skip
    if draws > 1:
        print(f"\n{rate_khz:g} kHz, {draws} draws: error / SE mean {np.mean(z):+.2f}, spread {np.std(z):.2f}, "
              f"largest {np.max(np.abs(z)):.2f}; covered {sum(covered)} of {draws}; a fit {np.median(walls):.0f} s "
              f"(median; the first {walls[0]:.0f} s)")  # fmt: skip


def points(draws: int) -> None:
    t, F = record(1.1, 1e3, 0.0, seed=0, t_final=1.0, tau=0.01)
    rng = np.random.default_rng(1)
    covered, z, walls = [], [], []
    for _ in range(draws):
        F_i = F * (1 + 0.005 * rng.standard_normal(F.size))
        result, wall = timed(fit_records, [Observation(V=1.1, t=t, v=None, F=F_i)], free=("c1",), tau=0.01)
        walls.append(wall)
        (lo, hi), = result.intervals()["c1"]
        covered.append(lo <= 420.0 <= hi)
        z.append((result.uncertainty.values[0] - 420.0) / result.uncertainty.standard_errors[0])
    print(f"{draws} draws: coverage {np.mean(covered):.1%}; error / SE mean {np.mean(z):+.2f}, spread {np.std(z):.2f}; "
          f"a fit {np.median(walls[1:] or walls):.2f} s after the first ({walls[0]:.0f} s with compilation)")  # fmt: skip


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--instrument", action="store_true")
    group.add_argument("--fit", type=float, metavar="KHZ")
    group.add_argument("--points", type=int, metavar="N")
    parser.add_argument("--draws", type=int, default=1, help="--fit: noise draws of the three records")
    args = parser.parse_args(argv)
    if args.instrument:
        instrument()
    elif args.fit is not None:
        fit(args.fit, args.draws)
    else:
        points(args.points)


if __name__ == "__main__":
    main()
