"""Profile-likelihood intervals of a table fit, honest across the jumps of a bifurcation.

The linearized interval θ̂_j ± q·SE_j assumes χ² quadratic in θ. Where a row's attractor
changes within it (a bifurcation: its statistics jump), χ² is not even continuous. The profile

    χ²_p(θ_j) = min over the other coefficients of χ²(θ),   θ_j fixed,

is defined whatever χ² does, and {θ_j : χ²_p(θ_j) ≤ χ²_min + s²·q²} is the profile-likelihood
confidence set (q the same quantile as the linearized interval's — Student's t where the
covariance is scaled by s² = χ²/dof, else the normal one — so that both coincide for a
quadratic χ²; Venzon & Moolgavkar 1988, lmfit's ``conf_interval``). Where two branches of
attractors both fit, the set is a union of intervals: the data cannot tell them apart.

:func:`profile` walks θ_j away from the optimum in both directions in steps of q·SE_j/``STEPS``
— each grid point a Levenberg–Marquardt fit of the others started from its neighbour's optimum,
whose attractors it follows (:class:`~peeljax.fit.table_rows.TableRows`) — until χ²_p exceeds
the threshold by ``BEYOND`` or after ``MAX_STEPS``. An end of the set between two grid points
is interpolated linearly in χ²_p where both lie on the same attractors, and bisected
(``BISECTIONS`` times) where an attractor changed between them: χ²_p jumps there.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .levenberg_marquardt import LevenbergMarquardt

__all__ = ["Profile", "profile"]

STEPS = 3  # grid points per linearized half-width
MAX_STEPS = 9  # at most this many grid points each way (3 linearized half-widths)
BEYOND = 1.5  # stop a direction once χ²_p − χ²_min exceeds BEYOND × the threshold
BISECTIONS = 3
INNER_ITERATIONS = 6  # Levenberg–Marquardt evaluations of the other coefficients per grid point
# the others' fit at a grid point stops once its Gauss–Newton step would lower χ²_p by at most this
# share of the threshold: χ²_p is then known to that share, an end of the set to ~half of it in
# linearized half-widths (tests/test_fit_attractors.py; on five draws of the two-coefficient coverage
# problem the ends moved by < 1e-3 half-widths and the profiles took half the evaluations)
INNER_ATOL = 1e-3


@dataclasses.dataclass(frozen=True)
class Profile:
    """One coefficient's profile (module docstring).

    Attributes:
        name: the coefficient; level: the confidence level; threshold: s²·q², the rise of χ²_p
            allowed; values: the grid of the coefficient (increasing); chi2: χ²_p − χ²_min there;
        intervals: the confidence set, a list of (lo, hi) (more than one: a union);
        jumps: the values between which a row's attractor changed (a bifurcation);
        evaluations: model evaluations spent.
    """

    name: str
    level: float
    threshold: float
    values: np.ndarray
    chi2: np.ndarray
    intervals: tuple[tuple[float, float], ...]
    jumps: tuple[tuple[float, float], ...]
    evaluations: int
    lowest: object = dataclasses.field(default=None, repr=False, compare=False)  # the grid's Point of least χ²

    def as_dict(self) -> dict:
        return {
            "name": self.name, "level": self.level, "threshold": self.threshold,
            "values": [float(x) for x in self.values], "delta_chi2": [float(x) for x in self.chi2],
            "intervals": [list(i) for i in self.intervals], "jumps": [list(j) for j in self.jumps],
            "evaluations": self.evaluations,
        }  # fmt: skip


def profile(rows, best, j: int, *, se_log: float, threshold: float, level: float, c_hat: float,
            fit_rtol: float, fit_atol: float, valley=None) -> Profile:  # fmt: skip
    """The profile of coefficient ``j`` (module docstring) about the optimum ``best`` (a
    :class:`~peeljax.fit.table_rows.Point`) of ``rows``; ``se_log``: its linearized standard
    error in log c; ``c_hat``: its fitted value."""
    p = best.z.size
    others = [k for k in range(p) if k != j]
    chi2_min = float(best.r @ best.r)
    h = threshold**0.5 * max(se_log, 1e-12) / STEPS  # √threshold = q·s: a linearized half-width
    evaluations = 0
    # LevenbergMarquardt's Gauss–Newton test scales fit_atol by max(1, χ²/dof)
    dof = max(best.r.size - len(others), 1)
    inner_atol = max(fit_atol, INNER_ATOL * threshold / max(1.0, chi2_min / dof))

    def optimise(delta, start):
        """χ²_p at θ_j = θ̂_j + delta, the others fitted from ``start`` (a Point)."""
        nonlocal evaluations
        z_j = best.z[j] + delta
        if not others:
            point = rows.evaluate(np.array([z_j]), start)
            evaluations += 1
            return point
        z0 = start.z.copy()
        if valley is not None:  # along the linearized valley: the others' optimum moves by Cov_oj/Cov_jj·Δθ_j
            z0 = z0 + valley * (z_j - z0[j])
        z0[j] = z_j
        point = rows.evaluate(z0, start)
        evaluations += 1
        run = LevenbergMarquardt(z0[others], point.r, point.J[:, others], point.v_range, fit_rtol=fit_rtol, fit_atol=inner_atol,
                                 max_iterations=INNER_ITERATIONS, state=point)  # fmt: skip
        while run.reason is None:
            trial = np.insert(run.trial(), j, z_j)
            q = rows.evaluate(trial, run.state)
            evaluations += 1
            run.take(q.r, q.J[:, others], q.v_range, state=q, crossed=bool(q.changes))
        return run.state

    def chi2(point):
        return float(point.r @ point.r) - chi2_min

    grid = {0.0: best}
    for sign in (1.0, -1.0):
        point = best
        for step in range(1, MAX_STEPS + 1):
            point = grid[sign * step * h] = optimise(sign * step * h, point)
            if chi2(point) > BEYOND * threshold:
                break
    deltas = np.array(sorted(grid))
    points = [grid[d] for d in deltas]
    rise = np.array([chi2(q) for q in points])
    inside = rise <= threshold
    jumps, intervals = [], []

    def edge(k_in: int, k_out: int) -> float:
        """The end of the set between grid points k_in (inside) and k_out (outside)."""
        a, b = deltas[k_in], deltas[k_out]
        pa, pb = points[k_in], points[k_out]
        if pa.branch == pb.branch:
            ra, rb = rise[k_in], rise[k_out]
            return a + (b - a) * (threshold - ra) / (rb - ra) if rb != ra else b
        jumps.append(tuple(sorted((c_hat * math.exp(a), c_hat * math.exp(b)))))
        for _ in range(BISECTIONS):  # the jump between a and b
            m = 0.5 * (a + b)
            pm = optimise(m, pa)
            if chi2(pm) <= threshold and pm.branch == pa.branch:
                a, pa = m, pm
            else:
                b, pb = m, pm
        return 0.5 * (a + b)

    k = 0
    while k < deltas.size:
        if not inside[k]:
            k += 1
            continue
        start = k
        while k + 1 < deltas.size and inside[k + 1]:
            k += 1
        lo = deltas[start] if start == 0 else edge(start, start - 1)
        hi = deltas[k] if k == deltas.size - 1 else edge(k, k + 1)
        intervals.append((c_hat * math.exp(lo), c_hat * math.exp(hi)))
        k += 1
    for k in range(deltas.size - 1):  # jumps inside the set too
        if points[k].branch != points[k + 1].branch:
            pair = tuple(sorted((c_hat * math.exp(deltas[k]), c_hat * math.exp(deltas[k + 1]))))
            if pair not in jumps:
                jumps.append(pair)
    return Profile(name="", level=level, threshold=threshold, values=c_hat * np.exp(deltas), chi2=rise,
                   intervals=tuple(intervals), jumps=tuple(sorted(jumps)), evaluations=evaluations,
                   lowest=points[int(np.argmin(rise))])  # fmt: skip
