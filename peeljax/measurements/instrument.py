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

The same draws say how a record's statistics scatter (:func:`record_covariance`): a record of
a periodic attractor is a window of it, and where in the period the window falls moves its
means far more than its cycles' spread over √n says — that treats the slips of one period, which
differ by design, as independent. Measured on records of 4 s at 5 kHz from φ with c1 × 1.05,
over 24 starts: F_mean's standard deviation 0.14 N at V = 1.1 m/s (the draws: 0.13; the
record's own standard error of the mean 2.6), 1.5 N at 2.4 (the draws 1.9, the record 5.3).
A records fit whitens each row by that covariance (a synthetic likelihood, Wood 2010).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..model import PeelingModel
from ..orbits.section import state_after_slip
from ..simulate import simulate
from .statistics import MIN_DROP_NOISE, STATISTICS, record_statistics

__all__ = ["REPLICATES", "Instrument", "InstrumentBias", "instrument_bias", "orbit_force", "record_covariance",
           "recorded_statistics"]

REPLICATES = 64  # draws of sampling phase and noise: their mean is the model's, their covariance a record's
SD_FLOOR = 1e-6  # this fraction of a statistic is added to its standard deviation over the draws in quadrature
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


def _recorded_draws(t_period, F_period, period: float, instrument: Instrument, seed: int,
                    replicates: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`peeljax.measurements.record_statistics` of ``replicates`` records of the periodic F
    as ``instrument`` takes them (random phase, its noise): their statistics (replicates, 5),
    NaN where a draw lacks one, and the slips each found (replicates,)."""
    rng = np.random.default_rng(seed)
    n = max(int(math.floor(instrument.duration / instrument.dt)) + 1, 3)
    draws, slips = np.full((replicates, len(STATISTICS)), np.nan), np.zeros(replicates)
    for r in range(replicates):
        t = rng.uniform(0.0, period) + instrument.dt * np.arange(n)
        F = np.interp(np.mod(t, period), t_period, F_period)
        if instrument.noise > 0:
            F = F + instrument.noise * rng.standard_normal(n)
        stats = instrument.statistics(t - t[0], F)
        draws[r] = [stats.get(s, math.nan) for s in STATISTICS]
        slips[r] = stats["slips"]
    return np.where(np.isfinite(draws), draws, np.nan), slips


def recorded_statistics(t_period, F_period, period: float, instrument: Instrument, *, seed: int = 0,
                        replicates: int = REPLICATES, spread: bool = False):  # fmt: skip
    """The mean over ``replicates`` draws of :func:`peeljax.measurements.record_statistics` of the periodic
    F (one period given densely) as ``instrument`` records it (module docstring); NaN for a
    statistic no draw produced. ``spread``: also the standard error of each mean (the draws'
    standard deviation / √replicates)."""
    draws, _ = _recorded_draws(t_period, F_period, period, instrument, seed, replicates)
    means, errors = _means(draws)
    if not spread:
        return means
    return means, errors


def _means(draws: np.ndarray) -> tuple[dict, dict]:
    """Each statistic's mean over the draws where it was produced, and its standard error."""
    means, errors = {}, {}
    for k, s in enumerate(STATISTICS):
        v = draws[:, k][np.isfinite(draws[:, k])]
        means[s] = float(np.mean(v)) if v.size else math.nan
        errors[s] = float(np.std(v, ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan
    return means, errors


def record_covariance(draws: np.ndarray) -> np.ndarray:
    """The covariance (5, 5) of one record's statistics over the phases and noises of
    ``draws`` (:func:`_recorded_draws`), scaled so that its inverse is unbiased (Hartlap et al.
    2007: × (R − 1)/(R − p − 2), R draws of p statistics) and for the Monte Carlo error of the
    model's mean (× (1 + 1/R)): the variance of a record minus the model's mean at the truth.
    Rows and columns of a statistic missing from more than a quarter of the draws are NaN; with
    too few complete draws for a covariance, the variances alone (no correlation). ``SD_FLOOR``
    of each statistic is added in quadrature (a noise-free record of a whole number of periods
    has no scatter)."""
    finite = np.isfinite(draws)
    usable = finite.mean(axis=0) >= 0.75
    cov = np.full((draws.shape[1],) * 2, np.nan)
    idx = np.flatnonzero(usable)
    if idx.size == 0:
        return cov
    complete = draws[np.all(finite[:, idx], axis=1)][:, idx]
    R, p = complete.shape[0], idx.size
    floor = (SD_FLOOR * np.abs(np.nanmean(draws[:, idx], axis=0))) ** 2
    if R >= 2 * p + 4:
        block = np.cov(complete, rowvar=False).reshape(p, p) * (R - 1) / (R - p - 2)
    else:
        R = int(np.min(finite[:, idx].sum(axis=0)))
        block = np.diag([np.var(draws[finite[:, k], k], ddof=1) for k in idx]) if R > 1 else np.diag(floor)
    block = (block + np.diag(floor)) * (1.0 + 1.0 / max(R, 1))
    cov[np.ix_(idx, idx)] = block
    return cov


class InstrumentBias(NamedTuple):
    """What an instrument adds to an orbit's exact statistics, and how a record of it scatters.

    Attributes:
        bias: :func:`recorded_statistics` minus the orbit's ``statistics`` (5,), 0 where not produced.
        error: the Monte Carlo standard error of ``bias`` (5,), 0 where not produced.
        covariance: :func:`record_covariance` (5, 5): one record's statistics about the model's mean.
        found: the fraction of the orbit's slips the instrument's records find (their mean
            number of slips over k·duration/T): below 1 its noise hides the small ones.
    """

    bias: np.ndarray
    error: np.ndarray
    covariance: np.ndarray
    found: float


def instrument_bias(model: PeelingModel, V: float, orbit: dict, instrument: Instrument, *,
                    seed: int = 0) -> InstrumentBias:  # fmt: skip
    """What ``instrument`` adds to each of the orbit's exact statistics, and the covariance of a
    record's statistics over its phase and noise (:class:`InstrumentBias`)."""
    period = float(orbit["period"])
    t, F = orbit_force(model, V, orbit["section"], period)
    draws, slips = _recorded_draws(t, F, period, instrument, seed, REPLICATES)
    recorded, errors = _means(draws)
    exact = np.asarray(orbit["statistics"], float)
    bias = np.array([recorded[s] for s in STATISTICS]) - exact
    error = np.array([errors[s] for s in STATISTICS])
    found = float(np.mean(slips)) / (int(orbit["slips"]) * instrument.duration / period)
    return InstrumentBias(np.where(np.isfinite(bias), bias, 0.0), np.where(np.isfinite(error), error, 0.0),
                          record_covariance(draws), found)  # fmt: skip
