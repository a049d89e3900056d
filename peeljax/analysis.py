"""Stick-slip analysis of a run: phases, near-singular points, local index, events, cycles.

Along a trajectory y_t = (α, ω, u, v) at pull velocity V and homogenization time scale τ:

* **phases** from the sign of ∂φ/∂v(v_t, V) (the paper's section 2: φ increases while the tape
  *sticks*, up to its maximum, and decreases while it *slips*): ``stick`` ⇔ ∂φ/∂v > 0,
  ``slip`` ⇔ ∂φ/∂v < 0. ``branch`` also tells the two rising branches apart: 0 below the maximum
  of φ (stick), 1 between the maximum and the minimum (slip), 2 above the minimum (the fast
  rising branch, ∂φ/∂v > 0 again: counted as stick by the sign rule);
* the Schur complement J_t(τ) = −∂φ/∂v + τ·F̃·(𝐈 − τ·∂f/∂x)⁻¹·∂f/∂v (Lemma 1) and the local index
  ⌈log_τ|J_t|⌉ + 1 (Lemma 2, :func:`peeljax.local_index`);
* **near-singular points** — the local bifurcation points of Theorem 3 (`bif`), |J_t| → 0 — as the sign
  changes of J_t between output times (interpolated) and the local minima of |J_t| below a
  threshold (default 1 N·s/m: the boundary of the fast scale of Lemma 2, index ≥ 2);
* **events**: stick → slip (∂φ/∂v crosses zero downwards: the maximum of φ, adhesion yields) and
  slip → stick (upwards), by linear interpolation between output times;
* **τ = 0 runs with jumps** (the DAE, ``fold="jump"``): v never sits on the middle branch, it
  jumps from the stick branch to the fast one (both with ∂φ/∂v > 0), so the sign rule cannot
  see the phases there. The jump record can, exactly: phases, events and the stick fraction
  come from it (:func:`peeljax.cycle_statistics`);
* **both sides of every jump**: a run carried through the folds keeps, at each jump time, a row
  with the state just before the jump and one with the state just after it (equal times; the
  second marked in ``Solution.after_jump``), so extrema and ranges see v⁺; rows with equal
  times are a zero-width interval to every time average and interpolation here;
* **means over time**: output times are not uniform (error control saves its accepted steps),
  so every mean is a time average, the trapezoid rule in t (:func:`time_average`); where the
  rows lack the jumps (a file written before both sides were kept), each recorded jump of v
  is inserted at its time (v_before, v_after) so that the jump is exact; fractions of phases
  are fractions of time;
* **cycle measures** of v after a transient: ``period`` is one thing, the mean time between
  stick → slip events (the jump record's ``slip_interval``; for τ > 0 the downward crossings of
  ∂φ/∂v), and ``repeat`` is the repeat of those events (:func:`peeljax.cycles.repeat_pattern`,
  k events every T, or :class:`~peeljax.cycles.TooFewRepeats`, or None: irregular or no slips);
  the amplitude (half the late peak-to-peak range, jump values included) and the local extrema.

:func:`trajectory_structure` is pure JAX (``jit``/``vmap``-able, any leading batch axes);
:func:`analyze` runs it and extracts the events on the host (one :class:`StickSlipAnalysis` per
trajectory). :func:`bifurcation_diagram` runs one simulation per V and collects the late
extrema of v (the sweep engine's batching can replace the loop; the result is the same).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .cycles import CycleStatistics, RepeatPattern, TooFewRepeats, cycle_statistics, repeat_outlook, repeat_pattern
from .homogenized import HomogenizedODE
from .model import PeelingModel
from .saved import SavedRun
from .solution import Solution
from .structure import (
    PHI_SEARCH_RANGE,
    jacobians,
    local_index,
    phi_max_and_min,
    schur_complement,
    truncated_schur_complement,
)

__all__ = [
    "BifurcationDiagram",
    "StickSlipAnalysis",
    "analyze",
    "bifurcation_diagram",
    "crossings",
    "fold_limit",
    "local_extrema",
    "oscillation",
    "phi_extrema",
    "time_average",
    "trajectory_structure",
]

DEFAULT_THRESHOLD = 1.0  # N·s/m: |J_t| < 1 ⇔ local index ≥ 2 (Lemma 2), the fast scale


# ---------------------------------------------------------------------------- JAX part
def trajectory_structure(
    model: PeelingModel, ys: Float[Array, "... 4"], V: ArrayLike, tau: ArrayLike, truncation: int | None = None
) -> dict[str, Array]:
    """∂φ/∂v, J_t(τ), the local index, the constraint residual G − φ and F̃·f at every state.

    Args:
        model: the model the run used.
        ys: states (α, ω, u, v), any leading axes (NaN states give NaN).
        V, tau: pull velocity and τ, broadcastable against ``ys[..., 0]``.
        truncation: the run's (``None``: the exact J_t; m: its m-term eq. ``hvex``), as in
            :class:`~peeljax.HomogenizedODE`.

    Returns:
        A dict of arrays of shape ``ys.shape[:-1]``: ``phi_v``, ``schur`` (J_t, Lemma 1),
        ``local_index`` (Lemma 2), ``constraint_residual`` ((1 + l·sinα/L)·F − φ, eq. ``sac``), ``drive``
        (F̃·f, the rate of change of the shear force).
    """
    ys = jnp.asarray(ys, float)

    def one(y, V, tau):
        jac = jacobians(model, y[:3], y[3], V)
        J = schur_complement(jac, tau) if truncation is None else truncated_schur_complement(jac, tau, truncation)
        return jac.phi_v, J, model.constraint(y[:3], y[3], V), jnp.dot(jac.F_tilde, jac.f)

    V = jnp.broadcast_to(jnp.asarray(V, float), ys.shape[:-1])
    tau = jnp.broadcast_to(jnp.asarray(tau, float), ys.shape[:-1])
    phi_v, J, constraint_residual, drive = jnp.vectorize(one, signature="(4),(),()->(),(),(),()")(ys, V, tau)
    index = jnp.where(jnp.isfinite(J), local_index(jnp.where(jnp.isfinite(J), J, 1.0), tau), 0)
    return {"phi_v": phi_v, "schur": J, "local_index": index, "constraint_residual": constraint_residual, "drive": drive}


def phi_extrema(model: PeelingModel | None = None, V: float = 1.1) -> tuple[float, float]:
    """The peeling velocities of the maximum and the minimum of φ(·, V) (∂φ/∂v = 0), NaN if absent.

    :func:`peeljax.structure.phi_max_and_min` (the search the sweep engine runs in the graph), on
    the host: v ∈ [1e-8, 1e2]·max(V, 1), a log grid refined by bisection in log v.
    """
    model = PeelingModel() if model is None else model
    top, bottom = _phi_extrema_jit(model, jnp.asarray(V, float))
    return float(top), float(bottom)


@eqx.filter_jit  # module level: compiled once per model structure, not per call
def _phi_extrema_jit(model, V):
    return phi_max_and_min(model, V)


_SLOPE_GRID = 4096  # log-spaced v of the search for min ∂φ/∂v: 400 points a decade
_GOLDEN = 0.5 * (5**0.5 - 1)


@eqx.filter_jit
def _min_slope(model, V):
    """min over v of ∂φ/∂v(v, V) [N·s/m]: < 0 where φ(·, V) has a fold (the slip branch between
    its maximum and minimum), > 0 where it has none. The grid's least slope, refined by a
    golden-section search in log v between its neighbours."""
    log_v = jnp.linspace(jnp.log(PHI_SEARCH_RANGE[0]), jnp.log(PHI_SEARCH_RANGE[1]), _SLOPE_GRID)
    log_v = log_v + jnp.log(jnp.maximum(V, 1.0))

    def slope(x):
        return jax.grad(lambda v: model.phi(v, V))(jnp.exp(x))

    i = jnp.argmin(jax.vmap(slope)(log_v))
    bracket = (log_v[jnp.maximum(i - 1, 0)], log_v[jnp.minimum(i + 1, _SLOPE_GRID - 1)])

    def shrink(_, bracket):
        lo, hi = bracket
        a, b = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
        left = slope(a) < slope(b)
        return jnp.where(left, lo, a), jnp.where(left, b, hi)

    lo, hi = jax.lax.fori_loop(0, 80, shrink, bracket)
    return slope(0.5 * (lo + hi))


def fold_limit(model: PeelingModel | None, V_fold: float, V_none: float, *, xtol: float = 1e-10) -> float:
    """The pull velocity between ``V_fold`` (φ(·, V) has a fold) and ``V_none`` (it has none)
    where the fold appears or vanishes: the cusp where φ's maximum and minimum merge, the root
    of s(V) = min_v ∂φ/∂v(v, V) (negative while the slip branch exists), by Brent's method.

    For the paper's φ the fold vanishes at V = 5.387 m/s (``tests/test_figures.py``).

    Raises:
        ValueError: when s has the same sign at both ends (no such V between them), naming them.
    """
    from scipy.optimize import brentq

    model = PeelingModel() if model is None else model

    def s(V):
        return float(_min_slope(model, jnp.asarray(V, float)))

    s_fold, s_none = s(V_fold), s(V_none)
    if not (s_fold < 0 < s_none):
        raise ValueError(
            f"fold_limit: φ must have a fold at V_fold = {V_fold:g} (min ∂φ/∂v = {s_fold:.3g}) and none at "
            f"V_none = {V_none:g} (min ∂φ/∂v = {s_none:.3g})"
        )
    return float(brentq(s, min(V_fold, V_none), max(V_fold, V_none), xtol=xtol, rtol=8.9e-16))


_structure_jit = eqx.filter_jit(trajectory_structure)  # truncation: a Python int or None, static


# ---------------------------------------------------------------------------- host helpers
def crossings(ts: np.ndarray, values: np.ndarray, direction: str = "both") -> np.ndarray:
    """Times where ``values`` crosses zero, by linear interpolation between samples.

    ``direction``: ``"down"`` (+ → −), ``"up"`` (− → +) or ``"both"``. NaN samples break the series.
    """
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    a, b = values[:-1], values[1:]
    ok = np.isfinite(a) & np.isfinite(b)
    down = ok & (a > 0) & (b <= 0)
    up = ok & (a < 0) & (b >= 0)
    mask = {"down": down, "up": up, "both": down | up}[direction]
    i = np.flatnonzero(mask)
    frac = a[i] / (a[i] - b[i])
    return ts[i] + frac * (ts[i + 1] - ts[i])


def local_extrema(ts: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Interior local maxima and minima of a sampled series: (t_max, v_max, t_min, v_min)."""
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    a, b, c = values[:-2], values[1:-1], values[2:]
    ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(c)
    imax = np.flatnonzero(ok & (b > a) & (b >= c)) + 1
    imin = np.flatnonzero(ok & (b < a) & (b <= c)) + 1
    return ts[imax], values[imax], ts[imin], values[imin]


def _with_jumps(ts, values, jumps):
    """The series with each jump (t_j, before_j, after_j) inserted as two points at t_j, in time
    order (a sample at t_j holds the state before the jump: it goes first)."""
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    if jumps is None or np.size(jumps[0]) == 0:
        return ts, values
    t_j, before, after = (np.asarray(a, float).ravel() for a in jumps)
    t = np.concatenate([ts, t_j, t_j])
    x = np.concatenate([values, before, after])
    rank = np.concatenate([np.zeros(ts.size), np.ones(t_j.size), np.full(t_j.size, 2.0)])
    order = np.lexsort((rank, t))
    return t[order], x[order]


def time_average(
    ts: np.ndarray,
    values: np.ndarray,
    t_start: float | None = None,
    t_end: float | None = None,
    jumps: tuple | None = None,
) -> float:
    """(1/(t_end − t_start))·∫ x dt over [t_start, t_end] by the trapezoid rule on the samples.

    The samples need not be uniform (error control's accepted steps are not): the unweighted
    mean of such samples over-weights where the steps are short. NaN samples are left out.
    Equal consecutive times (both sides of a jump in a run's rows) are a jump of x there: a
    window starting at that time starts from the value after it, one ending there ends at the
    value before it.

    Args:
        ts, values: the samples (t ascending where finite).
        t_start, t_end: the window (default: the first and last finite sample); the ends are
            interpolated linearly.
        jumps: ``(t_j, before_j, after_j)`` of jumps of x between samples (a run's jump record:
            v jumps at a fold), inserted so that the integral sees the jump where it happened;
            not needed where the samples hold both sides of each jump already.

    Returns:
        The time average; NaN when fewer than two finite samples lie in the window or it is empty.
    """
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    ok = np.isfinite(ts) & np.isfinite(values)
    t, x = _with_jumps(ts[ok], values[ok], jumps)
    if t.size < 2:
        return float("nan")
    a = float(t[0]) if t_start is None else max(float(t_start), float(t[0]))
    b = float(t[-1]) if t_end is None else min(float(t_end), float(t[-1]))
    if not b > a:
        return float("nan")
    # the piecewise-linear interpolant cut to [a, b]: the ends interpolated, the samples between kept
    inside = (t > a) & (t < b)
    t_cut = np.concatenate([[a], t[inside], [b]])
    x_cut = np.concatenate([[_interp_right(t, x, a)], x[inside], [_interp_left(t, x, b)]])
    return float(np.sum(0.5 * (x_cut[1:] + x_cut[:-1]) * np.diff(t_cut)) / (b - a))


def _interp_right(t, x, q):
    """The linear interpolant at q, taking the value after a jump when q is a jump's time."""
    i = int(np.searchsorted(t, q, side="right")) - 1
    if i >= t.size - 1:
        return float(x[-1])
    return float(x[i] + (q - t[i]) / (t[i + 1] - t[i]) * (x[i + 1] - x[i])) if t[i + 1] > t[i] else float(x[i + 1])


def _interp_left(t, x, q):
    """The linear interpolant at q, taking the value before a jump when q is a jump's time."""
    i = int(np.searchsorted(t, q, side="left"))
    if i == 0:
        return float(x[0])
    return float(x[i - 1] + (q - t[i - 1]) / (t[i] - t[i - 1]) * (x[i] - x[i - 1])) if t[i] > t[i - 1] else float(x[i - 1])


def _time_weights(ts: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The trapezoid weight of each valid sample (half of each neighbouring interval), 0 elsewhere:
    Σ w·mask / Σ w is the fraction of time where a 0/1 mask holds."""
    w = np.zeros(ts.size)
    i = np.flatnonzero(valid & np.isfinite(ts))
    if i.size >= 2:
        gaps = np.diff(ts[i])
        w[i[:-1]] += 0.5 * gaps
        w[i[1:]] += 0.5 * gaps
    elif i.size == 1:
        w[i] = 1.0
    return w


def oscillation(ts: np.ndarray, values: np.ndarray, t_start: float = 0.0) -> dict[str, float]:
    """Period, amplitude and mean of an oscillating series over t ≥ ``t_start``.

    The mean is the time average (:func:`time_average`: samples need not be uniform); the
    period is the median spacing of the upward crossings of that mean (NaN with fewer than
    two); the amplitude is half the late peak-to-peak range; ``decay`` is the ratio of the last
    to the first late half-range (< 1 for a damped oscillation), NaN with fewer than two cycles.
    """
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    late = (ts >= t_start) & np.isfinite(values)
    if late.sum() < 3:
        return {"period": float("nan"), "amplitude": float("nan"), "mean": float("nan"), "decay": float("nan")}
    t, x = ts[late], values[late]
    mean = time_average(t, x)
    ups = crossings(t, x - mean, "up")
    period = float(np.median(np.diff(ups))) if ups.size >= 2 else float("nan")
    amplitude = 0.5 * float(np.max(x) - np.min(x))
    decay = float("nan")
    if ups.size >= 3:
        first = (t >= ups[0]) & (t < ups[1])
        last = (t >= ups[-2]) & (t < ups[-1])
        span_first = np.ptp(x[first]) if first.any() else np.nan
        decay = float(np.ptp(x[last]) / span_first) if span_first > 0 else float("nan")
    return {"period": period, "amplitude": amplitude, "mean": mean, "decay": decay}


# ---------------------------------------------------------------------------- analysis
@dataclass(frozen=True)
class StickSlipAnalysis:
    """The stick-slip picture of one trajectory (host numpy arrays; see the module doc).

    Per output time: ``ts``, ``v``, ``valid``, ``phi_v``, ``stick``, ``slip``, ``branch``,
    ``schur`` (J_t), ``local_index``, ``near_singular`` (|J_t| < threshold), ``constraint_residual``,
    ``after_jump`` (the rows of the run: both sides of each jump, the second marked here).
    Events: ``stick_to_slip`` and ``slip_to_stick`` times (on a τ = 0 run with jumps: the jump
    record's), ``schur_sign_changes`` (J_t = 0 crossed between samples), ``bifurcation_times``
    (those and the local minima of |J_t| below the threshold: Theorem 3's points, as far as the
    output grid resolves them). Over the run: ``stick_fraction``, ``slip_fraction`` (of time;
    from the jump record on τ = 0 runs with jumps). Cycle measures of v after ``t_transient``:
    ``period`` (the mean time between stick → slip events), ``repeat`` (their repeat: a
    :class:`~peeljax.cycles.RepeatPattern`, a :class:`~peeljax.cycles.TooFewRepeats`, or None:
    ``repeat_verdict`` says irregular or none), ``amplitude``, ``v_mean`` (time average),
    ``decay``, ``oscillation_period`` (of v about its time-mean, :func:`oscillation`: what a
    run without slips, a damped oscillation, has), the extrema
    ``v_max_times``/``v_max``/``v_min_times``/``v_min``, and ``cycles``
    (the jump record's :class:`~peeljax.cycles.CycleStatistics` after the transient, or None).
    """

    V: float
    tau: float
    threshold: float
    t_transient: float
    t_stop: float
    completed: bool
    ts: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    phi_v: np.ndarray
    stick: np.ndarray
    slip: np.ndarray
    branch: np.ndarray
    schur: np.ndarray
    local_index: np.ndarray
    near_singular: np.ndarray
    constraint_residual: np.ndarray
    stick_to_slip: np.ndarray
    slip_to_stick: np.ndarray
    schur_sign_changes: np.ndarray
    bifurcation_times: np.ndarray
    v_max_times: np.ndarray
    v_max: np.ndarray
    v_min_times: np.ndarray
    v_min: np.ndarray
    period: float
    amplitude: float
    v_mean: float
    decay: float
    stick_fraction: float = float("nan")
    slip_fraction: float = float("nan")
    oscillation_period: float = float("nan")
    repeat: RepeatPattern | TooFewRepeats | None = None
    slips: int = 0
    cycles: CycleStatistics | None = None
    extra: dict = field(default_factory=dict)
    after_jump: np.ndarray | None = None

    @property
    def min_abs_schur(self) -> float:
        """min |J_t| over the valid output times."""
        values = np.abs(self.schur[self.valid & np.isfinite(self.schur)])
        return float(values.min()) if values.size else float("nan")

    @property
    def max_local_index(self) -> int:
        values = self.local_index[self.valid]
        return int(values.max()) if values.size else 0

    @property
    def repeat_verdict(self) -> str:
        """``"regular"``, ``"too few repeats to tell"``, ``"irregular"`` or ``"none"`` (no
        stick → slip after the transient), as :attr:`peeljax.CycleStatistics.verdict`."""
        if isinstance(self.repeat, RepeatPattern):
            return "regular"
        if isinstance(self.repeat, TooFewRepeats):
            return "too few repeats to tell"
        return "none" if self.slips == 0 else "irregular"

    def fraction(self, mask_name: str) -> float:
        """Fraction of the time (trapezoid weights of the valid output times) where ``stick``,
        ``slip`` or ``near_singular`` holds; for ``stick``/``slip`` the run's
        ``stick_fraction``/``slip_fraction`` (exact from the jump record on τ = 0 runs)."""
        if mask_name in ("stick", "slip"):
            return self.stick_fraction if mask_name == "stick" else self.slip_fraction
        return _mask_fraction(self.ts, self.valid, getattr(self, mask_name))

    def __repr__(self) -> str:
        """A few lines: the run, its phases and events, the cycle measures (``summary()``: all numbers)."""
        valid = int(self.valid.sum())
        outcome = "completed" if self.completed else "stopped"
        if isinstance(self.repeat, RepeatPattern):
            repeat = f"repeat T = {self.repeat.period:.4g} s with {self.repeat.events} slips"
        else:
            repeat = f"repeat: {self.repeat_verdict}"
        return (
            f"StickSlipAnalysis(V = {self.V:g} m/s, tau = {self.tau:g} s, {outcome} at t = {self.t_stop:.6g} s, "
            f"{valid} valid of {self.ts.size} output times,\n"
            f"  stick {self.stick_fraction:.1%}, slip {self.slip_fraction:.1%} of the time; "
            f"{self.stick_to_slip.size} stick -> slip and {self.slip_to_stick.size} slip -> stick events; "
            f"{self.bifurcation_times.size} near-singular points (min |J_t| = {self.min_abs_schur:.3g} N s/m, "
            f"local index <= {self.max_local_index}),\n"
            f"  after t = {self.t_transient:.4g} s: v time-mean {self.v_mean:.4g} m/s, amplitude {self.amplitude:.4g} m/s, "
            f"{self.slips} slips, period (time between slips) {self.period:.4g} s, {repeat}, decay {self.decay:.3g})"
        )

    def summary(self) -> dict:
        """Plain-Python numbers for JSON output and tables."""
        repeat = self.repeat.as_dict() if self.repeat is not None else None
        return {
            "V": self.V,
            "tau": self.tau,
            "t_stop": self.t_stop,
            "completed": self.completed,
            "stick_fraction": self.stick_fraction,
            "slip_fraction": self.slip_fraction,
            "n_stick_to_slip": int(self.stick_to_slip.size),
            "n_slip_to_stick": int(self.slip_to_stick.size),
            "n_bifurcation_points": int(self.bifurcation_times.size),
            "bifurcation_times": [float(t) for t in self.bifurcation_times],
            "min_abs_schur": self.min_abs_schur,
            "max_local_index": self.max_local_index,
            "slips": self.slips,
            "period": self.period,
            "repeat": repeat,
            "repeat_verdict": self.repeat_verdict,
            "amplitude": self.amplitude,
            "v_mean": self.v_mean,
            "decay": self.decay,
            "oscillation_period": self.oscillation_period,
        }


def _mask_fraction(ts, valid, mask) -> float:
    w = _time_weights(np.asarray(ts, float), np.asarray(valid, bool))
    total = w.sum()
    return float(np.sum(w * np.asarray(mask, bool)) / total) if total > 0 else float("nan")


def _branch(v: np.ndarray, v_top: float, v_bottom: float) -> np.ndarray:
    branch = np.where(v < v_top, 0, np.where(np.isnan(v_bottom) | (v < v_bottom), 1, 2))
    return np.where(np.isfinite(v), branch, -1).astype(np.int8)


def _jump_phases(ts, valid, t_j, up, branch, after=None):
    """stick, slip per output time on a τ = 0 run from its jumps: after the last jump strictly
    before t (a sample at a jump's time holds the state before it, unless marked ``after``:
    the state after it) the tape is where that jump landed; before the first, on the branch
    it leaves; without jumps, where v is (branch 0: the stick branch, else the fast one)."""
    if t_j.size == 0:
        return valid & (branch == 0), valid & (branch >= 1)
    n_before = np.searchsorted(t_j, np.where(np.isfinite(ts), ts, np.inf), side="left")
    if after is not None:
        n_before = np.minimum(n_before + after, t_j.size)
    stuck = np.where(n_before == 0, bool(up[0]), ~up[np.maximum(n_before - 1, 0)])
    return valid & stuck, valid & ~stuck


def _analyze_one(ts, ys, valid, t_stop, completed, struct, model, V, tau, threshold, t_transient, v_ext, jumps, after=None):
    v = np.where(valid, ys[:, 3], np.nan)
    phi_v = np.where(valid, struct["phi_v"], np.nan)
    J = np.where(valid, struct["schur"], np.nan)
    absJ = np.abs(J)
    near = valid & (absJ < threshold)
    sign_changes = crossings(ts, J, "both")
    # local minima of |J_t| below the threshold (points where it dips towards zero on the grid)
    _, _, t_min_J, v_min_J = local_extrema(ts, absJ)
    dips = t_min_J[v_min_J < threshold]
    if near.any():  # a threshold crossing at the last valid point (a run stopping there) counts too
        last = int(np.flatnonzero(valid)[-1])
        if near[last] and (last == 0 or absJ[last] <= absJ[last - 1]):
            dips = np.append(dips, ts[last])
    bif = np.unique(np.concatenate([sign_changes, dips]))
    branch = _branch(v, *v_ext)
    t_first = float(ts[valid][0]) if valid.any() else float("nan")
    t_end = float(t_stop) if np.isfinite(t_stop) else float(np.nanmax(ts[valid])) if valid.any() else float("nan")
    t_j = up = None
    jump_points = None
    if jumps is not None:
        t_j, up = jumps["jump_t"], jumps["jump_up"].astype(bool)
        # rows without the jumps (an older file): the record's v before and after, inserted
        jump_points = (t_j, jumps["jump_v_before"], jumps["jump_v_after"]) if after is None else None
    cycles = None
    if jumps is not None and tau == 0:
        # the DAE: the phases, events and stick fraction from the jump record, exactly
        stick, slip = _jump_phases(ts, valid, t_j, up, branch, after)
        to_slip, to_stick = t_j[up], t_j[~up]
        whole = cycle_statistics(jumps, t_end, transient=t_first) if t_end > t_first else None
        stick_fraction = whole.stick_fraction if whole is not None else float("nan")
        if np.isnan(stick_fraction):  # no jump: the branch v is on
            stick_fraction = _mask_fraction(ts, valid, stick)
        if t_transient < t_end:
            cycles = cycle_statistics(jumps, t_end, transient=max(t_transient, 0.0))
        late_up = to_slip[(to_slip >= t_transient) & (to_slip <= t_end)]
    else:
        stick, slip = valid & (phi_v > 0), valid & (phi_v < 0)
        to_slip, to_stick = crossings(ts, phi_v, "down"), crossings(ts, phi_v, "up")
        stick_fraction = _mask_fraction(ts, valid, stick)
        late_up = to_slip[to_slip >= t_transient]
    slip_fraction = 1.0 - stick_fraction if jumps is not None and tau == 0 else _mask_fraction(ts, valid, slip)
    # period: the mean time between stick → slip events after the transient; their repeat
    period = float(np.mean(np.diff(late_up))) if late_up.size >= 2 else float("nan")
    if cycles is not None:
        repeat = cycles.repeat if cycles.repeat is not None else cycles.too_few
    elif late_up.size:
        repeat = repeat_pattern(late_up)
        repeat = repeat if repeat is not None else repeat_outlook(late_up, t_end=t_end)
    else:
        repeat = None
    t_max, x_max, t_min, x_min = local_extrema(ts, v)
    late_max, late_min = t_max >= t_transient, t_min >= t_transient
    osc = oscillation(ts, v, t_transient)
    late = valid & (ts >= t_transient)
    late_v = v[late]
    if jump_points is not None:  # the values v jumps from and to are part of its range (rows without them)
        in_late = (t_j >= t_transient) & (t_j <= t_end)
        late_v = np.concatenate([late_v, jump_points[1][in_late], jump_points[2][in_late]])
    amplitude = 0.5 * float(np.ptp(late_v)) if late_v.size else float("nan")
    return StickSlipAnalysis(
        V=float(V),
        tau=float(tau),
        threshold=float(threshold),
        t_transient=float(t_transient),
        t_stop=float(t_stop),
        completed=bool(completed),
        ts=ts,
        v=v,
        valid=valid,
        phi_v=phi_v,
        stick=stick,
        slip=slip,
        branch=branch,
        schur=J,
        local_index=np.where(valid, struct["local_index"], 0).astype(np.int32),
        near_singular=near,
        constraint_residual=np.where(valid, struct["constraint_residual"], np.nan),
        stick_to_slip=to_slip,
        slip_to_stick=to_stick,
        schur_sign_changes=sign_changes,
        bifurcation_times=bif,
        v_max_times=t_max[late_max],
        v_max=x_max[late_max],
        v_min_times=t_min[late_min],
        v_min=x_min[late_min],
        period=period,
        amplitude=amplitude,
        v_mean=time_average(ts, v, t_transient, t_end, jumps=jump_points),
        decay=osc["decay"],
        oscillation_period=osc["period"],
        stick_fraction=float(stick_fraction),
        slip_fraction=float(slip_fraction),
        repeat=repeat,
        slips=int(late_up.size),
        cycles=cycles,
        after_jump=np.zeros(ts.shape, bool) if after is None else after,
    )


def analyze(
    solution: Solution,
    model: PeelingModel | HomogenizedODE | None = None,
    V: ArrayLike | None = None,
    tau: ArrayLike | None = None,
    *,
    truncation: int | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    t_transient: float | None = None,
) -> StickSlipAnalysis | list[StickSlipAnalysis]:
    """The stick-slip analysis of a run (or of each run of a batched, ``vmap``-ed, Solution).

    ``analyze(solution, ode)`` takes everything from the :class:`~peeljax.HomogenizedODE` the
    run integrated (model, V, τ, truncation); ``analyze(solution, model, V=…, tau=…)`` names
    them one by one; a run read back by :func:`peeljax.load` brings its own (model, V and τ
    from the file; what is given here overrides them).

    Args:
        solution: a single or batched :class:`Solution` (batch axes lead).
        model: the :class:`~peeljax.HomogenizedODE` of the run, or the model it used
            (default: the paper's).
        V, tau: with a model: the run's pull velocity and τ (scalars, or one per trajectory of
            the batch; default 1.1 and 0.01). J_t is recomputed at τ from the states (the
            α-method's ``diagnostics.schur`` holds the same values).
        truncation: with a model: the run's (see :class:`~peeljax.HomogenizedODE`).
        threshold: |J_t| below this [N·s/m] marks the fast scale / a near-singular point.
        t_transient: cycle measures (period, repeat, time-mean, amplitude) use t ≥ this
            (default: the second half of the output span); phase fractions cover the whole run.

    Returns:
        A :class:`StickSlipAnalysis`, or a flat list of them for a batch (row-major order).
    """
    if isinstance(model, HomogenizedODE):
        if V is not None or tau is not None or truncation is not None:
            raise ValueError("analyze: give the run's HomogenizedODE, or its model with V, tau and truncation, not both")
        model, V, tau, truncation = model.model, model.V, model.tau, model.truncation
    if isinstance(solution, SavedRun):  # a run read back from a file knows its own parameters
        if solution.model is None and model is None:
            raise ValueError(
                f"analyze: {solution.path!r} was made with a callable phi, which the file cannot hold: "
                "pass the run's model (analyze(run, model))"
            )
        model = solution.model if model is None else model
        V = solution.V if V is None else V
        tau = solution.tau if tau is None else tau
    model = PeelingModel() if model is None else model
    V = 1.1 if V is None else V
    tau = 0.01 if tau is None else tau
    if not threshold > 0:
        raise ValueError(f"threshold must be > 0 (allowed range: (0, inf)), got {threshold!r}")
    ys = jnp.asarray(solution.ys)
    batch_shape = ys.shape[:-2]
    V_b = np.broadcast_to(np.asarray(V, float), batch_shape)
    tau_b = np.broadcast_to(np.asarray(tau, float), batch_shape)
    struct = _structure_jit(model, ys, jnp.asarray(V_b)[..., None], jnp.asarray(tau_b)[..., None], truncation)
    struct = {key: np.asarray(value) for key, value in struct.items()}
    ts_all = np.asarray(solution.ts, float)
    ys_all = np.asarray(ys, float)
    valid_all = np.asarray(solution.valid, bool)
    t_stop_all = np.asarray(solution.t_stop, float)
    completed_all = np.asarray(solution.completed)
    n = int(np.prod(batch_shape)) if batch_shape else 1
    ts_flat = ts_all.reshape(n, -1)
    jumps_flat = _jump_arrays(solution.jumps, n)
    after_flat = None if solution.after_jump is None else np.asarray(solution.after_jump, bool).reshape(n, -1)
    out = []
    extrema_cache: dict[float, tuple[float, float]] = {}
    for i in range(n):
        ts = ts_flat[i]
        Vi, taui = (
            float(V_b.reshape(n)[i] if batch_shape else V_b),
            float(tau_b.reshape(n)[i] if batch_shape else tau_b),
        )
        if Vi not in extrema_cache:
            extrema_cache[Vi] = phi_extrema(model, Vi)
        # nanmax: an error-controlled run without output times pads its step points with NaN
        t_tr = 0.5 * (ts[0] + np.nanmax(ts)) if t_transient is None else float(t_transient)
        out.append(
            _analyze_one(
                ts,
                ys_all.reshape(n, -1, 4)[i],
                valid_all.reshape(n, -1)[i],
                t_stop_all.reshape(n)[i],
                completed_all.reshape(n)[i],
                {key: value.reshape(n, -1)[i] for key, value in struct.items()},
                model,
                Vi,
                taui,
                threshold,
                t_tr,
                extrema_cache[Vi],
                None if jumps_flat is None else jumps_flat[i],
                None if after_flat is None else after_flat[i],
            )
        )
    return out if batch_shape else out[0]


def _jump_arrays(record, n: int) -> list[dict] | None:
    """The recorded jumps of each of the n trajectories as host arrays (first ``count`` slots)."""
    if record is None:
        return None
    count = np.asarray(record.count).reshape(n)
    fields = {"jump_t": record.t, "jump_up": record.up, "jump_v_before": record.v_before,
              "jump_v_after": record.v_after, "jump_G": record.G}  # fmt: skip
    arrays = {key: np.asarray(value).reshape(n, -1) for key, value in fields.items()}
    return [{key: value[i, : int(count[i])] for key, value in arrays.items()} for i in range(n)]


# ---------------------------------------------------------------------------- bifurcation diagram
@dataclass(frozen=True)
class BifurcationDiagram:
    """Late extrema of v against V at fixed τ: ``v_max[i]``/``v_min[i]`` are arrays for ``V[i]``.

    ``t_stop[i]`` and ``completed[i]`` tell which runs ended early (their extrema come from the
    part that was computed, after ``t_transient``).
    """

    V: np.ndarray
    tau: float
    t_transient: float
    v_max: list[np.ndarray]
    v_min: list[np.ndarray]
    v_final: np.ndarray
    t_stop: np.ndarray
    completed: np.ndarray


def bifurcation_diagram(
    Vs: ArrayLike,
    tau: float = 0.01,
    *,
    model: PeelingModel | None = None,
    dt: float = 1 / 82,
    t_final: float = 3.0,
    t_transient: float | None = None,
    engine: str = "auto",
) -> BifurcationDiagram:
    """Run the α-method at each V (τ fixed, the paper's initial data) and collect the late extrema of v.

    Args:
        Vs: pull velocities [m/s].
        tau: the fixed homogenization time scale [s].
        dt, t_final: the mesh (as for :func:`peeljax.simulate`).
        t_transient: extrema are taken over t ≥ this (default t_final/2).
        engine: ``"sweep"`` (the batched :func:`peeljax.sweep`, states saved every step),
            ``"loop"`` (one :func:`peeljax.simulate` per V; V is traced, so one compilation), or
            ``"auto"`` (the sweep engine).
    """
    from .simulate import simulate

    if engine not in ("auto", "sweep", "loop"):
        raise ValueError(f"engine must be one of auto, sweep, loop; got {engine!r}")
    model = PeelingModel() if model is None else model
    Vs = np.atleast_1d(np.asarray(Vs, float))
    t_tr = 0.5 * t_final if t_transient is None else float(t_transient)
    series = []  # (ts, v, t_stop, completed) per V
    if engine in ("auto", "sweep"):
        from .sweeps import sweep as run_sweep

        result = run_sweep(model, V=Vs, tau=tau, dt=dt, t_final=t_final, save_every=1, progress=False)
        for i in range(Vs.size):
            series.append(
                (
                    np.asarray(result.ts),
                    np.asarray(result.ys[i, :, 3]),
                    float(result.t_stop[i]),
                    bool(result.completed[i]),
                )
            )
    else:
        for V in Vs:
            sol = simulate(model, float(V), tau, dt, t_final)
            v = np.where(np.asarray(sol.valid), np.asarray(sol.v), np.nan)
            series.append((np.asarray(sol.ts), v, float(sol.t_stop), bool(sol.completed)))
    v_max, v_min, v_final, t_stop, completed = [], [], [], [], []
    for ts, v, stop, done in series:
        tM, xM, tm, xm = local_extrema(ts, v)
        v_max.append(xM[tM >= t_tr])
        v_min.append(xm[tm >= t_tr])
        finite = v[np.isfinite(v)]
        v_final.append(finite[-1] if finite.size else np.nan)
        t_stop.append(stop)
        completed.append(done)
    return BifurcationDiagram(
        V=Vs,
        tau=float(tau),
        t_transient=t_tr,
        v_max=v_max,
        v_min=v_min,
        v_final=np.asarray(v_final),
        t_stop=np.asarray(t_stop),
        completed=np.asarray(completed),
    )
