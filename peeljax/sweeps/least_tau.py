"""The least resolvable τ (the paper's τ_*, section "Relationship with Bifurcation").

The paper calls τ_* the least τ for which J_t stays invertible along the run, in practice the
least τ for which the α-method integrates [0, t_final] (Figs. 2 and 5–7: below it Newton fails
or an impasse point ends the run early). Completion need not be monotone in τ, so peeljax
defines, for each V and a given mesh and solver:

    τ* = the least tested τ such that every tested τ ≥ τ* completed,
         and τ*·(1 − tau_rtol) was tested and stopped.

The search (all V in parallel; each round is one batched :func:`peeljax.sweep`-engine run):

1. Scan: ``n_points`` τ log-spaced over ``tau_range`` = [lo, hi]. If τ = hi stops, no τ* in
   the range (NaN, ``found = False``); if every τ completes, τ* ≤ lo (``tau_star = lo``,
   ``found = False``). Otherwise the bracket is (largest stopping τ, next tested τ).
2. Refine: each round tests, for every V not yet done, ``n_points`` τ inside the bracket
   (lo, hi): top = hi·(1 − tau_rtol) and top·q^j, j = 1 … n_points − 1, with
   q = min((lo/top)^(1/n_points), 1 − tau_rtol) (those at or below lo are replaced by top). Then
   lo = the largest stopping τ tested so far, hi = the least completing τ tested above it.
   Consecutive points are at most a factor (1 − tau_rtol) apart, so the search ends when
   hi·(1 − tau_rtol) itself was tested: it stopped (τ* = hi found), or, completion being
   non-monotone there, it completed below a larger stopping τ (reported, ``found = False``).
   The bracket's log-width shrinks about n_points-fold per round.

Every round has the same batch shape, so the search compiles once.
"""

from __future__ import annotations

import dataclasses
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Bool, Float

from .._validation import check_truncation
from ..integrators.alpha import AlphaMethod

from ..model import PeelingModel
from .devices import batch_mesh, default_lane_batch, put_lanes, to_host
from .grid import axis, check_parameter
from .integrators import sweep_plan

__all__ = ["LeastTau", "least_tau"]


@dataclasses.dataclass(frozen=True)
class LeastTau:
    """τ* per V (see the module docstring for the definition).

    Attributes:
        V: the pull velocities, shape (m,).
        tau_star: τ* (NaN where even tau_range's upper end stops; tau_range's lower end where
            every tested τ completed).
        tau_below: the largest tested τ that stopped (in [τ*·(1 − tau_rtol), τ*) when found).
        found: True where τ* lies inside tau_range and is bracketed to tau_rtol.
        t_stop_below: where the run at tau_below stopped.
        rounds: batched runs made (the scan included).
        tested: per V, every tested (τ, (completed, t_stop)) in increasing τ.
    """

    V: Float[np.ndarray, " m"]
    tau_star: Float[np.ndarray, " m"]
    tau_below: Float[np.ndarray, " m"]
    found: Bool[np.ndarray, " m"]
    t_stop_below: Float[np.ndarray, " m"]
    rounds: int
    tested: list
    settings: dict

    def as_dict(self) -> dict:
        """τ* per V as JSON-able lists (``V``, ``tau_star``, ``tau_below``, ``found``, ``t_stop_below``) and
        ``rounds``."""
        fields = ("V", "tau_star", "tau_below", "found", "t_stop_below")
        return {name: np.asarray(getattr(self, name)).tolist() for name in fields} | {"rounds": self.rounds}

    def summary(self) -> str:
        """One line per V: τ*, where τ*·(1 − tau_rtol) stopped, and whether τ* was bracketed inside tau_range."""
        lines = []
        for i, V in enumerate(self.V):
            note = "" if self.found[i] else "  (not bracketed inside tau_range)"
            lines.append(f"V = {V:g} m/s: tau* = {self.tau_star[i]:.6g} s (tau*(1-tau_rtol) stops at t = "
                         f"{self.t_stop_below[i]:.4g} s){note}")  # fmt: skip
        return "\n".join(lines)


def check_search(tau_range, tau_rtol, n_points) -> tuple[float, float]:
    """The search's options of :func:`least_tau`, checked (nothing compiles); returns (lo, hi)."""
    try:
        lo, hi = (float(x) for x in tau_range)
    except (TypeError, ValueError):
        raise ValueError(f"tau_range must be two numbers (lo, hi) with 0 < lo < hi, got {tau_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"tau_range must satisfy 0 < lo < hi (finite), got {tau_range!r}")
    if not (isinstance(tau_rtol, (int, float)) and 0 < tau_rtol < 1):
        raise ValueError(f"tau_rtol must lie in (0, 1), got {tau_rtol!r}")
    if isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < 2:
        raise ValueError(f"n_points must be an integer >= 2, got {n_points!r}")
    return lo, hi


def least_tau(
    model: PeelingModel | None = None,
    V: ArrayLike = (1.1, 2.0, 4.0),
    dt: float | None = None,
    t_final: float = 3.0,
    tau_range: tuple[float, float] = (1e-4, 1.0),
    tau_rtol: float = 0.05,
    *,
    n_points: int = 8,
    solver: AlphaMethod | diffrax.AbstractSolver | None = None,
    rho: float = 0.0,
    truncation: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dtmin: float | None = None,
    max_steps: int | None = None,
    max_rounds: int = 40,
    devices=None,
    lane_batch: int | None = None,
) -> LeastTau:
    """τ* for every V: the least τ above which every tested τ completes [0, t_final].

    Args:
        V: pull velocities [m/s] (> 0), searched in parallel.
        dt, t_final: as in :func:`peeljax.simulate`: ``dt=None`` (default) runs error
            control (its default stepper), where a run stops at an impasse point or when its step
            size collapses below ``dtmin``; a number runs the uniform mesh, where it stops at an
            impasse point or when Newton fails at the finest subdivision.
        rtol, atol, dtmin, max_steps: error control's, as in :func:`peeljax.simulate`.
        solver: as in :func:`peeljax.sweep` (default: ``simulate``'s default stepper; the
            uniform mesh, ``dt`` given, is ``AlphaMethod(rho=rho)``).
        tau_range: (lo, hi), 0 < lo < hi: where to search.
        tau_rtol: relative resolution: τ·(1 − tau_rtol) is tested and stops, 0 < tau_rtol < 1.
        n_points: τ values per V and round (the scan's and every refinement's).

    Returns:
        A :class:`LeastTau`.
    """
    model = PeelingModel() if model is None else model
    Vs = axis("V", V)
    check_parameter("V", Vs)
    # τ* is where the homogenized run stops at a fold: fold="stop", the paper's behaviour.
    plan = sweep_plan(solver, rho, dt, t_final, rtol, atol, None, None, dtmin, max_steps, fold="stop")
    lo, hi = check_search(tau_range, tau_rtol, n_points)
    check_truncation(truncation)
    devices = list(jax.devices()) if devices is None else list(devices)
    m = Vs.size
    mesh = batch_mesh(devices)
    width = -(-(m * n_points) // len(devices)) * len(devices)
    lane_batch = default_lane_batch(devices, width) if lane_batch is None else lane_batch
    t_final_array, window = jnp.asarray(float(t_final)), jnp.asarray([0.0, 1.0])

    def run(taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """taus: (m, n_points) → completed and t_stop of each, in one batched run."""
        V_lanes = np.repeat(Vs, n_points)
        tau_lanes = taus.reshape(-1)
        pad = width - V_lanes.size
        V_in = np.concatenate([V_lanes, np.full(pad, V_lanes[-1])])
        tau_in = np.concatenate([tau_lanes, np.full(pad, tau_lanes[-1])])
        V_dev, tau_dev = put_lanes((V_in, tau_in), devices)
        summary = plan.run(model, V_dev, tau_dev, {}, t_final_array, window, truncation, mesh, lane_batch)
        host = to_host({"status": summary.status, "t_stop": summary.t_stop})
        done = (host["status"][: V_lanes.size] == 0).reshape(m, n_points)
        t_stop = host["t_stop"][: V_lanes.size].reshape(m, n_points)
        return done, t_stop

    # 1. the scan
    history: list[dict[float, tuple[bool, float]]] = [{} for _ in range(m)]  # per V: τ → (completed, t_stop)

    def record(points, done, t_stop):
        for j in range(m):
            for k in range(n_points):
                history[j][float(points[j, k])] = (bool(done[j, k]), float(t_stop[j, k]))

    scan = np.broadcast_to(np.geomspace(lo, hi, n_points), (m, n_points)).copy()
    record(scan, *run(scan))
    rounds = 1
    state = [_bracket(h, tau_rtol) for h in history]
    active = np.array([s[3] is None for s in state])

    # 2. refinement rounds: n_points τ per V from hi·(1 − tau_rtol) down, ratio ≤ 1 − tau_rtol
    while active.any() and rounds < max_rounds:
        points = scan.copy()  # placeholders for finished V (results ignored)
        for j in np.flatnonzero(active):
            lower, upper = state[j][0], state[j][1]
            top = upper * (1.0 - tau_rtol)
            q = min((lower / top) ** (1.0 / n_points), 1.0 - tau_rtol) if top > lower else 1.0
            candidates = top * q ** np.arange(n_points)
            points[j] = np.where(candidates > lower, candidates, top)
        done, t_stop = run(points)
        rounds += 1
        for j in np.flatnonzero(active):
            for k in range(n_points):
                history[j][float(points[j, k])] = (bool(done[j, k]), float(t_stop[j, k]))
            state[j] = _bracket(history[j], tau_rtol)
            active[j] = state[j][3] is None
    lower, upper, t_below = np.array([s[:3] for s in state], float).reshape(-1, 3).T
    settings = {**plan.settings(), "t_final": float(t_final), "tau_range": [lo, hi], "tau_rtol": float(tau_rtol),
                "n_points": n_points, "truncation": truncation}  # fmt: skip
    found = np.array([s[3] is True for s in state])
    return LeastTau(V=Vs, tau_star=upper, tau_below=lower, found=found, t_stop_below=t_below, rounds=rounds,
                    tested=[sorted(h.items()) for h in history], settings=settings)  # fmt: skip


def _bracket(history: dict[float, tuple[bool, float]], tau_rtol: float):
    """(lower, upper, t_stop at lower, verdict) from the tested τ of one V.

    lower: the largest stopping τ (NaN if none), upper: the least completing τ above it
    (= τ*; NaN if none; the least tested τ if none stops). verdict: True when
    upper·(1 − tau_rtol) was tested and stopped (τ* found), False when the search cannot go on
    (no stop, nothing completes above the largest stop, or upper·(1 − tau_rtol) completed while a
    larger τ stopped), None to continue.
    """
    taus = np.array(sorted(history))
    done = np.array([history[t][0] for t in taus])
    if done.all():
        return math.nan, float(taus[0]), math.nan, False
    k = int(np.flatnonzero(~done)[-1])
    lower, t_below = float(taus[k]), history[float(taus[k])][1]
    if k == taus.size - 1:
        return lower, math.nan, t_below, False
    upper = float(taus[k + 1])
    top = upper * (1.0 - tau_rtol)
    near = [t for t in history if abs(t - top) <= 1e-12 * top]
    if near:
        return lower, upper, t_below, (not history[near[0]][0]) or False
    return lower, upper, t_below, None
