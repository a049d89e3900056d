"""A force record's statistics as its instrument saw them, and the model's as the same instrument would.

A load cell sampled every Δt sees a slip's peak and its duration only at its samples, and with
its noise: measured on the paper's φ with c1 × 1.05 (``docs/fitting.md``), noise-free records at
1, 2, 5, 10 kHz give slip durations 53 %, 27 %, 11 %, 5.6 % longer than the exact ones (the
maximum is the last sample before the slip, the minimum the first after the re-stick: about Δt
in all), F_slip 0.1 % low at 1 kHz; with white noise of 0.5 % of F the detection of slips
(:func:`peeljax.measurements.record_statistics`, drops above 10 × the noise) merges small slips, and
the statistics are of another thing altogether.

So a record is compared with the model's statistics *as a record would show them*
(:func:`recorded_statistics`): the model's F over one period of its orbit, extended
periodically over the record's window, sampled every Δt with a random phase, with white noise of
the record's own level added, and passed through the very function that made the record's
statistics — averaged over ``REPLICATES`` draws of phase and noise (fixed seeds: the same draws
at every θ). What differs from the orbit's exact statistics is the instrument's **bias**
(:func:`instrument_bias`); the fit (:mod:`peeljax.fit.table`) adds it to the orbit's exact
statistics, their derivatives from the implicit function theorem (the bias, O(Δt) and smooth
in θ, is held fixed in the Jacobian and recomputed at each optimum until it settles).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from ..model import PeelingModel
from ..orbits.section import state_after_slip
from ..simulate import simulate
from .statistics import MIN_DROP_NOISE, STATISTICS, record_statistics

__all__ = ["REPLICATES", "Instrument", "instrument_bias", "orbit_force", "recorded_statistics"]

REPLICATES = 32  # draws of sampling phase and noise averaged (their spread / √32 enters σ)
DENSE = 20001  # points of the dense F over one period
_RUN_BOUND = 2.0  # [s]: the dense run's t_final (one compiled run for every period below it)


@dataclasses.dataclass(frozen=True)
class Instrument:
    """How a force record was taken, as read from the record itself.

    Attributes:
        dt: the sampling interval [s] (the median spacing of its times).
        noise: the white-noise level of F [N] (the median absolute deviation of its second
            differences, :func:`peeljax.measurements.record_statistics`'s ``noise``).
        duration: the length of the window its statistics were taken over [s].
        min_drop: the slip threshold used on it [N] (None: the default rule, re-applied to
            each model record as to the record).
        smooth, noise_factor: the smoothing [s] and noise factor of its slip detection
            (:func:`peeljax.measurements.record_statistics`).
    """

    dt: float
    noise: float
    duration: float
    min_drop: float | None = None
    smooth: float = 0.0
    noise_factor: float = MIN_DROP_NOISE

    @classmethod
    def of_record(cls, t, F, *, transient: float = 0.0, min_drop: float | None = None, smooth: float = 0.0,
                  noise_factor: float = MIN_DROP_NOISE) -> Instrument:  # fmt: skip
        t = np.asarray(t, float)
        stats = record_statistics(t, np.asarray(F, float), transient=transient, min_drop=min_drop, smooth=smooth,
                                  noise_factor=noise_factor)  # fmt: skip
        window = stats["window"]
        return cls(dt=float(np.median(np.diff(t))), noise=float(stats["noise"]), duration=float(window[1] - window[0]),
                   min_drop=min_drop, smooth=smooth, noise_factor=noise_factor)  # fmt: skip

    def statistics(self, t, F) -> dict:
        """:func:`peeljax.measurements.record_statistics` as this instrument's records were treated."""
        return record_statistics(t, F, min_drop=self.min_drop, smooth=self.smooth, noise_factor=self.noise_factor)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def orbit_force(model: PeelingModel, V: float, section, period: float, n: int = DENSE) -> tuple[np.ndarray, np.ndarray]:
    """(t, F) over one period [0, T] of the orbit through ``section`` (s = (α, ω) before the
    slip), densely, with both sides of every jump (F is continuous, its slope jumps)."""
    y0 = state_after_slip(model, V, section)
    t_final = _RUN_BOUND if period < _RUN_BOUND else float(period)
    sol = simulate(model, V=float(V), tau=0, y0=y0, t_final=t_final, ts=np.linspace(0.0, period, n), rtol=1e-9,
                   atol=1e-12)  # fmt: skip
    keep = np.asarray(sol.valid) & (np.asarray(sol.ts) <= period)
    t = np.asarray(sol.ts)[keep]
    F = np.asarray(model.tension(jnp.asarray(np.asarray(sol.ys)[keep, 2]), jnp.asarray(np.asarray(sol.ys)[keep, 0])))
    return t, F


def recorded_statistics(t_period, F_period, period: float, instrument: Instrument, *, seed: int = 0,
                        replicates: int = REPLICATES, spread: bool = False):  # fmt: skip
    """The mean over ``replicates`` draws of :func:`peeljax.measurements.record_statistics` of the periodic
    F (one period given densely) as ``instrument`` records it (module docstring); NaN for a
    statistic no draw produced. ``spread``: also the standard error of each mean (the draws'
    standard deviation / √replicates)."""
    rng = np.random.default_rng(seed)
    n = max(int(math.floor(instrument.duration / instrument.dt)) + 1, 3)
    draws = {s: [] for s in STATISTICS}
    for _ in range(replicates):
        t = rng.uniform(0.0, period) + instrument.dt * np.arange(n)
        F = np.interp(np.mod(t, period), t_period, F_period)
        if instrument.noise > 0:
            F = F + instrument.noise * rng.standard_normal(n)
        stats = instrument.statistics(t - t[0], F)
        for s in STATISTICS:
            if s in stats and math.isfinite(stats[s]):
                draws[s].append(stats[s])
    means = {s: float(np.mean(v)) if v else math.nan for s, v in draws.items()}
    if not spread:
        return means
    errors = {s: float(np.std(v, ddof=1) / math.sqrt(len(v))) if len(v) > 1 else math.nan for s, v in draws.items()}
    return means, errors


def instrument_bias(model: PeelingModel, V: float, orbit: dict, instrument: Instrument, *,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """What ``instrument`` adds to each of the orbit's exact statistics (5,): its
    :func:`recorded_statistics` minus the orbit's ``statistics`` (0 where not produced), and the
    Monte Carlo standard error of that (5,)."""
    t, F = orbit_force(model, V, orbit["section"], float(orbit["period"]))
    recorded, errors = recorded_statistics(t, F, float(orbit["period"]), instrument, seed=seed, spread=True)
    exact = np.asarray(orbit["statistics"], float)
    bias = np.array([recorded[s] for s in STATISTICS]) - exact
    error = np.array([errors[s] for s in STATISTICS])
    return np.where(np.isfinite(bias), bias, 0.0), np.where(np.isfinite(error), error, 0.0)
