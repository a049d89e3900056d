"""Levenberg–Marquardt driven from the host, one evaluation at a time: the table fit's solver.

The model's residuals r(θ) and their forward-mode Jacobian come from one evaluation (a compiled
program, or a host procedure that follows each row's attractor); the solver proposes the next
point (:meth:`LevenbergMarquardt.trial`) and judges the evaluation there
(:meth:`LevenbergMarquardt.take`): Nielsen's damping update with Marquardt's diagonal scaling,
and stop reasons that say which test stopped it (:data:`STOP_REASONS`). Used by the table fit's
rounds (:mod:`peeljax.fit.table`), the records fit and each grid point of a profile
(:mod:`peeljax.fit.profile`).
"""

from __future__ import annotations

import numpy as np

from .window_rows import MISSING_RESIDUAL

__all__ = ["CONVERGED", "FLOOR", "STOP_REASONS", "LevenbergMarquardt", "missing_entries"]


def missing_entries(r) -> int:
    """The entries at ``MISSING_RESIDUAL``: statistics the runs did not produce."""
    return int(np.sum(np.asarray(r) == MISSING_RESIDUAL))


# Why Levenberg–Marquardt stopped (the converged reasons first), and each reason in words.
CONVERGED = ("gauss-newton", "loss", "floor", "bifurcation")
FLOOR = 0.25  # ‖J·δ‖²: a step this small is within 0.5 standard errors
STOP_REASONS = {
    "gauss-newton": "converged: the Gauss-Newton step would lower chi2 by less than fit_atol "
    "(the optimum within sqrt(fit_atol) standard errors)",
    "floor": f"converged to the rough floor of chi2: a step of at most {FLOOR**0.5:g} standard errors "
    "(|J step|^2 <= 0.25) does not lower chi2 (an orbit's period and slip duration jump where it gains or loses a "
    "slip per period, a row's statistics where it loses its orbit, a window statistic where a slip crosses the "
    "window's edge; a row whose derivative is too steep to use moves on its own)",
    "bifurcation": f"converged at a bifurcation: a step of at most {FLOOR**0.5:g} standard errors crosses to another "
    "attractor of a row, where chi2 is higher (the optimum lies on the edge of its branch; see the profile intervals)",
    "loss": "converged: the last step and the Gauss-Newton step lower chi2 by less than fit_rtol (relative)",
    "max_iterations": "not converged: max_iterations model evaluations reached",
    "stalled": "not converged: no step lowers chi2 any more (the damping grew past 1e9): the "
    "residuals' own numerical noise, or a start where the runs lose their stick-slip",
    "nonfinite": "not converged: the residuals or the Jacobian at the start are not finite",
}


class LevenbergMarquardt:
    """One Levenberg–Marquardt run on χ²(z) = ‖r(z)‖² (Nielsen's damping update, Marquardt's
    diagonal scaling), driven from outside: :meth:`trial` proposes the next point, :meth:`take`
    judges r and J there (every evaluation gives both from one forward-mode trace, so an
    accepted trial point needs no second run). ``reason`` is set once it stops, on the first of:

    * ``gauss-newton``: the Gauss–Newton step's predicted decrease of χ², ‖J·δ_GN‖², is at most
      fit_atol·max(1, χ²/dof) — the optimum is within √fit_atol standard errors;
    * ``loss``: an accepted step lowered χ² by at most fit_rtol·χ², and the Gauss–Newton
      step would too;
    * ``floor``: a trial refused whose step moves the linearised residuals by ‖J·δ‖² ≤ ``FLOOR``
      = 0.25, half a standard error: χ² is rough at that scale and the optimum is found to it
      (an orbit's per-slip averages jump where it gains or loses a slip per period, by 2–3 σ at
      1 % noise, ``benchmarks/results/fit_roughness_wide_c1.md``; a row's statistics where it
      loses its orbit; a window statistic where a slip crosses the window's edge);
    * ``max_iterations`` evaluations; ``stalled``: the damping λ past 1e9 (no descent found);
      ``nonfinite`` r or J at the start.

    A trial point where the runs lose a statistic the current point has (no slip in a window) is
    refused whatever its χ².
    """

    def __init__(self, z, r, J, v_range, *, fit_rtol, fit_atol, max_iterations, state=None):
        self.z, self.r, self.J, self.v_range = np.asarray(z, float), r, J, v_range
        self.state = state  # what the caller keeps of the current point (the attractors it follows)
        self.fit_rtol, self.fit_atol, self.max_iterations = fit_rtol, fit_atol, max_iterations
        self.evaluations, self.chi2 = 1, float(r @ r)
        self.history, self.reason, self.step = [self.chi2], None, None
        if not (np.isfinite(self.chi2) and np.all(np.isfinite(J))):
            self.reason = "nonfinite"
            return
        self.lam = 1e-3  # dimensionless: the damping is λ·diag(JᵀJ) (Marquardt's scaling)
        self.lam_max, self.nu = 1e9, 2.0
        self._check()

    def _check(self):
        """Set ``reason`` where the Gauss–Newton test or the budget stops the run."""
        m, p = self.J.shape
        gauss_newton = np.linalg.lstsq(self.J, -self.r, rcond=None)[0]
        self.predicted_gn = float(np.sum((self.J @ gauss_newton) ** 2))
        if self.predicted_gn <= self.fit_atol * max(1.0, self.chi2 / max(m - p, 1)):
            self.reason = "gauss-newton"
        elif self.evaluations >= self.max_iterations:
            self.reason = "max_iterations"

    def trial(self) -> np.ndarray:
        """The next point to evaluate (the current one once stopped)."""
        if self.reason is not None:
            return self.z
        A, g = self.J.T @ self.J, self.J.T @ self.r
        D = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        self.step = np.linalg.solve(A + self.lam * np.diag(D), -g)
        self.predicted = float(-(2 * g @ self.step + self.step @ A @ self.step))
        return self.z + self.step

    def take(self, r, J, v_range, state=None, crossed: bool = False) -> None:
        """r, J and the v range at :meth:`trial`'s point; ``state``: kept with it where it is
        accepted; ``crossed``: the trial point lies across a bifurcation from the current one."""
        if self.reason is not None:
            return
        self.evaluations += 1
        chi2 = float(r @ r)
        rho = (self.chi2 - chi2) / self.predicted if self.predicted > 0 else -1.0
        keeps = missing_entries(r) <= missing_entries(self.r)
        if keeps and np.isfinite(chi2) and np.all(np.isfinite(J)) and rho > 1e-4:
            decrease = self.chi2 - chi2
            self.z, self.r, self.J, self.v_range, self.chi2 = self.z + self.step, r, J, v_range, chi2
            self.state = state
            self.history.append(chi2)
            self.lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
            self.nu = 2.0
            self._check()
            if self.reason is None and decrease <= self.fit_rtol * chi2 and self.predicted_gn <= self.fit_rtol * chi2:
                self.reason = "loss"
        else:
            self.lam *= self.nu
            self.nu *= 2.0
            # the refused step moves the linearised residuals by at most √FLOOR σ in all: χ² is
            # rough at this scale (a slip crossing a window's edge), the optimum found to it
            if float(np.sum((self.J @ self.step) ** 2)) <= FLOOR:
                self.reason = "bifurcation" if crossed else "floor"
            elif self.lam > self.lam_max:
                self.reason = "stalled"
            elif self.evaluations >= self.max_iterations:
                self.reason = "max_iterations"
