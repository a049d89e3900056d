"""The problems of ``compare.py`` (issue 6: P1–P5): their constants, grids, references and calibration helpers.

Nothing here is timed. P1/P2 integrate one trajectory at V = ``V`` on t ∈ [0, ``T_FINAL``] with v
compared at the 301 times ``GRID`` against :func:`reference` (diffrax Kvaerno5 at ``REF_RTOL``);
P3 is the batch ``p3_grid`` (``P3_VELOCITIES`` × τ log-spaced in ``P3_TAU_RANGE``), checked on
``p3_subsample`` with :func:`relative_errors` and each method's setting picked by :func:`calibrate`;
P4 is the loss of v at ``P4_TIMES`` (data ``peers.casadi_peer.p4_data``, taken at :func:`p4_coefficients`) whose
gradient with respect to φ's 14 coefficients (``COEFFICIENT_NAMES``) is measured by
:func:`scaled_error`; P5 runs the direct DAE at a few V (``compare.py``).

This module is the floor of the suite: it imports no other module of ``benchmarks/`` (the peers,
``compare.py`` and ``compare_report.py`` import it), so the imports have no circle.
"""

from __future__ import annotations

import math
import sys

import numpy as np

V = 1.1
T_FINAL = 3.0
GRID = np.linspace(0.0, T_FINAL, 301)
TARGET = 1e-3
REF_RTOL, REF_ATOL = 1e-11, 1e-13
ADAPTIVE_ALPHA_ATOL = 1e-3  # the adaptive α-method runs at atol = ADAPTIVE_ALPHA_ATOL·rtol

COEFFICIENT_NAMES = ("c1", "p1", "c2", "p2", "c3", "c4", "c5", "p5", "c6", "c7", "p7", "c8", "p8", "p9")
PAPER_PHI = (400.0, 0.35, 110.0, 0.15, 130.0, 11.0, 2.0, 1.5, 415.0, 45.0, 0.4, 0.35, 2.15, 0.5)

# (P3) a batch of trajectories
P3_VELOCITIES = (1.1, 2.0, 4.0, 8.0)
P3_TAU_RANGE = (0.005, 0.5)
P3_SAVE_DT = 0.01  # output_times(0.01, 3) is GRID (checked by compare.py's P3)
# Loose to tight, atol = ADAPTIVE_ALPHA_ATOL·rtol. The error falls only about as rtol^(2/3) (P2: error ∝
# steps^-2, steps ∝ rtol^(-1/3)), so the rungs are half a decade apart.
# One ladder for every error-controlled P3 method (1, 2, 5 per decade): each gets the loosest rung
# that meets the target, so no method gains from where its rungs happen to fall.
P3_RTOL_LADDER = tuple(float(f"{m}e{e}") for e in range(-2, -8, -1) for m in (5, 2, 1))
P3_ADAPTIVE_RTOLS = tuple(r for r in P3_RTOL_LADDER if r <= 1e-3)
# The tuned row of P3: ρ = 0.5 (error constant 1/9 against 1/3 at the default ρ = 0) and the
# peers' atol = 1e-2·rtol; the levers measured in ``lane_levers.py``.
P3_TUNED_RHO, P3_TUNED_ATOL = 0.5, 1e-2

# (P4) the gradient of a trajectory loss
P4_TAU, P4_T_FINAL, P4_DEN = 0.1, 1.0, 82
P4_TIMES = np.arange(round(P4_T_FINAL * P4_DEN) + 1) / P4_DEN
P4_PERTURBATION = ("c1", 1.02)
P4_FD_STEP = 1e-4  # relative step of the central differences


def one_line(error: Exception) -> str:
    """An exception as one short line that fits in a markdown table cell."""
    text = " ".join(str(error).split()).replace("|", "/")
    return f"{type(error).__name__}: {text[:70]}"


# --------------------------------------------------------------------------- (P1, P2) one trajectory
def reference(tau):
    """v on ``GRID`` by diffrax Kvaerno5 at rtol ``REF_RTOL``, atol ``REF_ATOL`` (``peeljax.simulate_reference``)."""
    import jax

    import peeljax

    sol = peeljax.simulate_reference(V=V, tau=tau, dt=T_FINAL / 300, t_final=T_FINAL, rtol=REF_RTOL, atol=REF_ATOL)
    v = np.asarray(jax.block_until_ready(sol.ys))[:, 3]
    if not bool(sol.completed):
        raise RuntimeError(f"the reference stopped at t = {float(sol.t_stop)} (tau = {tau})")
    return v


def cheapest_at(rows, target):
    """The fastest checked row (``status == "ok"``, timed) whose error is ≤ ``target``, or None."""
    ok = [r for r in rows if r.get("status") == "ok" and r["error"] <= target]
    return min(ok, key=lambda r: r["median_s"]) if ok else None


# --------------------------------------------------------------------------- (P3) a batch of trajectories
def p3_grid(n_tau):
    """(V, τ) of the batch: every V of ``P3_VELOCITIES`` with ``n_tau`` τ log-spaced in ``P3_TAU_RANGE``."""
    taus = np.geomspace(*P3_TAU_RANGE, n_tau)
    return np.repeat(np.asarray(P3_VELOCITIES, float), n_tau), np.tile(taus, len(P3_VELOCITIES))


def p3_subsample(n_tau, per_v):
    """Indices of ``per_v`` τ per V spread over [τ_min, τ_max] (both ends included)."""
    j = np.unique(np.linspace(0, n_tau - 1, per_v).round().astype(int))
    return np.concatenate([k * n_tau + j for k in range(len(P3_VELOCITIES))])


def relative_errors(v, v_ref):
    """Per trajectory: max over ``GRID`` of |v − v_ref| / max |v_ref| (inf where v stopped)."""
    v, v_ref = np.atleast_2d(v), np.atleast_2d(v_ref)
    error = np.max(np.abs(v - v_ref), axis=1) / np.max(np.abs(v_ref), axis=1)
    return np.where(np.all(np.isfinite(v), axis=1), error, np.inf)


def calibrate(name, values, run_sub, v_ref, calibration):
    """Settings from the cheapest on; stop at the first whose max error on the subsample is ≤ ``TARGET``.

    ``run_sub(setting)`` returns v on the checked trajectories (rows of ``v_ref``). Every setting
    tried is recorded in ``calibration[name]`` as (setting, max error, completed or "failed: …").
    Returns ((setting, error, completed) of the setting chosen, whether it met ``TARGET``); when
    none did, the most accurate one.
    """
    tried = []
    for setting in values:
        try:
            v = run_sub(setting)
            errors = relative_errors(v, v_ref)
            tried.append((setting, float(np.max(errors)), int(np.sum(np.isfinite(errors)))))
        except Exception as error:  # noqa: BLE001 (a failing setting is reported)
            tried.append((setting, math.inf, f"failed: {one_line(error)}"))
        if tried[-1][1] <= TARGET:
            break
    calibration[name] = tried
    print(f"  [P3 {name}: {tried}]", file=sys.stderr, flush=True)
    ok = [t for t in tried if t[1] <= TARGET]
    return (ok[0] if ok else min(tried, key=lambda t: t[1])), bool(ok)


# --------------------------------------------------------------------------- (P4) the gradient of a trajectory loss
def p4_coefficients():
    """Where the gradient is taken: the paper's φ with c1 raised by 2 % (the data come from the paper's φ)."""
    c = np.array(PAPER_PHI)
    c[COEFFICIENT_NAMES.index(P4_PERTURBATION[0])] *= P4_PERTURBATION[1]
    return c


def central_differences(value, c):
    """dL/dc_i ≈ (L(c_i(1 + h)) − L(c_i(1 − h)))/(2h·c_i), 28 forward runs."""
    g = np.empty(c.size)
    for i in range(c.size):
        plus, minus = c.copy(), c.copy()
        plus[i] *= 1 + P4_FD_STEP
        minus[i] *= 1 - P4_FD_STEP
        g[i] = (value(plus) - value(minus)) / (2 * P4_FD_STEP * c[i])
    return g


def scaled_error(g, g_ref, c):
    """max_i |c_i·(g − g_ref)_i| / max_i |c_i·g_ref,i|: the error of the sensitivities to relative changes of c."""
    g, g_ref, c = np.asarray(g), np.asarray(g_ref), np.asarray(c)
    return float(np.max(np.abs(c * (g - g_ref))) / np.max(np.abs(c * g_ref)))
