"""Fitting φ to a stick-slip table: Levenberg–Marquardt on the cycle statistics, with uncertainties.

Each row of a :class:`~peeljax.fit.StickSlipTable` is one pull velocity V_i, where the model's
statistics (``F_mean``, ``F_slip``, ``F_stick``, ``period``, ``slip_duration``: on its attractor,
:mod:`.table_rows`, or over the window [transient, transient + window] of a run from the paper's
initial data through the folds, :mod:`.window_rows`) are compared with the table's:

    r_is = (model_s(V_i; θ) − data_is)/σ_is,

σ_is² the table's variance (else the RMS of column s, and the covariance is then scaled by the
residual variance) plus the model window's cycle-to-cycle scatter²
(:func:`peeljax.measurements.statistics.window_scatter`). A statistic the table has but the model
does not produce (no slip) costs a fixed residual ``MISSING_RESIDUAL`` with zero derivative, so
that a trial step that loses the stick-slip is never mistaken for a better fit. A force record
that stick-slips is fitted through these statistics, not point by point: the phase of a
sawtooth drifts and would dominate a point-wise misfit (``docs/fitting.md`` measures it).

Solver: Levenberg–Marquardt (:class:`LevenbergMarquardt`, host-driven) from the start, or
(window method) from the best few of a coarse batch (the start and a Latin hypercube around
it), the runs of every start in lockstep through one compiled program that gives r and its
forward-mode Jacobian (one tangent per free coefficient, through every jump by the implicit
function theorem); its stop reason names the test that stopped it. χ²/dof is reported and
scales the covariance where it exceeds 1 (:mod:`peeljax.fit.uncertainty`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._validation import check_positive
from ..adhesion import AdhesionLaw
from ..model import PeelingModel
from ..orbits.api import DEFAULT_ORBIT_RTOL
from .levenberg_marquardt import CONVERGED, STOP_REASONS, LevenbergMarquardt, missing_entries
from .profile import profile
from .table_rows import Point, TableRows, attractor_rows
from .window_rows import MISSING_RESIDUAL, TableFit, build_table_fit, table_residuals
from ..measurements.statistics import STATISTICS
from ..measurements.stick_slip_table import StickSlipTable
from .parameters import check_free, model_and_start, value_and_jacfwd
from .result import FitInterrupted, TableFitResult, interrupted, least_squares_result
from .result import EQUAL_CHI2, OUTLIER_SIGMA, ROUGH_PROFILES  # noqa: F401 - importable from their old home
from .uncertainty import uncertainty_from_jacobian

__all__ = ["CONVERGED", "MISSING_RESIDUAL", "STOP_REASONS", "TableFit", "TableFitResult", "attractor_statistics",
    "build_table_fit", "check_intervals", "fit_rows", "fit_stick_slip", "least_squares_result", "table_residuals"]  # fmt: skip


@eqx.filter_jit
def _evaluate(fit: TableFit, thetas):
    """For a batch of θ (each leaf (B,)), one after another (``lax.map``) in one compiled program:
    r (B, m), J (B, m, p; columns in ``fit.names`` order) and the v range (B, n, 2). The coarse
    batch and every Levenberg–Marquardt iteration call this one program (one compilation: a
    second, runs-only program for the coarse batch would cost more to compile than its
    tangents cost to run). ``lax.map``, not ``vmap``: under ``vmap`` every lax.cond of the loop
    (the fold location, the jump, the output) runs at every step."""

    def one(theta):
        z = jnp.stack([theta[n] for n in fit.names])
        (r, v_range), J = value_and_jacfwd(lambda z: fit.residuals_and_range(dict(zip(fit.names, z))), z)
        return r, J, v_range

    return jax.lax.map(one, thetas)


def _evaluate_batch(fit: TableFit, zs: np.ndarray, batch: int):
    """r, J, v range at the rows of ``zs`` (θ in ``fit.names`` order), ``batch`` at a time
    through the one compiled program :func:`_evaluate` (the last chunk padded)."""
    out = []
    for begin in range(0, len(zs), batch):
        chunk = zs[begin : begin + batch]
        padded = np.concatenate([chunk, np.repeat(chunk[-1:], batch - len(chunk), axis=0)])
        r, J, v = _evaluate(fit, {n: jnp.asarray(padded[:, k]) for k, n in enumerate(fit.names)})
        out += list(zip(np.asarray(r), np.asarray(J), np.asarray(v)))[: len(chunk)]
    return out


def progress_callback(progress):
    """``progress`` as the fits take it: None (silent) for None or False, a line on stderr per
    iteration for True, a callable ``progress(iteration, chi2)`` as it is."""
    if progress is None or progress is False:
        return None
    if progress is True:
        return lambda iteration, chi2: print(f"iteration {iteration}: chi2 = {chi2:.6g}", file=sys.stderr, flush=True)
    if not callable(progress):
        raise TypeError(f"progress must be None, True, False or a callable progress(iteration, chi2), got {progress!r}")
    return progress


def _solve(fit: TableFit, starts, evaluated, *, fit_rtol, fit_atol, max_iterations, progress=None) -> list[LevenbergMarquardt]:
    """Levenberg–Marquardt from each start (rows of ``starts``, already ``evaluated``: (r, J, v
    range) each) in lockstep: each iteration evaluates every run's trial point in one call of
    :func:`_evaluate`."""
    runs = [LevenbergMarquardt(z, *e, fit_rtol=fit_rtol, fit_atol=fit_atol, max_iterations=max_iterations)
            for z, e in zip(starts, evaluated)]  # fmt: skip
    iteration = 0
    try:
        while any(run.reason is None for run in runs):
            trials = np.stack([run.trial() for run in runs])
            for run, e in zip(runs, _evaluate_batch(fit, trials, len(runs))):
                run.take(*e)
            iteration += 1
            if progress is not None:  # on the host, between iterations: the lowest chi2 so far
                progress(iteration, min(run.chi2 for run in runs))
    except KeyboardInterrupt:  # Ctrl-C: the best point so far goes with the interruption
        raise FitInterrupted(interrupted(fit.names, fit.start, min(runs, key=lambda run: run.chi2), iteration)) from None
    return runs


def _coarse_starts(n_coarse: int, p: int, spread: float, seed: int) -> np.ndarray:
    """θ = 0 (the start itself) and n_coarse − 1 points of a Latin hypercube on [−spread, spread]^p
    (log c: each coefficient within a factor exp(±spread) of its start)."""
    rng = np.random.default_rng(seed)
    n = n_coarse - 1
    cube = (np.stack([rng.permutation(n) for _ in range(p)], axis=1) + rng.uniform(size=(n, p))) / max(n, 1)
    return np.concatenate([np.zeros((1, p)), spread * (2 * cube - 1)])


def _table_arrays(table: StickSlipTable, wanted) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(data, σ, measured, σ from the table) as (n, 5) arrays over :data:`STATISTICS`."""
    data = np.zeros((len(table), len(STATISTICS)))
    sigma = np.ones_like(data)
    measured = np.zeros_like(data, bool)
    has_std = all(s in table.std and not np.any(np.isnan(table.std[s][~np.isnan(table.values[s])])) for s in wanted)
    for j, s in enumerate(STATISTICS):
        if s not in wanted:
            continue
        column = table.values[s]
        measured[:, j] = ~np.isnan(column)
        data[:, j] = np.nan_to_num(column)
        sigma[:, j] = np.nan_to_num(table.std[s], nan=1.0) if has_std else float(np.sqrt(np.nanmean(column**2)))
    return data, sigma, measured, has_std


def _check_options(
    table, transient, window, n_samples, tau, n_starts, max_iterations, fit_rtol, fit_atol, n_coarse, coarse_spread,
    scale_covariance, taper=0.0,
):  # fmt: skip
    if not isinstance(table, StickSlipTable):
        raise TypeError(f"table must be a StickSlipTable (read_stick_slip_table), got {type(table).__name__}")
    for name, value in (("window", window), ("fit_rtol", fit_rtol), ("fit_atol", fit_atol), ("coarse_spread", coarse_spread)):
        check_positive(name, value)
    for name, value in (("transient", transient), ("tau", tau)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    for name, value, least in (("n_samples", n_samples, 2), ("n_starts", n_starts, 1),
                               ("max_iterations", max_iterations, 1), ("n_coarse", n_coarse, 1)):  # fmt: skip
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
    if not (isinstance(taper, (int, float)) and 0 <= taper <= 0.5):
        raise ValueError(f"taper must be a number in [0, 0.5], got {taper!r}")
    if not (scale_covariance is True or scale_covariance is False or scale_covariance == "auto"):
        raise ValueError(f"scale_covariance must be 'auto', True or False, got {scale_covariance!r}")


def table_tolerances(tau: float, rtol: float | None = None, atol: float | None = None) -> tuple[float, float]:
    """The integrator's tolerances of a table fit: given ones, else by τ.

    τ = 0 runs Tsit5, whose forward-mode Jacobian of the statistics through ~30 jumps is
    right to 1e-3 at rtol 1e-9 and 1e-8 but not at 1e-7, where one near-tangential slip's
    time derivative is 3× off (measured: ``tests/test_steppers.py``); a fifth-order
    stepper's tighter tolerance costs little. τ > 0 keeps the α-method's 1e-7.
    """
    loose = float(tau) > 0
    return (1e-7 if loose else 1e-9) if rtol is None else rtol, (1e-10 if loose else 1e-12) if atol is None else atol


def fit_stick_slip(table: StickSlipTable, model: PeelingModel | None = None, *,
                   free: Sequence[str] | None = ("c1", "c3", "c6"), start: AdhesionLaw | None = None,
                   statistics: Sequence[str] | None = None, method: str = "orbit", tau: float = 0.0,
                   transient: float = 0.5, window: float = 1.0, n_samples: int = 401,
                   rtol: float | None = None, atol: float | None = None,
                   orbit_rtol: float = DEFAULT_ORBIT_RTOL, fit_rtol: float = 1e-6, fit_atol: float = 1e-6,
                   max_iterations: int = 20, n_starts: int | None = None, n_coarse: int | None = None,
                   coarse_spread: float = 0.15, seed: int = 0, scale_covariance: bool | str = "auto",
                   cycle_scatter: bool = True, taper: float | None = None, intervals: str = "auto",
                   level: float = 0.95, max_jumps: int = 4096, max_steps: int = 400_000, progress=None,
                   instruments: dict | None = None, points=None) -> TableFitResult:  # fmt: skip
    """Fit φ's free coefficients to a stick-slip table by Levenberg–Marquardt (module docstring).

    Args:
        table: the measured statistics against V (:func:`peeljax.fit.read_stick_slip_table`,
            :meth:`StickSlipTable.from_force_records`); rows with ``F_mean`` only where peeling
            is steady, the others where it stick-slips, in any mix.
        model: spool and tape (default the paper's); its φ is the start unless ``start`` is given.
        free: the coefficients to fit (default c1, c3, c6); None: all 14. Coefficients the
            table cannot determine are named in ``result.uncertainty.undetermined``.
        statistics: the table's statistics to fit (default all it has).
        method: ``"orbit"`` (default: each row on its own attractor — steady peeling
            F = φ(V, V), the periodic orbit's statistics over one period, or, where a row has no
            periodic attractor, the tapered window statistics; :mod:`peeljax.fit.table_rows`)
            or ``"window"`` (every row's statistics over the window of a run from the paper's
            start, as before orbits; τ > 0 needs it).
        tau: 0 (default: the DAE with jumps) or τ > 0 (the homogenized ODE with jumps; window only).
        transient, window: the window statistics are taken over ``[transient, transient +
            window]`` [s].
        n_samples: dense-output times in the window (``F_mean`` is their mean).
        rtol, atol: the window runs' tolerances; None: :func:`table_tolerances` (τ = 0: rtol
            1e-9, atol 1e-12 for the default Tsit5 stepper; τ > 0: 1e-7, 1e-10).
        orbit_rtol: the tolerance of each orbit's period run (default 1e-8,
            :data:`peeljax.orbits.DEFAULT_ORBIT_RTOL`).
        fit_rtol, fit_atol: Levenberg–Marquardt's convergence tolerances (``STOP_REASONS``:
            fit_atol on the Gauss–Newton step's predicted χ² decrease, fit_rtol on the relative
            step and χ² decrease); ``max_iterations``: its budget of model evaluations per start.
        n_coarse, coarse_spread, seed: the coarse batch (window method): χ² at the start and at
            n_coarse − 1 points of a Latin hypercube (n_coarse default 16, raised to ``n_starts``),
            each coefficient within exp(±coarse_spread) of its start (``seed``). The orbit method
            starts from ``start`` alone: its statistics are smooth between bifurcations, and the
            profile intervals map the landscape across them.
        n_starts: Levenberg–Marquardt runs from the n_starts best points of the coarse batch
            (window method, default 3), the best end kept, the others in ``result.optima``.
        scale_covariance: ``"auto"`` (scale by χ²/dof where it exceeds 1: the table's σ too
            small), True (always, as ``curve_fit``), False (never);
            :mod:`peeljax.fit.uncertainty`. A table without σ is always scaled.
        cycle_scatter: add to each window statistic's σ² the model window's cycle-to-cycle
            standard error² (:func:`peeljax.measurements.statistics.window_scatter`); False: the table's
            σ alone. (Orbit statistics are exact: nothing to add.)
        taper: the fraction of the window over which each edge's weight of a window statistic
            ramps (:func:`peeljax.measurements.statistics.jump_statistics`), in [0, 0.5]; default 0.25
            for the orbit method's window rows (continuous in the coefficients), 0 for the
            window method (the table must be made with the same taper).
        intervals: ``"auto"`` (default: a profile-likelihood interval, :mod:`peeljax.fit.profile`,
            beside the linearized one of each coefficient whose linearized interval holds a
            bifurcation — a row on another attractor at one of its ends —, unless χ² is rough at
            the optimum, :func:`rough_rows`, where profiles were measured too narrow),
            ``"profile"`` (for every coefficient), ``"linear"`` (never).
        level: the confidence level of the profile intervals (default 0.95).
        max_jumps, max_steps: each window run's jump record and step budget.
        progress: None or False (silent), True (a line on stderr per iteration), or
            ``progress(iteration, chi2)`` called on the host after each Levenberg–Marquardt
            iteration (chi2: the lowest of the starts so far).
        instruments: {row: :class:`~peeljax.measurements.instrument.Instrument`} for rows measured from
            force records (orbit method): the model's statistics there as that record's sampling
            and noise show them (:func:`peeljax.fit.fit_records` passes them).
        points: a :class:`~peeljax.fit.points.PointRows` of records fitted point by point
            together with the table (orbit method; :func:`peeljax.fit.fit_records`).

    Returns:
        A :class:`TableFitResult` (``summary()`` prints it): the fitted ``adhesion``, its
        ``uncertainty`` and ``intervals()``, ``rows`` (per row its kind, its orbit, and
        ``singular_elasticity`` where its derivative is too steep to use,
        :func:`~peeljax.fit.table_rows.singular_rows`), ``crossings`` (every bifurcation a step
        crossed or was refused across), χ², outliers, optima and ``v_range`` (from at least
        ``V_REST`` = 1e-4 m/s, where the tape comes to rest: φ is fixed by the data only there).
    """
    began = time.perf_counter()
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    if (instruments or points is not None) and method != "orbit":
        raise ValueError("instruments and points need method='orbit'")
    if method == "orbit" and not (isinstance(tau, (int, float)) and tau == 0):
        raise ValueError(f"tau must be 0 with method='orbit' (orbits of the DAE with jumps); use method='window' for tau > 0, got {tau!r}")
    check_intervals(intervals, level)
    check_positive("orbit_rtol", orbit_rtol)
    taper = (0.25 if method == "orbit" else 0.0) if taper is None else taper
    n_starts = (1 if method == "orbit" else 3) if n_starts is None else n_starts
    n_coarse = (1 if method == "orbit" else 16) if n_coarse is None else n_coarse
    rtol, atol = table_tolerances(tau, rtol, atol)
    progress = progress_callback(progress)
    _check_options(
        table, transient, window, n_samples, tau, n_starts, max_iterations, fit_rtol, fit_atol, n_coarse,
        coarse_spread, scale_covariance, taper,
    )  # fmt: skip
    names = check_free(free)
    model, start = model_and_start(model, start, "fit_stick_slip")
    wanted = table.statistics if statistics is None else tuple(statistics)
    unknown = [s for s in wanted if s not in table.statistics]
    if unknown or not wanted:
        raise ValueError(f"statistics: {unknown or 'none'} not in the table, which has {list(table.statistics)}")
    data, sigma, measured, has_std = _table_arrays(table, wanted)
    if int(measured.sum()) <= len(names):
        raise ValueError(
            f"free: {int(measured.sum())} measured values cannot determine {len(names)} coefficients "
            "with an error estimate; fit fewer"
        )
    window_options = dict(names=names, tau=tau, transient=transient, window=window, n_samples=n_samples, rtol=rtol,
                          atol=atol, max_jumps=max_jumps, max_steps=max_steps, cycle_scatter=cycle_scatter, taper=taper)  # fmt: skip
    scale = True if not has_std else scale_covariance
    options = dict(fit_rtol=fit_rtol, fit_atol=fit_atol, max_iterations=max_iterations, progress=progress)
    if method == "orbit":
        fitted = _fit_on_attractors(table, model, start, data, sigma, measured, names, window_options, orbit_rtol,
                                    cycle_scatter, options, scale=scale, intervals=intervals, level=level,
                                    instruments=instruments, points=points)  # fmt: skip
        runs, initial = fitted.pop("runs"), fitted.pop("initial")
        report = fitted  # the rows followed, why each has its kind, the crossings and the profiles
        measured = getattr(report["rows"], "table", report["rows"]).measured  # less what records' instruments miss
    else:
        fit = build_table_fit(start, model, table.V, data, sigma, measured, **window_options)
        n_coarse = max(n_coarse, n_starts)  # the starts are the best of the coarse batch
        coarse = _coarse_starts(n_coarse, len(names), coarse_spread, seed)
        evaluated = _evaluate_batch(fit, coarse, n_starts)
        coarse_losses = np.asarray([float(r @ r) for r, _, _ in evaluated])
        coarse_missing = np.asarray([missing_entries(r) for r, _, _ in evaluated])
        # fewest missing statistics first (a point where the runs lose their stick-slip is worse
        # than any that keeps it, whatever its χ²), then χ²
        order = np.lexsort((np.where(np.isfinite(coarse_losses), coarse_losses, np.inf), coarse_missing))[:n_starts]
        runs = _solve(fit, coarse[order], [evaluated[k] for k in order], **options)
        initial = float(coarse_losses[0])  # the coarse batch's first point is ``start`` itself
        report = {"coarse_losses": coarse_losses}
    settings = {
        "kind": "stick-slip table", "V": [float(v) for v in table.V], "statistics": list(wanted), "method": method,
        "tau": float(tau), "transient": float(transient), "window": float(window), "n_samples": n_samples,
        "rtol": rtol, "atol": atol, "orbit_rtol": orbit_rtol, "fit_rtol": fit_rtol, "fit_atol": fit_atol,
        "max_iterations": max_iterations, "n_starts": n_starts, "n_coarse": n_coarse, "coarse_spread": coarse_spread,
        "seed": seed, "intervals": intervals, "level": level,
        "solver": "levenberg-marquardt (forward-mode Jacobian)" + (
            " from the start, each row's attractor followed" if method == "orbit" else " from the best of a coarse batch"),
        "weights": "the table's standard deviations" if has_std else "column RMS",
        "scale_covariance": scale if isinstance(scale, str) else bool(scale), "cycle_scatter": bool(cycle_scatter),
        "taper": float(taper),
        "parametrisation": "c = c_start*exp(theta)",
    }  # fmt: skip
    return least_squares_result(runs, start, names, settings, scale=scale, initial=initial, began=began, table=table,
                                measured=measured, **report)  # fmt: skip


METHODS = ("orbit", "window")
INTERVALS = ("auto", "profile", "linear")


def check_intervals(intervals: str, level: float) -> None:
    """``intervals`` one of :data:`INTERVALS` and ``level`` in (0, 1), as every least-squares fit takes them."""
    if intervals not in INTERVALS:
        raise ValueError(f"intervals must be one of {', '.join(map(repr, INTERVALS))}, got {intervals!r}")
    if not (isinstance(level, float) and 0 < level < 1):
        raise ValueError(f"level must be a number in (0, 1), got {level!r}")


def _fit_on_attractors(table, model, start, data, sigma, measured, names, window_options, orbit_rtol, cycle_scatter,
                       options, *, scale, intervals, level, instruments=None, points=None) -> dict:  # fmt: skip
    """Levenberg–Marquardt from ``start`` with every row on its attractor (:func:`attractor_rows`;
    with ``points``, a :class:`~peeljax.fit.points.PointRows`, records fitted point by point
    beside them): :func:`fit_rows`."""
    rows, why = attractor_rows(model, start, table.V, data, sigma, measured, window_options=window_options,
                               orbit_rtol=orbit_rtol, cycle_scatter=cycle_scatter)  # fmt: skip
    if instruments:
        rows.set_instruments(instruments)
    if points is not None:
        from .points import Joint

        rows = Joint(rows, points)
    fitted = fit_rows(rows, start, names, options, scale=scale, intervals=intervals, level=level)
    return {**fitted, "why": why}


def fit_rows(rows, start, names, options, *, scale, intervals, level) -> dict:
    """Levenberg–Marquardt from θ = 0 on ``rows`` (:class:`TableRows`, or anything with its
    ``start``/``evaluate``), each trial point following the attractors of the point it steps
    from; the crossings of bifurcations logged (accepted or refused); then the intervals
    (:func:`_profiles_if_needed`), and Levenberg–Marquardt again from a profile point of lower
    χ² where one was found (the optimum was a branch's, not the table's)."""
    point = rows.start()
    if getattr(rows, "has_instruments", False):  # the records' instruments at the start's orbits
        rows.update_bias(point)
        point = rows.evaluate(point.z, point)
    initial = float(point.r @ point.r)
    crossings, counter, latest = [], [0], []
    try:
        return _fit_rows_from(rows, point, start, names, options, crossings, counter, latest, initial, scale=scale,
                              intervals=intervals, level=level)  # fmt: skip
    except KeyboardInterrupt:  # Ctrl-C: the best point so far goes with the interruption
        if not latest:
            raise
        best = min(latest, key=lambda run: run.chi2)
        raise FitInterrupted(interrupted(names, start, best, counter[0])) from None


def _fit_rows_from(rows, point, start, names, options, crossings, counter, latest, initial, *, scale, intervals,
                   level) -> dict:  # fmt: skip
    run = _rounds(rows, point, options, crossings, counter, latest)
    run = _beyond_the_edge(rows, run, options, crossings, counter, latest)
    profiles = {}
    for _ in range(RESTARTS + 1):
        values = np.asarray([float(getattr(start, n)) * math.exp(run.z[k]) for k, n in enumerate(names)])
        uncertainty = uncertainty_from_jacobian(run.J, run.r, values, names, scaled=scale)
        profiles = _profiles_if_needed(rows, run, uncertainty, intervals, level, options)
        lowest = min((p.lowest for p in profiles.values()), key=lambda q: float(q.r @ q.r), default=None)
        if lowest is None or not float(lowest.r @ lowest.r) < run.chi2 - LOWER:
            break
        crossings.append({"row": None, "V": None, "from": None, "to": None, "iteration": counter[0], "accepted": True,
                          "why": f"the profile found chi2 {float(lowest.r @ lowest.r):.4g} below the optimum's "
                          f"{run.chi2:.4g} on another branch: Levenberg-Marquardt again from there"})  # fmt: skip
        run = _rounds(rows, lowest, options, crossings, counter, latest)
    return {"runs": [run], "rows": rows, "crossings": crossings, "initial": initial, "profiles": profiles}


def _beyond_the_edge(rows, run, options, crossings: list, counter: list, latest: list):
    """A run stopped at a bifurcation or on a rough floor may sit at the edge of its attractors'
    branch with the optimum beyond: there the steps toward it lose an orbit near a grazing, or
    cross to another, and are refused. So the Gauss–Newton point of the rows that carry the
    Jacobian is evaluated with every orbit found afresh; where its χ² is lower (by ``LOWER``),
    Levenberg–Marquardt goes on from it, and its optimum is taken where lower still (at most
    ``RESTARTS`` times). Measured on the whole-range table without noise (χ² 0 at the truth):
    the fit stopped at χ² 1.25, 0.87 SE from the truth; now at χ² 0.14 and 0.30 SE, or, where
    the last digits of the run lead the row at 3.5 m/s to a coexisting attractor, at 6.93 and
    1.00 SE (``tests/test_fit_table.py``, benchmarks/results/fit_coverage_wide.md)."""
    table = getattr(rows, "table", rows)  # a Joint: its table's rows
    if not isinstance(table, TableRows) or not table.rows["orbit"]:
        return run
    for _ in range(RESTARTS):
        if run.reason not in ("bifurcation", "floor"):
            break
        jump = run.z + np.linalg.lstsq(run.J, -run.r, rcond=None)[0]
        there = rows.evaluate(jump, rows.forget(run.state, list(table.rows["orbit"])))
        if not float(there.r @ there.r) < run.chi2 - LOWER:
            break
        other = _rounds(rows, there, options, crossings, counter, latest)
        if other.reason not in CONVERGED or not other.chi2 < run.chi2 - LOWER:
            break
        crossings.append({"row": None, "V": None, "from": None, "to": None, "iteration": counter[0], "accepted": True,
                          "why": f"stopped at the edge of a branch (chi2 {run.chi2:.4g}): Levenberg-Marquardt again "
                          f"from the Gauss-Newton point, its orbits found afresh, reached chi2 {other.chi2:.4g}"})  # fmt: skip
        run = other
    return run


ROUNDS = 4  # Levenberg–Marquardt runs at most: the first, then after switching to the attractors reached from rest or updating the instruments' bias
RESTARTS = 2  # Levenberg–Marquardt again from a profile's lower χ² at most this often
LOWER = 0.5  # a profile point this much below the optimum's χ² is a better optimum
BIAS_SETTLED = 0.05  # [σ]: the instruments' bias is settled once an update moves it less


def _rounds(rows, point, options, crossings: list, counter: list, latest: list):
    """Levenberg–Marquardt from ``point``; then again from the attractors reached from rest
    where they are not the ones followed (the table was measured from rest), and with the
    records' instrument bias updated at the optimum until it settles; at most ``ROUNDS`` times
    (then :func:`_least_chi2_round`). ``latest`` gets each run as it starts (what an
    interruption keeps)."""
    unsettled = []  # the converged runs after which rest reached other attractors
    for round_ in range(ROUNDS):
        run = LevenbergMarquardt(point.z, point.r, point.J, point.v_range, fit_rtol=options["fit_rtol"],
                         fit_atol=options["fit_atol"], max_iterations=options["max_iterations"], state=point)  # fmt: skip
        latest.append(run)
        while run.reason is None:
            trial = rows.evaluate(run.trial(), run.state)
            run.take(trial.r, trial.J, trial.v_range, state=trial, crossed=bool(trial.changes))
            counter[0] += 1
            for change in trial.changes:
                crossings.append({**change, "iteration": counter[0], "accepted": run.state is trial})
            if options["progress"] is not None:
                options["progress"](counter[0], run.chi2)
        if run.reason not in CONVERGED:
            return run
        differ = rows.from_rest(run.state)
        moved = rows.update_bias(run.state) if getattr(rows, "has_instruments", False) else 0.0
        if not differ and moved <= BIAS_SETTLED:
            return run
        unsettled.append(run)
        if round_ == ROUNDS - 1:
            break
        point = rows.evaluate(run.z, rows.forget(run.state, differ))
        for change in point.changes:
            crossings.append({**change, "iteration": counter[0], "accepted": True,
                              "why": "the attractor reached from rest is another one (coexisting attractors)"})  # fmt: skip
    return _least_chi2_round(rows, unsettled, crossings, counter)


def _least_chi2_round(rows, runs: list, crossings: list, counter: list):
    """The run to keep when every round's optimum reached other attractors from rest: where two
    orbits of a row coexist over an interval of θ that holds the optima, rest can reach the
    other one at each optimum, and the rule "the attractor reached from rest" has no answer
    (measured: the whole-range table's row at 3.5 m/s, orbits of 33 and 34 slips, alternated
    over four rounds of one fit, χ² 48 and 84; ``benchmarks/fit_coverage.py --problem wide``,
    draw 11). The round of least χ² is kept, the branch profiled out. Not with records, whose
    bias moves between rounds (their χ² are of different models): the last."""
    last = runs[-1]
    if getattr(rows, "has_instruments", False):
        return last
    best = min(runs, key=lambda run: run.chi2)
    if best is not last:
        crossings.append({"row": None, "V": None, "from": None, "to": None, "iteration": counter[0], "accepted": True,
                          "why": f"from rest other attractors were reached at each of {len(runs)} optima: the one "
                          f"of least chi2 kept ({best.chi2:.4g}, against {last.chi2:.4g} at the last)"})  # fmt: skip
    return best


# Measured (benchmarks/fit_coverage.py --problem wide, 21 draws): where rows are judged by χ²
# alone or by window statistics at the optimum, the profile intervals covered the truth in
# 10–11 of 21 draws (often 0.2–0.5 of the linearized width, some not holding the optimum), the
# linearized ones in 19–20 (errors/SE spread 0.93–1.11); "auto" keeps the linearized ones there.


def rough_rows(point) -> list[int]:
    """The rows of ``point`` whose χ² contribution jumps at scales below a profile's grid: a
    derivative left out (:func:`~peeljax.fit.table_rows.singular_rows`) or window statistics in
    place of a lost orbit (a :class:`~peeljax.fit.points.Joint`'s point has neither)."""
    return sorted(set(getattr(point, "singular", {})) | set(getattr(point, "windowed", ())))


def _profiles_if_needed(rows: TableRows, best, uncertainty, intervals, level, options) -> dict:
    """Profile-likelihood intervals (:mod:`peeljax.fit.profile`) where ``intervals`` asks: for
    every coefficient (``"profile"``), or (``"auto"``) for each coefficient whose linearized
    interval has an end where a row's attractor is another than at the optimum (a bifurcation
    within it), unless χ² is rough at the optimum (:func:`rough_rows`: the linearized intervals
    then, measured to cover where the profiles did not)."""
    if intervals == "linear" or best.state is None or not np.isfinite(best.chi2):
        return {}
    if intervals == "auto" and rough_rows(best.state):
        return {}  # χ² jumps at the optimum: profiles came out too narrow (ROUGH_PROFILES)
    q = uncertainty.quantile(level)
    cov = np.asarray(uncertainty.covariance_log)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    doubtful = [j for j in range(best.z.size) if np.isfinite(se[j]) and se[j] > 0]
    if intervals == "auto":
        # the ends of each linearized interval, the others moved along the linear profile
        # (θ̂ ± q·direction: θ_j = θ̂_j ± q·se_j, the others re-fitted); a coefficient whose two
        # ends lie on the optimum's attractors keeps its linearized interval
        def crosses(j):
            direction = cov[:, j] / se[j]
            return any(rows.evaluate(best.z + sign * q * direction, best.state).changes for sign in (1.0, -1.0))

        doubtful = [j for j in doubtful if crosses(j)]
    threshold = uncertainty.residual_variance * q**2
    out = {}
    for j in doubtful:
        name = uncertainty.names[j]
        prof = profile(rows, best.state, j, se_log=float(se[j]), threshold=threshold, level=level,
                       c_hat=float(uncertainty.values[j]), fit_rtol=options["fit_rtol"],
                       fit_atol=options["fit_atol"], valley=cov[:, j] / cov[j, j])  # fmt: skip
        out[name] = dataclasses.replace(prof, name=name)
    return out


def attractor_statistics(law: AdhesionLaw, V, *, model: PeelingModel | None = None, names=("c1",), orbit_rtol=None,
                         window_fit_options: dict | None = None, follow_lost: bool = False,
                         ) -> tuple[Point, TableRows, list[str]]:  # fmt: skip
    """The model's statistics at the pull velocities ``V`` with φ = ``law``, each row on its
    attractor as :func:`~peeljax.fit.fit_stick_slip` (``method="orbit"``) predicts it: the
    :class:`Point` at θ = 0 (``values``, ``available``, ``v_range``), the :class:`TableRows` and
    why each row has its kind. ``names``: the coefficients of the compiled orbit program (share
    it with a fit of the same ``free``); ``window_fit_options``: :func:`peeljax.fit.window_rows.build_table_fit`'s
    for rows without a periodic attractor; ``follow_lost``: the rows' :meth:`TableRows.evaluate`
    at another θ gives an orbit row that loses its orbit its window statistics, as a fit does."""
    model = PeelingModel() if model is None else model
    V = np.asarray(V, float).reshape(-1)
    shape = (V.size, len(STATISTICS))
    rtol, atol = table_tolerances(0.0)
    options = {"transient": 0.5, "window": 1.0, "n_samples": 401, "rtol": rtol, "atol": atol, "max_jumps": 4096,
               "max_steps": 400_000, "taper": 0.25, **(window_fit_options or {}), "names": tuple(names), "tau": 0.0}  # fmt: skip
    rows, why = attractor_rows(eqx.tree_at(lambda m: m.adhesion, model, law), law, V, np.zeros(shape), np.ones(shape),
                               np.ones(shape, bool), window_options=options, orbit_rtol=orbit_rtol or DEFAULT_ORBIT_RTOL,
                               follow_lost=follow_lost)  # fmt: skip
    return rows.start(), rows, why
