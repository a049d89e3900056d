"""Uncertainties of fitted coefficients from the Jacobian of the residuals, as curve_fit and lmfit report them.

At the optimum θ̂ of a least-squares fit with residuals r(θ) (m of them, p free log
coefficients θ, c = c_start·exp(θ)) and Jacobian J = ∂r/∂θ = U·S·Vᵀ:

    Cov(θ) = s²·(JᵀJ)⁻¹ = s²·V·S⁻²·Vᵀ,   Cov(c) = diag(c)·Cov(θ)·diag(c),

χ² = ‖r‖², dof = m − p, and s² the covariance's scale (``scaled``):

* ``"auto"`` (the table fit's default): s² = max(1, χ²/dof) where the data carry standard
  deviations — the residuals are (model − data)/σ, so χ²/dof ≈ 1 when the σ are right, and a
  larger χ²/dof says they are too small (or the model misses something): the covariance is
  inflated by it as ``scipy.optimize.curve_fit`` (``absolute_sigma=False``) and lmfit
  (``scale_covar=True``) do, but never shrunk below the σ given;
* ``True``: s² = χ²/dof always (curve_fit's default; the data without standard deviations,
  whose residuals are in units of each column's RMS);
* ``False``: s² = 1 (the σ taken as exact: curve_fit's ``absolute_sigma=True``).

Standard errors are √diag(Cov(c)), the correlation Cov_ij/(σ_i·σ_j).

**Singular directions** (:attr:`Uncertainty.directions`): the columns V_k of V are the
combinations Σ_j V_jk·log c_j the data determine independently, each to the standard error
s/S_k (relative: a change of the product Π_j c_j^V_jk by that fraction). Where coefficients are
strongly correlated, a coefficient alone is poorly determined while a combination (typically
along the valley of two terms of φ that compensate) is determined well; the summary then lists
the directions from the best to the worst determined.

**Undetermined coefficients**: a singular value below ``rcond``·S_max means a direction in
θ the data do not fix; the coefficients that make up that direction (|V_ij| ≥ 0.3) are named
in :attr:`Uncertainty.undetermined`, their standard errors are infinite, and the covariance
is that of the determined directions only.

**Confidence intervals** at level q use Student's t quantile with m − p degrees of freedom
when s² is estimated (Cornish–Fisher's expansion about the normal quantile; within 1.1e-3 of
the exact quantile at 5 degrees of freedom, closer above: ``tests/test_fit_table.py``), the normal quantile otherwise. **The band on
φ(v, V)** propagates Cov(θ) linearly: Var φ = gᵀ·Cov(θ)·g, g = ∂φ/∂θ by autodiff.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri

from ..adhesion import AdhesionLaw
from .parameters import law_from

__all__ = ["Uncertainty", "quantile", "uncertainty_from_jacobian"]

UNDETERMINED_RCOND = 1e-6
CORRELATED = 0.9  # |correlation| from which the summary lists the singular directions
SCALE_RULES = ("auto", True, False)
_MEMBER = 0.3  # |V_ij| from which a coefficient is part of an undetermined direction


def quantile(level: float, dof: float | None) -> float:
    """The two-sided quantile of ``level`` (0.95 → 1.96 for the normal): Student's t with ``dof``
    degrees of freedom (Cornish–Fisher), or the normal one where ``dof`` is None."""
    z = float(ndtri(0.5 + level / 2))
    if dof is None or not math.isfinite(dof):
        return z
    nu = max(float(dof), 1.0)
    return (z + (z**3 + z) / (4 * nu) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * nu**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * nu**3))  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """The covariance of the fitted coefficients and what follows from it (module docstring).

    Attributes:
        names: the free coefficients, in order.
        values: their fitted values c.
        covariance: Cov(c) (p × p).
        covariance_log: Cov(θ), θ = log(c/c_start) (p × p).
        standard_errors: √diag Cov(c) (inf for undetermined coefficients).
        correlation: Cov_ij/(σ_i·σ_j) (NaN where a σ is infinite or zero).
        singular_values: of J = ∂r/∂θ, decreasing.
        undetermined: the coefficients the data do not determine (module docstring).
        residual_variance: s², the covariance's scale (module docstring).
        dof: m − p, the residuals minus the free coefficients.
        scaled: whether the covariance was scaled by χ²/dof (s² ≠ 1).
        chi2: χ² = ‖r‖² at the optimum.
        directions: V (p × p, column k the k-th singular direction of J in log c).
        scale_rule: how s² was chosen (``"auto"``, ``"always"``, ``"never"``).
    """

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    covariance_log: np.ndarray
    standard_errors: np.ndarray
    correlation: np.ndarray
    singular_values: np.ndarray
    undetermined: tuple[str, ...]
    residual_variance: float
    dof: int
    scaled: bool
    chi2: float = math.nan
    directions: np.ndarray | None = None
    scale_rule: str = "always"

    @property
    def chi2_dof(self) -> float:
        """χ²/dof (NaN without degrees of freedom)."""
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def direction_errors(self) -> np.ndarray:
        """The standard error s/S_k of each singular direction's combination Σ_j V_jk·log c_j
        (inf for an undetermined one)."""
        S = np.asarray(self.singular_values, float)
        with np.errstate(divide="ignore"):
            return np.where(S > 0, math.sqrt(self.residual_variance) / np.where(S > 0, S, 1.0), np.inf)

    def combinations(self) -> list[tuple[str, float]]:
        """The singular directions as text, ``"+0.71·log c1 −0.70·log c6"``, with their
        standard errors; from the best to the worst determined."""
        if self.directions is None:
            return []
        out = []
        for k, err in enumerate(self.direction_errors()):
            w = self.directions[:, k]
            w = w if w[np.argmax(np.abs(w))] > 0 else -w  # sign: the largest weight positive
            terms = [f"{x:+.2f}·log {n}" for n, x in zip(self.names, w) if abs(x) >= 0.05]
            out.append((" ".join(terms), float(err)))
        return out

    def max_correlation(self) -> float:
        """The largest |correlation| between two different coefficients (0 for one)."""
        p = len(self.names)
        if p < 2:
            return 0.0
        off = np.abs(self.correlation[~np.eye(p, dtype=bool)])
        return float(np.nanmax(off)) if np.any(np.isfinite(off)) else math.nan

    def quantile(self, level: float = 0.95) -> float:
        return quantile(level, self.dof if self.scaled else None)

    def intervals(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Each coefficient's confidence interval value ± q·σ at ``level``."""
        q = self.quantile(level)
        return {n: (float(v - q * s), float(v + q * s)) for n, v, s in zip(self.names, self.values, self.standard_errors)}

    def phi_band(self, law: AdhesionLaw, v, V, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """(φ(v, V), its half-width q·σ_φ) on the v given, by propagating Cov(θ) through φ."""
        v = jnp.asarray(v, float)
        names = self.names

        def phi(theta):
            return law_from(dict(zip(names, theta)), law)(v, V)

        theta0 = jnp.zeros(len(names))
        g = jax.jacfwd(phi)(theta0)  # (n_v, p)
        var = jnp.einsum("ip,pq,iq->i", g, jnp.asarray(self.covariance_log), g)
        return np.asarray(phi(theta0)), self.quantile(level) * np.sqrt(np.maximum(np.asarray(var), 0.0))

    def as_dict(self) -> dict:
        def finite(x):  # strict JSON: None for NaN and infinities, entry by entry
            return [finite(y) for y in x] if np.ndim(x) else (float(x) if math.isfinite(x) else None)

        return {
            "names": list(self.names), "values": [float(x) for x in self.values],
            "standard_errors": finite(self.standard_errors), "correlation": finite(np.atleast_2d(self.correlation)),
            "covariance": finite(np.atleast_2d(self.covariance)),
            "singular_values": [float(x) for x in self.singular_values], "undetermined": list(self.undetermined),
            "residual_variance": self.residual_variance, "dof": self.dof, "scaled": self.scaled,
            "scale_rule": self.scale_rule, "chi2": finite(self.chi2), "chi2_dof": finite(self.chi2_dof),
            "singular_directions": [{"combination": text, "standard_error": finite(err)}
                                    for text, err in self.combinations()],
            "intervals_95": {k: list(v) for k, v in self.intervals(0.95).items()},
        }  # fmt: skip

    def table(self) -> str:
        """One line per coefficient: value ± standard error (relative) and the linearized 95 %
        interval (:meth:`intervals`), and the undetermined ones."""
        intervals = self.intervals(0.95)
        lines = [f"{'coefficient':<12} {'value':>14} {'± std. error':>14} {'relative':>9}   {'95 % interval':<28}"]
        for n, v, s in zip(self.names, self.values, self.standard_errors):
            rel = abs(s / v) if v != 0 and math.isfinite(s) else math.inf
            lo, hi = intervals[n]
            lines.append(f"{n:<12} {v:>14.6g} {s:>14.3g} {rel:>9.2%}   [{lo:.6g}, {hi:.6g}]")
        if self.undetermined:
            lines.append(f"not determined by the data: {', '.join(self.undetermined)}")
        if math.isfinite(self.chi2):
            how = (f"covariance scaled by chi2/dof = {self.residual_variance:.3g}" if self.scaled
                   else "covariance not scaled (the table's standard deviations taken as they are)")  # fmt: skip
            lines.append(f"chi2 = {self.chi2:.4g}, dof = {self.dof}, chi2/dof = {self.chi2_dof:.3g}; {how}")
        if self.undetermined or self.max_correlation() >= CORRELATED:
            lines.append(
                f"coefficients correlated (max |correlation| {self.max_correlation():.3f}): "
                "the combinations the data determine (singular directions, relative standard error):"
            )
            lines += [f"  {text}: ± {err:.3g}" for text, err in self.combinations()]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


def uncertainty_from_jacobian(jacobian, residuals, values, names, *, scaled: bool | str,
                              rcond: float = UNDETERMINED_RCOND) -> Uncertainty:  # fmt: skip
    """:class:`Uncertainty` from J = ∂r/∂θ (m × p) and r at the optimum, c = ``values``;
    ``scaled``: ``"auto"``, True or False (module docstring)."""
    if not any(scaled is rule or (isinstance(scaled, str) and scaled == rule) for rule in SCALE_RULES):
        raise ValueError(f"scale_covariance must be 'auto', True or False, got {scaled!r}")
    J = np.asarray(jacobian, float)
    r = np.asarray(residuals, float)
    c = np.asarray(values, float)
    m, p = J.shape
    dof = m - p
    chi2 = float(r @ r)
    ratio = chi2 / dof if dof > 0 else 1.0
    rule = "auto" if isinstance(scaled, str) else ("always" if scaled else "never")
    s2 = {"auto": max(1.0, ratio), "always": ratio, "never": 1.0}[rule]
    _, S, Vt = np.linalg.svd(J, full_matrices=False)
    keep = S > rcond * (S[0] if S.size and S[0] > 0 else 1.0)
    inv = np.where(keep, 1.0 / np.where(keep, S, 1.0) ** 2, 0.0)
    cov_log = s2 * (Vt.T * inv) @ Vt
    undetermined = set()
    for k in np.flatnonzero(~keep):
        undetermined |= {names[j] for j in np.flatnonzero(np.abs(Vt[k]) >= _MEMBER)}
    cov = cov_log * np.outer(c, c)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    bad = np.array([n in undetermined for n in names])
    se = np.where(bad, np.inf, se)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr = np.where(np.outer(bad, bad) | ~np.isfinite(corr), np.nan, corr)
    return Uncertainty(
        names=tuple(names), values=c, covariance=cov, covariance_log=cov_log, standard_errors=se,
        correlation=corr, singular_values=S, undetermined=tuple(n for n in names if n in undetermined),
        residual_variance=s2, dof=int(dof), scaled=bool(s2 != 1.0), chi2=chi2, directions=Vt.T, scale_rule=rule,
    )  # fmt: skip
