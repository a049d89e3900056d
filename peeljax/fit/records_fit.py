"""Measured records of every kind fitted in one call: by their stick-slip statistics, or point by point.

:func:`fit_records` takes force records (t and F, what a load cell gives; also v or α where a
record holds them) at any pull velocities and decides per record how it is fitted (``by``):

* **statistics** — a t, F record that stick-slips (at least ``MIN_SLIPS`` slips after its
  transient, :func:`peeljax.fit.record_statistics`): its statistics over the record's second
  half (by default: by then the run has settled on its attractor), pooled per V, each with the
  standard error of its mean (:meth:`StickSlipTable.from_force_records` with ``std="error"``),
  fitted with the attractor's statistics as the record's instrument would show them
  (:mod:`peeljax.measurements.instrument`: the sampling interval and the noise of the record itself);
* **points** — a record that does not stick-slip (a transient settling to steady peeling,
  steady peeling), or one with v or α: point by point (:mod:`peeljax.fit.points`), the
  homogenized ODE at ``tau`` from the paper's initial data.

Records of both kinds are fitted together: one Levenberg–Marquardt on their residuals stacked,
with uncertainties (:mod:`peeljax.fit.uncertainty`) and the table fit's intervals.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import equinox as eqx
import numpy as np

from ..adhesion import AdhesionLaw
from ..model import PeelingModel
from ..simulate import simulate
from ..measurements.instrument import Instrument
from ..measurements.statistics import record_cycles, record_statistics
from .points import PointRows
from ..measurements.stick_slip_table import StickSlipTable
from .result import TableFitResult, least_squares_result
from .table import check_intervals, fit_rows, fit_stick_slip, progress_callback
from .parameters import check_free, model_and_start
from ..measurements.observations import Observation

__all__ = ["BY", "MIN_SLIPS", "POORLY_DETERMINED", "fit_records", "how_fitted", "is_force_record", "poorly_determined"]

BY = ("auto", "statistics", "points")
MIN_SLIPS = 10  # a record with fewer slips after its transient is fitted point by point
SMOOTH = 0.6e-3  # [s]: the slips of a record are found on F averaged over this window …
NOISE_FACTOR = 6.0  # … falling by more than this many times its noise (record_statistics; measured in docs/fitting.md)
SETTLED = 4.0  # standard errors: a record whose statistics drift more between its window's halves has not settled
LONG = 50  # slips: a record without a repeat has to hold this many for the halves' test
MODEL_RATE = 1e4  # [Hz]: the model's noise-free record that judges a record of too few slips …
MODEL_SAMPLES = 200_000  # … over its window, at most this many samples
LIVE = 5.0  # slip thresholds: F of a record still stick-slipping swings by more over its window's last quarter


def _holds(o: Observation, quantity: str) -> bool:
    values = getattr(o, quantity)
    return values is not None and bool(np.isfinite(values).any())


def is_force_record(o: Observation) -> bool:
    """A force record (t, F): F but neither v nor alpha, what a load cell gives."""
    return not _holds(o, "v") and not _holds(o, "alpha") and _holds(o, "F")


def how_fitted(observations: Sequence[Observation], by: str = "auto", transient: float | None = None,
               model: PeelingModel | None = None) -> list[tuple[str, str]]:  # fmt: skip
    """(``"statistics"`` or ``"points"``, why) for each record (module docstring); ``transient``:
    the statistics' start [s] (default: each record's midpoint). Under ``"auto"`` a record with
    some slips but fewer than ``MIN_SLIPS`` — a record whose noise hides its small slips shows
    few: 9 of about 265 at V = 2.4 m/s, 2 kHz, 0.5 % noise — is judged by ``model`` where one
    is given: it stick-slips if F still swings by ``LIVE`` times its slip threshold over the last
    quarter of its window (a transient settling to steady peeling does not: 0.9 times, against
    17 times at 2.4 m/s) and the model's noise-free run from rest at its V shows at least
    ``MIN_SLIPS`` slips over the same window (:func:`_model_record`)."""
    if by not in BY:
        raise ValueError(f"by must be one of {', '.join(BY)}, got {by!r}")
    out = []
    for o in observations:
        if _holds(o, "v") or _holds(o, "alpha"):
            if by == "statistics":
                raise ValueError(f"the record at V = {o.V:g} holds v or alpha: it is fitted point by point, not by statistics")
            out.append(("points", "it holds v or alpha"))
            continue
        if not _holds(o, "F"):
            raise ValueError(f"the record at V = {o.V:g} holds no F to fit")
        t, F = o.series("F")
        start = _transient(t, transient)
        try:
            found = record_statistics(t, F, transient=start, smooth=SMOOTH, noise_factor=NOISE_FACTOR)
            slips, live = found["slips"], _still_slipping(t, F, start, found["min_drop"])
        except ValueError:  # too few samples after the transient to take statistics of
            slips, live = 0, False
        if by == "points":
            out.append(("points", "asked for (--by points)"))
        elif by == "statistics":
            if slips < 2:
                raise ValueError(f"the record at V = {o.V:g} has {slips} slip(s) after t = {start:g} s: no stick-slip "
                                 "statistics to fit; fit it point by point")  # fmt: skip
            out.append(("statistics", "asked for (--by statistics)"))
        elif slips >= MIN_SLIPS:
            out.append(("statistics", f"it stick-slips: {slips} slips after t = {start:g} s"))
        elif slips > 0 and live and model is not None and (seen := _model_slips(model, o.V, t, start)) >= MIN_SLIPS:
            out.append(("statistics", f"it stick-slips: {slips} slips found after t = {start:g} s (its noise hides "
                                      f"the small ones), {seen} in the model's run from rest over the same window"))  # fmt: skip
        else:
            out.append(("points", f"it does not stick-slip: {slips} slip(s) after t = {start:g} s (fewer than {MIN_SLIPS})"))
    return out


def settled(observation: Observation, transient: float, model: PeelingModel | None = None) -> tuple[bool, str]:
    """Whether a stick-slip record has settled on its attractor after ``transient``: every
    statistic's mean over the first half of its cycles lies within ``SETTLED`` combined standard
    errors of the second half's, over at least ``LONG`` slips. A record that has not (a transient
    from rest still in it, or too short to tell: the approach to an attractor can look periodic
    for a while, the docs' 1 s record at V = 1.1 repeats every 8 slips 15 % faster than the
    orbit it approaches) is fitted with the statistics of a run from rest over the same window
    instead of the orbit's: its time 0 is taken to be the start of the pull.

    A record of fewer than ``LONG`` slips — its noise hides the small ones: at 2 kHz and 0.5 %
    noise, 11 of about 265 at V = 2.4 m/s — is judged by ``model`` where one is given: by the
    same test on the model's own noise-free run from rest at the record's V over the record's
    span (:func:`_model_record`), which sees every slip. Its own halves do not decide, drift or
    not: the slips the noise lets through are a few of a beating orbit's (measured: a settled
    record at 2.4 m/s whose 12 slips' period drifted by 4.3 standard errors sent the whole fit
    to runs from rest, c1 −0.96 % at χ²/dof 11).
    """
    found = _drift(observation.series("F"), transient)
    if found[0] is not None:
        return found[0], found[1]
    if model is None:
        return False, found[1]
    t, F = observation.series("F")
    ok, why = _drift(_model_record(model, float(observation.V), transient, float(np.max(t))), transient)
    if ok:
        return True, f"{found[1]}; the model's run from rest over the same window has settled ({why})"
    return False, f"{found[1]}; nor is the model's run from rest over the same window settled ({why})"


def _drift(record, transient: float) -> tuple[bool | None, str]:
    """The halves test of :func:`settled` on one (t, F): True or False with why, or None where
    the record holds too few slips to tell (and none of its statistics drifts)."""
    found = record_cycles(*record, transient=transient, smooth=SMOOTH, noise_factor=NOISE_FACTOR)
    t_slip, cycles = found["t_slip"], found["cycles"]
    worst, which = 0.0, ""
    for name, values in cycles.items():
        if values.size < 8:
            continue
        a, b = values[: values.size // 2], values[values.size // 2 :]
        se = math.sqrt(np.var(a, ddof=1) / a.size + np.var(b, ddof=1) / b.size)
        z = abs(float(a.mean() - b.mean())) / se if se > 0 else 0.0
        if z > worst:
            worst, which = z, name
    drifts = f"its {which} drifts between the halves of its window by {worst:.1f} standard errors"
    if t_slip.size < LONG:  # (few slips, chosen by the noise from a beating orbit's: their drift tells nothing)
        return None, f"{t_slip.size} slips, too few to tell a settled record (at least {LONG})" + (
            f"; {drifts}" if worst > SETTLED else "")  # fmt: skip
    if worst > SETTLED:
        return False, drifts
    return True, f"its {t_slip.size} slips' statistics agree between the halves of its window"


def _still_slipping(t, F, start: float, min_drop: float) -> bool:
    """F swings by at least ``LIVE`` × ``min_drop`` over the last quarter of [start, end]."""
    t, F = np.asarray(t, float), np.asarray(F, float)
    last = t >= start + 0.75 * (float(np.max(t)) - start)
    return bool(np.count_nonzero(last) > 1 and np.ptp(F[last]) >= LIVE * min_drop)


def _model_slips(model: PeelingModel, V: float, t, transient: float) -> int:
    """The slips after ``transient`` of the model's noise-free run from rest over a record's span."""
    found = record_cycles(*_model_record(model, float(V), transient, float(np.max(t))), transient=transient,
                          smooth=SMOOTH, noise_factor=NOISE_FACTOR)  # fmt: skip
    return int(found["t_slip"].size)


def _model_record(model: PeelingModel, V: float, start: float, t_final: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, F) over [start, t_final] of the model's run from rest at V (τ = 0), noise-free, sampled
    at ``MODEL_RATE`` (at most ``MODEL_SAMPLES`` samples: a long record is sampled more sparsely)."""
    n = int(min(math.floor((t_final - start) * MODEL_RATE), MODEL_SAMPLES)) + 1
    ts = np.linspace(start, t_final, n)
    sol = simulate(model, V=V, tau=0, t_final=float(t_final), ts=ts, rtol=1e-8, atol=1e-10)
    rows = ~np.asarray(sol.before_jump) & ~np.asarray(sol.after_jump) & np.asarray(sol.valid)
    ys = np.asarray(sol.ys)[rows]
    return np.asarray(sol.ts)[rows], np.asarray(model.tension(ys[:, 2], ys[:, 0]))


def _transient(t, transient) -> float:
    t = np.asarray(t, float)
    return 0.5 * (float(t[0]) + float(t[-1])) if transient is None else float(transient)


def fit_records(observations: Sequence[Observation], model: PeelingModel | None = None, *,
                free: Sequence[str] | None = ("c1",), start: AdhesionLaw | None = None, by: str = "auto",
                statistics: Sequence[str] | None = None, transient: float | None = None, tau: float = 0.01,
                instrument: bool = True, rtol: float = 1e-8, atol: float = 1e-10, max_iterations: int = 20,
                intervals: str = "auto", level: float = 0.95, scale_covariance: bool | str = "auto",
                progress=None) -> TableFitResult:  # fmt: skip
    """Fit φ's free coefficients to measured records of any kind (module docstring).

    Args:
        observations: the records (:func:`peeljax.fit.read_observations`,
            :func:`peeljax.fit.read_force_record`).
        model: spool and tape (default the paper's); its φ is the start unless ``start`` is given.
        free: the coefficients to fit (default c1).
        by: ``"auto"`` (per record: statistics where it stick-slips, else points), ``"statistics"``
            or ``"points"`` (every t, F record so; a record with v or α is always fitted by points).
        statistics: the statistics of the stick-slip records to fit (default: all they show).
        transient: where the statistics of a stick-slip record start [s] (default: each record's
            midpoint).
        tau: the τ of the records fitted point by point [s] (> 0; the statistics are the DAE's,
            τ = 0).
        instrument: compare each stick-slip record with the model's statistics as its
            instrument would show them (default; :mod:`peeljax.measurements.instrument`); False: the
            orbit's exact statistics.
        rtol, atol: the point-by-point runs' tolerances.
        max_iterations, intervals, level, scale_covariance: as :func:`peeljax.fit.fit_stick_slip`.
        progress: None or False (silent), True (a line on stderr per iteration), or
            ``progress(iteration, chi2)``.

    Returns:
        A :class:`~peeljax.fit.table.TableFitResult`; ``settings["records"]`` says how each record
        was fitted and why.
    """
    began = time.perf_counter()
    if not observations:
        raise ValueError("no records to fit")
    if not (isinstance(tau, (int, float)) and math.isfinite(tau) and tau > 0):
        raise ValueError(f"tau must be > 0 [s] for records fitted point by point, got {tau!r}")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise ValueError(f"max_iterations must be an integer >= 1, got {max_iterations!r}")
    check_intervals(intervals, level)
    names = check_free(free)
    progress = progress_callback(progress)
    model, start = model_and_start(model, start, "fit_records")
    judge = eqx.tree_at(lambda m: m.adhesion, model, start)  # judges a record of too few slips to tell
    decided = how_fitted(observations, by, transient, judge)
    stats = [o for o, (kind, _) in zip(observations, decided) if kind == "statistics"]
    pts = [o for o, (kind, _) in zip(observations, decided) if kind == "points"]
    records = [{"V": float(o.V), "by": kind, "why": why} for o, (kind, why) in zip(observations, decided)]
    points = PointRows(pts, model=model, start=start, names=names, tau=tau, rtol=rtol, atol=atol) if pts else None
    options = {"free": names, "max_iterations": max_iterations, "intervals": intervals, "level": level,
               "scale_covariance": scale_covariance, "progress": progress}  # fmt: skip
    if statistics is not None:
        options["statistics"] = tuple(statistics)
    if stats:
        begin = min(_transient(o.series("F")[0], transient) for o in stats)
        table = StickSlipTable.from_force_records(stats, transient=begin, std="error", smooth=SMOOTH,
                                                  noise_factor=NOISE_FACTOR)  # fmt: skip
        verdicts = [settled(o, begin, judge) for o in stats]
        drift = [(o, why) for o, (ok, why) in zip(stats, verdicts) if not ok]
        by_statistics = [r for r in records if r["by"] == "statistics"]  # in the order of stats
        for r, (ok, why) in zip(by_statistics, verdicts):
            r["why"] += f"; settled ({why})" if ok else (f"; not settled ({why}): the statistics of a run from rest "
                                                        "over the same window")  # fmt: skip
        if drift:
            # A record still in its transient from rest: the statistics of runs from rest over
            # the same window (the window method, no instrument: its slip durations, which the
            # sampling lengthens by about Δt, are left out).
            if points is not None:
                raise ValueError("records fitted point by point and stick-slip records not settled on their attractor "
                                 f"({drift[0][1]}) are not fitted together: fit them in separate calls")  # fmt: skip
            end = min(float(o.series("F")[0][-1]) for o in stats)
            wanted = [s for s in (statistics or table.statistics) if s != "slip_duration" and s in table.statistics]
            result = fit_stick_slip(table, model, start=start, method="window", statistics=wanted, transient=begin,
                                    window=end - begin, taper=0.0, free=names, max_iterations=max_iterations,
                                    scale_covariance=scale_covariance, progress=progress)  # fmt: skip
        else:
            instruments = {}
            if instrument:
                for i, V in enumerate(table.V):
                    at_V = [o for o in stats if float(o.V) == float(V)]
                    first = Instrument.of_record(*at_V[0].series("F"), transient=begin, smooth=SMOOTH,
                                                 noise_factor=NOISE_FACTOR)  # fmt: skip
                    duration = sum(float(o.series("F")[0][-1]) - begin for o in at_V)
                    instruments[i] = dataclasses.replace(first, duration=duration)
            result = fit_stick_slip(table, model, start=start, instruments=instruments, points=points, **options)
    else:  # records fitted point by point alone: no table, no intervals but the linearized ones
        lm = {"fit_rtol": 1e-6, "fit_atol": 1e-6, "max_iterations": max_iterations, "progress": progress}
        fitted = fit_rows(points, start, names, lm, scale=scale_covariance, intervals="linear", level=level)
        result = least_squares_result(fitted["runs"], start, names, {"kind": "records", "method": "points"},
                                      scale=scale_covariance, initial=fitted["initial"], began=began)  # fmt: skip
    result.settings.update(records=records, tau_points=float(tau) if pts else None, instrument=bool(instrument),
                           statistics_from=None if not stats else begin)  # fmt: skip
    result.wall_time_s = time.perf_counter() - began
    return result


POORLY_DETERMINED = 0.05  # a coefficient known to worse relative standard error is reported as poorly determined


def poorly_determined(result, records: list[Observation], target: float = 0.01) -> str | None:
    """A line for the coefficients the records determine to worse than ``POORLY_DETERMINED`` (relative standard
    error), with the record length that would give ``target``: the error of a fit to noisy samples falls like
    1/√(its samples), so the length scales with its square (an estimate: it holds while longer records add samples
    like these, not new physics)."""
    uncertainty = getattr(result, "uncertainty", None)
    if uncertainty is None:
        return None
    values = np.asarray(uncertainty.values, float)
    errors = np.asarray(uncertainty.standard_errors, float)
    relative = np.abs(errors / np.where(values != 0, values, np.nan))
    worst = [(name, r) for name, r in zip(uncertainty.names, relative) if not r <= POORLY_DETERMINED]
    if not worst:
        return None
    spans = [float(np.ptp(series[0])) for o in records if (series := o.series("F")) is not None and len(series[0])]
    length = sum(spans)
    said = ", ".join(f"{name} to {100 * r:.3g} %" if np.isfinite(r) else f"{name} not at all" for name, r in worst)
    factor = max((r / target) ** 2 for _, r in worst)
    longer = (f"; about {length * factor:.3g} s of record ({factor:.3g}x the {length:.3g} s given) would give "
              f"{100 * target:g} %") if np.isfinite(factor) and length > 0 else ""  # fmt: skip
    return f"the records determine {said} only (relative standard error){longer}"
