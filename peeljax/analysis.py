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
* **oscillation** of v after a transient: the period (median spacing of the upward crossings
  of the late mean), the amplitude (half the late peak-to-peak range) and the local extrema.

:func:`trajectory_structure` is pure JAX (``jit``/``vmap``-able, any leading batch axes);
:func:`analyze` runs it and extracts the events on the host (one :class:`StickSlipAnalysis` per
trajectory). :func:`bifurcation_diagram` runs one simulation per V and collects the late
extrema of v (the sweep engine's batching can replace the loop; the result is the same).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .homogenized import HomogenizedODE
from .model import PeelingModel
from .saved import SavedRun
from .solution import Solution
from .structure import jacobians, local_index, phi_extremum, schur_complement, truncated_schur_complement

__all__ = [
    "BifurcationDiagram",
    "StickSlipAnalysis",
    "analyze",
    "bifurcation_diagram",
    "crossings",
    "local_extrema",
    "oscillation",
    "phi_extrema",
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

    :func:`peeljax.structure.phi_extremum` (the search the sweep engine runs in the graph), on
    the host: v ∈ [1e-8, 1e2]·max(V, 1), a log grid refined by bisection in log v.
    """
    model = PeelingModel() if model is None else model
    top, bottom = _phi_extrema_jit(model, jnp.asarray(V, float))
    return float(top), float(bottom)


@eqx.filter_jit  # module level: compiled once per model structure, not per call
def _phi_extrema_jit(model, V):
    return phi_extremum(model, V, "max"), phi_extremum(model, V, "min")


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


def oscillation(ts: np.ndarray, values: np.ndarray, t_start: float = 0.0) -> dict[str, float]:
    """Period, amplitude and mean of an oscillating series over t ≥ ``t_start``.

    The period is the median spacing of the upward crossings of the late mean (NaN with fewer
    than two); the amplitude is half the late peak-to-peak range; ``decay`` is the ratio of the
    last to the first late half-range (< 1 for a damped oscillation), NaN with fewer than two
    cycles.
    """
    ts, values = np.asarray(ts, float), np.asarray(values, float)
    late = (ts >= t_start) & np.isfinite(values)
    if late.sum() < 3:
        return {"period": float("nan"), "amplitude": float("nan"), "mean": float("nan"), "decay": float("nan")}
    t, x = ts[late], values[late]
    mean = float(np.mean(x))
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
    ``schur`` (J_t), ``local_index``, ``near_singular`` (|J_t| < threshold), ``constraint_residual``.
    Events: ``stick_to_slip`` and ``slip_to_stick`` times, ``schur_sign_changes`` (J_t = 0 crossed
    between samples), ``bifurcation_times`` (those and the local minima of |J_t| below the
    threshold: Theorem 3's points, as far as the output grid resolves them). Cycle measures of
    v after ``t_transient``: ``period``, ``amplitude``, ``v_mean``, ``decay``, and the extrema
    ``v_max_times``/``v_max``/``v_min_times``/``v_min``.
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
    extra: dict = field(default_factory=dict)

    @property
    def min_abs_schur(self) -> float:
        """min |J_t| over the valid output times."""
        values = np.abs(self.schur[self.valid & np.isfinite(self.schur)])
        return float(values.min()) if values.size else float("nan")

    @property
    def max_local_index(self) -> int:
        values = self.local_index[self.valid]
        return int(values.max()) if values.size else 0

    def fraction(self, mask_name: str) -> float:
        """Fraction of the valid output times where ``stick``, ``slip`` or ``near_singular`` holds."""
        mask = getattr(self, mask_name)
        n = int(self.valid.sum())
        return float((mask & self.valid).sum() / n) if n else float("nan")

    def __repr__(self) -> str:
        """A few lines: the run, its phases and events, the cycle measures (``summary()``: all numbers)."""
        valid = int(self.valid.sum())
        outcome = "completed" if self.completed else "stopped"
        return (
            f"StickSlipAnalysis(V = {self.V:g} m/s, tau = {self.tau:g} s, {outcome} at t = {self.t_stop:.6g} s, "
            f"{valid} valid of {self.ts.size} output times,\n"
            f"  stick {self.fraction('stick'):.0%}, slip {self.fraction('slip'):.0%} of the time; "
            f"{self.stick_to_slip.size} stick -> slip and {self.slip_to_stick.size} slip -> stick events; "
            f"{self.bifurcation_times.size} near-singular points (min |J_t| = {self.min_abs_schur:.3g} N s/m, "
            f"local index <= {self.max_local_index}),\n"
            f"  v after t = {self.t_transient:.4g} s: mean {self.v_mean:.4g} m/s, amplitude {self.amplitude:.4g} m/s, "
            f"period {self.period:.4g} s, decay {self.decay:.3g})"
        )

    def summary(self) -> dict:
        """Plain-Python numbers for JSON output and tables."""
        return {
            "V": self.V,
            "tau": self.tau,
            "t_stop": self.t_stop,
            "completed": self.completed,
            "stick_fraction": self.fraction("stick"),
            "slip_fraction": self.fraction("slip"),
            "n_stick_to_slip": int(self.stick_to_slip.size),
            "n_slip_to_stick": int(self.slip_to_stick.size),
            "n_bifurcation_points": int(self.bifurcation_times.size),
            "bifurcation_times": [float(t) for t in self.bifurcation_times],
            "min_abs_schur": self.min_abs_schur,
            "max_local_index": self.max_local_index,
            "period": self.period,
            "amplitude": self.amplitude,
            "v_mean": self.v_mean,
            "decay": self.decay,
        }


def _branch(v: np.ndarray, v_top: float, v_bottom: float) -> np.ndarray:
    branch = np.where(v < v_top, 0, np.where(np.isnan(v_bottom) | (v < v_bottom), 1, 2))
    return np.where(np.isfinite(v), branch, -1).astype(np.int8)


def _analyze_one(ts, ys, valid, t_stop, completed, struct, model, V, tau, threshold, t_transient, v_ext):
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
    t_max, x_max, t_min, x_min = local_extrema(ts, v)
    late_max, late_min = t_max >= t_transient, t_min >= t_transient
    osc = oscillation(ts, v, t_transient)
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
        stick=valid & (phi_v > 0),
        slip=valid & (phi_v < 0),
        branch=_branch(v, *v_ext),
        schur=J,
        local_index=np.where(valid, struct["local_index"], 0).astype(np.int32),
        near_singular=near,
        constraint_residual=np.where(valid, struct["constraint_residual"], np.nan),
        stick_to_slip=crossings(ts, phi_v, "down"),
        slip_to_stick=crossings(ts, phi_v, "up"),
        schur_sign_changes=sign_changes,
        bifurcation_times=bif,
        v_max_times=t_max[late_max],
        v_max=x_max[late_max],
        v_min_times=t_min[late_min],
        v_min=x_min[late_min],
        period=osc["period"],
        amplitude=osc["amplitude"],
        v_mean=osc["mean"],
        decay=osc["decay"],
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
        t_transient: cycle measures use t ≥ this (default: the second half of the output span).

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
            )
        )
    return out if batch_shape else out[0]


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
