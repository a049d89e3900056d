"""The stick-slip statistics of a measured force record F(t): the sawtooth's slips and cycles.

Plain NumPy on the host, in float64: :func:`record_statistics` for one record,
:func:`record_cycles` for the per-cycle values that :meth:`StickSlipTable.from_force_records
<peeljax.fit.StickSlipTable.from_force_records>` pools over the records at one V. The slips are
detected as force drops with hysteresis (see :func:`record_statistics` for the definitions and
the default threshold); :mod:`.statistics` computes the same statistics of a simulated run from
its jumps, differentiably.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = ["MIN_DROP_NOISE", "MIN_DROP_RANGE", "record_cycles", "record_statistics", "sample_std"]

MIN_DROP_NOISE = 10.0  # default min_drop: this many times the estimated noise …
MIN_DROP_RANGE = 0.01  # … and at least this fraction of the record's peak-to-peak range


def _noise(F: np.ndarray) -> float:
    """The white noise's standard deviation, estimated from second differences (robust: the
    median absolute deviation, which the few samples of each slip do not move)."""
    if F.size < 3:
        return 0.0
    d2 = np.diff(F, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _extrema(F: np.ndarray, drop: float) -> tuple[np.ndarray, np.ndarray]:
    """Hysteresis extrema: indices of the maxima (each followed by a fall of more than ``drop``
    below it) and of the minima (each followed by a rise of more than ``drop``), alternating.
    The first extremum of the window is left out: the window may have cut its rise or fall.

    These are the samples whose topographic prominence exceeds ``drop`` (``find_peaks`` on F
    and −F: both the rise before and the fall after a maximum exceed ``drop``, which also leaves
    out the first extremum, whose rise the window cut). Of a flat top (or bottom) the first
    sample is taken; of equal maxima with no minimum deeper than ``drop`` between them (a
    quantized record), the first.
    """
    from scipy.signal import find_peaks  # here, not at the top: scipy.signal takes seconds to import

    bound = np.nextafter(drop, np.inf)  # find_peaks keeps prominence >= bound; a swing must exceed drop
    peaks = find_peaks(F, prominence=bound, plateau_size=1)[1]["left_edges"]
    troughs = find_peaks(-F, prominence=bound, plateau_size=1)[1]["left_edges"]
    index = np.concatenate([peaks, troughs])
    is_peak = np.concatenate([np.ones(peaks.size, bool), np.zeros(troughs.size, bool)])
    order = np.argsort(index, kind="stable")
    index, is_peak = index[order], is_peak[order]
    first = np.ones(index.size, bool)  # equal extrema of one kind in a row: one slip, the first
    first[1:] = is_peak[1:] != is_peak[:-1]
    return index[first & is_peak].astype(int), index[first & ~is_peak].astype(int)


def _integral(F: np.ndarray, t: np.ndarray) -> float:
    """∫ F dt by the trapezoid rule."""
    return float(np.sum(0.5 * (F[1:] + F[:-1]) * np.diff(t)))


def sample_std(x: np.ndarray) -> float:
    """The sample standard deviation (ddof = 1); NaN for fewer than 2 values."""
    return float(np.std(x, ddof=1)) if x.size >= 2 else math.nan


def smoothed(t: np.ndarray, F: np.ndarray, smooth: float) -> tuple[np.ndarray, int]:
    """F averaged over a moving window of ``smooth`` seconds (w = round(smooth/Δt) samples, the
    ends held), and w; F itself where w < 2."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    w = int(round(smooth / dt)) if smooth > 0 and dt > 0 else 1
    if w < 2:
        return F, 1
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(F, w, mode="nearest"), w


def record_cycles(t, F, *, transient: float = 0.0, min_drop: float | None = None, smooth: float = 0.0,
                  noise_factor: float = MIN_DROP_NOISE) -> dict:  # fmt: skip
    """The slips and cycles of one record (the definitions: :func:`record_statistics`): a dict
    with the time average ``F_mean`` and ``duration`` of the window, ``cycles`` (name → the
    per-cycle values of each statistic), ``t_slip``, ``t_stick``, ``min_drop``, ``noise`` and
    ``window``."""
    t = np.asarray(t, dtype=np.float64)
    F = np.asarray(F, dtype=np.float64)
    if t.ndim != 1 or t.shape != F.shape:
        raise ValueError(f"t and F must be 1-D arrays of one length, got shapes {t.shape} and {F.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(F))):
        raise ValueError("t and F must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must increase strictly")
    transient = float(transient)
    if not (math.isfinite(transient) and transient >= 0):
        raise ValueError(f"transient must be a finite number >= 0, got {transient!r}")
    window = t >= transient
    if window.sum() < 2:
        raise ValueError(f"fewer than 2 samples after the transient {transient:g} s (the record ends at {t[-1]:g} s)")
    t, F = t[window], F[window]
    noise = _noise(F)
    if not (math.isfinite(smooth) and smooth >= 0):
        raise ValueError(f"smooth must be a number >= 0 [s], got {smooth!r}")
    F, w = smoothed(t, F, smooth)
    if min_drop is None:
        drop = max(noise_factor * noise / math.sqrt(w), MIN_DROP_RANGE * float(np.ptp(F)))
    else:
        drop = float(min_drop)
        if not (math.isfinite(drop) and drop > 0):
            raise ValueError(f"min_drop must be > 0 [N], got {min_drop!r}")
    peaks, troughs = _extrema(F, drop) if drop > 0 else (np.zeros(0, int), np.zeros(0, int))
    # a slip: a maximum and the minimum that follows it (they alternate: before the next maximum)
    nxt = np.searchsorted(troughs, peaks)
    has = nxt < troughs.size
    slip_duration = t[troughs[nxt[has]]] - t[peaks[has]]
    cycle_means = np.asarray(
        [_integral(F[a : b + 1], t[a : b + 1]) / (t[b] - t[a]) for a, b in itertools.pairwise(peaks)]
    )
    duration = float(t[-1] - t[0])
    return {
        "F_mean": float(_integral(F, t) / duration),
        "duration": duration,
        "cycles": {
            "F_mean": cycle_means,
            "F_slip": F[peaks],
            "F_stick": F[troughs],
            "period": np.diff(t[peaks]),
            "slip_duration": slip_duration,
        },
        "t_slip": t[peaks],
        "t_stick": t[troughs],
        "min_drop": drop,
        "noise": noise,
        "window": (float(t[0]), float(t[-1])),
    }


def record_statistics(t, F, *, transient: float = 0.0, min_drop: float | None = None, smooth: float = 0.0,
                      noise_factor: float = MIN_DROP_NOISE) -> dict:  # fmt: skip
    """The stick-slip statistics of a measured force record F(t) (a sawtooth), after ``transient``.

    **Slips.** A slip is a fall of F by more than ``min_drop`` [N] below its running maximum;
    the next one counts only after F has risen by more than ``min_drop`` above its running
    minimum (hysteresis: noise smaller than ``min_drop`` neither makes nor splits a slip). The
    first extremum found in the window is left out (the window may cut it). These are the
    maxima and minima of prominence above ``min_drop`` (``scipy.signal.find_peaks``). Default
    ``min_drop``: the larger of 10 times the record's white-noise level (estimated from the
    median absolute deviation of its second differences, which assumes samples dense enough
    that F changes smoothly between slips) and 1 % of its peak-to-peak range. Not a fixed
    fraction of the range: the model's slips come in bursts of unequal size (V = 1.1 m/s:
    drops of 17–28 N and re-stick rises of 6–20 N within a range of 118 N; V = 3 m/s: drops
    down to 2.3 N, rises to 0.4 N in 220 N), so a quarter of the range would see none of them.
    Slips smaller than ``min_drop`` — or whose re-stick rise is — are merged with their
    neighbours: check ``slips`` against the record, and pass ``min_drop`` where it misjudges.

    **Per slip**: ``F_slip``, the maximum of F before the fall (the stick → slip instant: in
    the model F is continuous and largest there); ``F_stick``, the minimum after it (slip →
    stick); ``slip_duration``, from that maximum to that minimum; ``period``, between
    consecutive maxima. ``F_mean`` is the time average of F over the window (trapezoid rule),
    its ``F_mean_std`` the spread of the time averages over the cycles (maximum to maximum).
    Each statistic is given as its mean over the slips in the window and ``<name>_std``, their
    sample standard deviation (NaN for fewer than 2 values). The times are those of the
    samples: within a sample spacing of the true instants.

    **Noisy records** (``smooth`` > 0 [s]): the slips are found on, and every statistic taken
    from, F averaged over a moving window of ``smooth`` seconds, whose noise is the record's /√w
    (w samples in the window); the default ``min_drop`` is then ``noise_factor`` times that.
    Measured on records at V = 1.1 and 1.6 m/s with white noise of 0.5 % of F (``docs/fitting.md``):
    at 10 kHz, 0.6 ms and a factor 6 find 108 and 198 of their 107 and 204 slips (no smoothing and
    the default factor 10: 38 and 28). The statistics are then those of the smoothed record: a
    model compared with it has to be smoothed alike (:mod:`peeljax.fit.instrument` does).

    Returns:
        a dict with ``F_mean``, ``F_mean_std`` and, where at least one value was found,
        ``F_slip``, ``F_stick``, ``period``, ``slip_duration`` with their ``_std``; and
        ``slips`` (the number of maxima found), ``t_slip``/``t_stick`` (the times of the
        maxima/minima), ``min_drop`` (the threshold used), ``noise`` (the estimated noise
        level) and ``window`` (first and last time used). A record without slips (steady
        peeling) has only ``F_mean`` of the statistics.
    """
    r = record_cycles(t, F, transient=transient, min_drop=min_drop, smooth=smooth, noise_factor=noise_factor)
    out = {"F_mean": r["F_mean"], "F_mean_std": sample_std(r["cycles"]["F_mean"])}
    for name in ("F_slip", "F_stick", "period", "slip_duration"):
        values = r["cycles"][name]
        if values.size:
            out[name], out[f"{name}_std"] = float(np.mean(values)), sample_std(values)
    out.update(
        slips=int(r["t_slip"].size), t_slip=r["t_slip"], t_stick=r["t_stick"], min_drop=r["min_drop"],
        noise=r["noise"], window=r["window"],
    )  # fmt: skip
    return out
