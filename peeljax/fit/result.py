"""The result of a fit, built in one place: what every fit of φ returns.

:class:`FitResult` is what every fit returns (:func:`~peeljax.fit.fit_adhesion`,
:func:`~peeljax.fit.fit_adhesion_steady`: the optax fits of :mod:`peeljax.fit.trajectory`);
:class:`TableFitResult` adds what a least-squares fit reports (χ²/dof, outliers, optima, each
row's attractor, the intervals), built by :func:`least_squares_result` alone from the
Levenberg–Marquardt runs of :func:`~peeljax.fit.fit_stick_slip` and
:func:`~peeljax.fit.fit_records`. :class:`FitInterrupted` carries the best point so far of
a fit stopped by Ctrl-C (:func:`interrupted` makes it of a Levenberg–Marquardt run).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .._atomic import write_text
from .._files import json_safe
from ..adhesion import LAW_KEY, AdhesionLaw, in_a_file
from .levenberg_marquardt import CONVERGED, STOP_REASONS, LevenbergMarquardt, missing_entries
from .parameters import law_from
from ..measurements.statistics import STATISTICS
from ..measurements.stick_slip_table import StickSlipTable
from .table_rows import V_REST, TableRows
from .uncertainty import uncertainty_from_jacobian
from .window_rows import MISSING_RESIDUAL

__all__ = ["EQUAL_CHI2", "OUTLIER_SIGMA", "ROUGH_PROFILES", "FitInterrupted", "FitResult", "TableFitResult",
    "interrupted", "least_squares_result"]  # fmt: skip


@dataclasses.dataclass
class FitResult:
    """The outcome of :func:`fit_adhesion` / :func:`fit_adhesion_steady`.

    Attributes:
        adhesion: the fitted law (the best iterate).
        start: the law the fit started from.
        loss_history: the loss at θ_0 … θ_steps (``steps + 1`` entries).
        initial_loss, final_loss: L at the start and at the fitted law.
        gradient_norm: ‖∂L/∂θ‖₂ at the fitted law (θ the log parameters of the free coefficients).
        steps: the optimizer's iterations (updates) taken, at most the ``steps`` asked for;
            stopped_early: early stopping (patience/tolerance) fired.
        v_range: (min, max) of v visited by the fitted model's runs (or of the data's v,
            steady case): φ is determined by the data only there.
        free: the fitted coefficients' names; settings: the fit's options.
        uncertainty, stop_reason, residuals, start_losses: least-squares fits
            (:func:`peeljax.fit.fit_stick_slip`): the coefficients' covariance, standard errors
            and correlations (:class:`peeljax.fit.uncertainty.Uncertainty`), why it stopped, the
            residuals at the optimum and every start's final loss.
    """

    adhesion: AdhesionLaw
    start: AdhesionLaw
    loss_history: np.ndarray
    initial_loss: float
    final_loss: float
    gradient_norm: float
    steps: int
    stopped_early: bool
    v_range: tuple[float, float]
    free: tuple[str, ...]
    settings: dict
    t_stop: list[float] = dataclasses.field(default_factory=list)
    wall_time_s: float = math.nan
    uncertainty: object | None = None  # peeljax.fit.uncertainty.Uncertainty (least-squares fits)
    stop_reason: str = ""
    residuals: np.ndarray | None = None
    start_losses: np.ndarray | None = None

    @property
    def loss_reduction(self) -> float:
        return self.initial_loss / self.final_loss if self.final_loss > 0 else math.inf

    def to_dict(self) -> dict:
        """The 14 coefficients at top level (``AdhesionLaw.from_dict`` reads them) and the rest; a
        fitted subclass of AdhesionLaw is named under ``"law"``, and ``from_dict`` then refuses the file."""
        return {
            **self.adhesion.coefficients(), "start": self.start.coefficients(), "free": list(self.free),
            "loss_history": [float(x) for x in self.loss_history], "initial_loss": self.initial_loss,
            "final_loss": self.final_loss, "loss_reduction": self.loss_reduction, "gradient_norm": self.gradient_norm,
            "steps": self.steps, "stopped_early": self.stopped_early, "v_range": list(self.v_range),
            "t_stop": list(self.t_stop), "wall_time_s": self.wall_time_s, "settings": self.settings,
            **({} if in_a_file(self.adhesion) else {LAW_KEY: type(self.adhesion).__qualname__}),
            **({} if not self.stop_reason else {"stop_reason": self.stop_reason}),
            **({} if self.uncertainty is None else {"uncertainty": self.uncertainty.as_dict()}),
            **({} if self.residuals is None else {"residuals": [float(x) for x in self.residuals]}),
            **({} if self.start_losses is None else {"start_losses": [float(x) for x in self.start_losses]}),
        }  # fmt: skip

    def to_json(self, path: str | Path | None = None) -> str:
        """:meth:`to_dict` as strict JSON (NaN and infinities as null), written to ``path`` if given."""
        text = json.dumps(json_safe(self.to_dict()), indent=2, allow_nan=False)
        if path is not None:
            write_text(path, text + "\n")
        return text


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`fit_adhesion`: still a ``KeyboardInterrupt``, which also holds the
    fit's best iterate so far as a :class:`FitResult` (``best``; its ``stop_reason`` says after
    how many iterations), e.g. ``except FitInterrupted as stop: stop.best.adhesion``."""

    def __init__(self, best: FitResult):
        super().__init__(best.stop_reason)
        self.best = best


# summary()'s note where intervals="auto" kept the linearized intervals (why: peeljax.fit.table.rough_rows)
ROUGH_PROFILES = "profile intervals are not computed where chi2 is rough at the optimum"
OUTLIER_SIGMA = 5.0  # |residual| in σ from which a table entry is named in the result
EQUAL_CHI2 = 1.0  # optima within χ²_min + 1 fit equally well (a 68 % joint region's edge for one coefficient)


@dataclasses.dataclass
class TableFitResult(FitResult):
    """:class:`~peeljax.fit.FitResult` of a table fit, with what a least-squares fit reports.

    Attributes (besides :class:`~peeljax.fit.FitResult`'s):
        chi2, dof: χ² = Σ r² at the optimum and m − p; ``chi2 / dof`` ≈ 1 when the table's σ
            are right (``uncertainty.scaled``: whether the covariance was scaled by it).
        outliers: entries with |r| > 5 σ, as (row, V, statistic, r in σ), largest first.
        missing: entries the fitted model does not produce (no slip in the window), as
            (row, V, statistic); each costs ``MISSING_RESIDUAL`` in χ².
        optima: every LM run's end (coefficients, χ², stop reason), best first;
            ``equivalent_optima`` those distinct from the best (> 1 standard error apart in some
            coefficient) with χ² within χ²_min + 1: the data do not choose between them.
        coarse_losses: χ² of every point of the coarse batch (the start first).
        converged: the best run stopped on a convergence criterion with every statistic produced.
    """

    chi2: float = math.nan
    dof: int = 0
    outliers: list = dataclasses.field(default_factory=list)
    missing: list = dataclasses.field(default_factory=list)
    optima: list = dataclasses.field(default_factory=list)
    equivalent_optima: list = dataclasses.field(default_factory=list)
    coarse_losses: np.ndarray | None = None
    converged: bool = False
    rows: list = dataclasses.field(default_factory=list)
    crossings: list = dataclasses.field(default_factory=list)
    profiles: dict = dataclasses.field(default_factory=dict)
    intervals_used: str = "linear"
    table: object = None  # the StickSlipTable fitted (records: the one made of them)

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def intervals(self, level: float = 0.95) -> dict[str, list[tuple[float, float]]]:
        """Each coefficient's confidence set at ``level``: the profile-likelihood interval(s)
        where they were computed at that level (a union of intervals where the data cannot tell
        two branches apart), else the linearized interval value ± q·SE."""
        linear = self.uncertainty.intervals(level)
        out = {}
        for name in self.free:
            profile = self.profiles.get(name)
            if profile is not None and abs(profile.level - level) < 1e-12:
                out[name] = list(profile.intervals)
            else:
                out[name] = [linear[name]]
        return out

    def covers(self, truth: dict, level: float = 0.95) -> dict[str, bool]:
        """Whether each coefficient's confidence set (:meth:`intervals`) holds ``truth[name]``."""
        return {n: any(lo <= truth[n] <= hi for lo, hi in sets) for n, sets in self.intervals(level).items()}

    def to_dict(self) -> dict:
        return {
            **super().to_dict(),
            "chi2": self.chi2, "dof": self.dof, "chi2_dof": self.chi2_dof, "converged": self.converged,
            "outliers": [{"row": i, "V": V, "statistic": s, "residual_sigma": x} for i, V, s, x in self.outliers],
            "missing": [{"row": i, "V": V, "statistic": s} for i, V, s in self.missing],
            "optima": self.optima, "equivalent_optima": self.equivalent_optima,
            "coarse_losses": None if self.coarse_losses is None else [float(x) for x in self.coarse_losses],
            "rows": self.rows, "crossings": self.crossings, "intervals_used": self.intervals_used,
            "intervals_95": {n: [list(i) for i in sets] for n, sets in self.intervals(0.95).items()},
            "profiles": {n: p.as_dict() for n, p in self.profiles.items()},
        }  # fmt: skip

    def summary(self) -> str:
        """The fit in a few lines: stop reason, χ²/dof, coefficients ± standard errors, the
        residuals beyond 5 σ, equally good optima."""
        lines = [
            f"Levenberg-Marquardt: {self.steps} model evaluations, chi2 {self.initial_loss:.4g} -> {self.final_loss:.4g}",
            f"stopped: {self.stop_reason}",
            self.uncertainty.table(),
        ]
        if self.outliers:
            lines.append(f"residuals beyond {OUTLIER_SIGMA:g} sigma:")
            lines += [f"  row {i} (V = {V:g}) {s}: {x:+.1f} sigma" for i, V, s, x in self.outliers]
        if self.missing:
            lines.append("not produced by the fitted model (no slip in the window; each costs "
                         f"{MISSING_RESIDUAL:g} sigma):")  # fmt: skip
            lines += [f"  row {i} (V = {V:g}) {s}" for i, V, s in self.missing]
        if self.rows:
            lines.append("rows: " + "; ".join(_row_text(row) for row in self.rows))
        for c in self.crossings:
            if c["row"] is None:
                lines.append(f"  {c['why']}")
                continue
            lines.append(
                f"  {'crossed' if c['accepted'] else 'refused a step across'} a bifurcation at row {c['row']} "
                f"(V = {c['V']:g}): {c['from']} -> {c['to'] if c['to'] is not None else 'none'} slips per period ({c['why']})"
            )
        rough = [r for r in self.rows if "singular_elasticity" in r or r.get("how", "").endswith("window statistics")]
        if rough and not self.profiles and self.settings.get("intervals") == "auto":
            at = ", ".join(f"{r['V']:g}" for r in rough)
            lines.append(f"intervals: the linearized ones ({ROUGH_PROFILES}: rows at V = {at})")
        if self.profiles:
            lines.append("profile-likelihood intervals (95 %) beside the linearized ones:")
            linear = self.uncertainty.intervals(0.95)
            for name, profile in self.profiles.items():
                sets = " u ".join(f"[{lo:.6g}, {hi:.6g}]" for lo, hi in profile.intervals) or "none"
                lo, hi = linear[name]
                lines.append(f"  {name}: profile {sets}; linearized [{lo:.6g}, {hi:.6g}]")
        if self.equivalent_optima:
            lines.append(f"other optima within chi2_min + {EQUAL_CHI2:g} (the data do not choose between them):")
            lines += [
                "  " + ", ".join(f"{n} = {c:.6g}" for n, c in o["coefficients"].items()) + f" (chi2 {o['chi2']:.4g})"
                for o in self.equivalent_optima
            ]
        return "\n".join(lines)


def _row_text(row: dict) -> str:
    if row["kind"] != "orbit":
        text = row["kind"]
    elif row.get("slips") is None:
        text = row["how"]
    else:
        text = f"orbit, {row['slips']} slips per period, {'stable' if row.get('stable') else 'UNSTABLE'}"
    if "singular_elasticity" in row:  # peeljax.fit.table_rows.singular_rows
        text += f" (a derivative too steep to use: elasticity {row['singular_elasticity']:.3g})"
    if "slips_found" in row:
        text += f" (its record finds {row['slips_found']:.0%} of the slips: F_mean only)"
    return f"V = {row['V']:g}: {text}"


def least_squares_result(runs: list[LevenbergMarquardt], start: AdhesionLaw, names, settings: dict, *, scale,
                         initial: float, began: float, table: StickSlipTable | None = None, measured=None,
                         coarse_losses=None, rows=None, why=None, crossings=(), profiles=None) -> TableFitResult:  # fmt: skip
    """The one :class:`TableFitResult` of a Levenberg–Marquardt fit, from its ``runs`` (best
    first once sorted: fewest missing statistics, then χ²): the law, its uncertainty
    (:func:`~peeljax.fit.uncertainty.uncertainty_from_jacobian`, ``scale`` as
    ``scale_covariance``), the table's outliers and missing entries (where ``table`` and its
    (n, 5) ``measured`` mask are given), the optima, and the rows' report (``rows``: the
    :class:`TableRows` followed, ``why`` each row's kind)."""
    runs.sort(key=lambda run: (missing_entries(run.r), run.chi2 if np.isfinite(run.chi2) else np.inf))
    best = runs[0]
    law = law_from({n: jnp.asarray(best.z[k]) for k, n in enumerate(names)}, start)
    values = np.asarray([float(getattr(law, n)) for n in names])
    uncertainty = uncertainty_from_jacobian(best.J, best.r, values, names, scaled=scale)
    entries = []
    if table is not None:
        measured_rows, columns = np.nonzero(measured)
        entries = [(int(i), float(table.V[i]), STATISTICS[j], float(x)) for i, j, x in zip(measured_rows, columns, best.r)]
    missing = [e[:3] for e in entries if e[3] == MISSING_RESIDUAL]
    outliers = sorted((e for e in entries if abs(e[3]) > OUTLIER_SIGMA and e[3] != MISSING_RESIDUAL),
                      key=lambda e: -abs(e[3]))  # fmt: skip
    optima = [
        {"coefficients": {n: float(getattr(start, n)) * math.exp(run.z[k]) for k, n in enumerate(names)},
         "chi2": run.chi2, "stop_reason": run.reason, "evaluations": run.evaluations}
        for run in runs
    ]  # fmt: skip
    se_log = np.sqrt(np.maximum(np.diag(uncertainty.covariance_log), 0.0))
    equivalent = [
        o for run, o in zip(runs[1:], optima[1:])
        if run.chi2 <= best.chi2 + EQUAL_CHI2 and np.any(np.abs(run.z - best.z) > np.maximum(se_log, 1e-12))
    ]  # fmt: skip
    v_range = np.asarray(best.v_range)
    profiles = profiles or {}
    return TableFitResult(
        adhesion=law, start=start, loss_history=np.asarray(best.history), initial_loss=initial, final_loss=best.chi2,
        gradient_norm=float(np.linalg.norm(2 * best.J.T @ best.r)), steps=int(max(run.evaluations for run in runs)),
        stopped_early=best.reason in CONVERGED,
        v_range=(float(max(np.nanmin(v_range[:, 0]), V_REST)), float(np.nanmax(v_range[:, 1]))),
        free=names, settings=settings, wall_time_s=time.perf_counter() - began, uncertainty=uncertainty,
        stop_reason=STOP_REASONS[best.reason], residuals=best.r, start_losses=np.asarray([run.chi2 for run in runs]),
        chi2=best.chi2, dof=uncertainty.dof, outliers=outliers, missing=missing, optima=optima,
        equivalent_optima=equivalent, coarse_losses=coarse_losses, converged=best.reason in CONVERGED and not missing,
        rows=[] if rows is None else _row_report(rows, best.state, why), crossings=list(crossings), profiles=profiles,
        intervals_used="profile" if profiles else "linear", table=table,
    )  # fmt: skip


def interrupted(names, start: AdhesionLaw, run: LevenbergMarquardt, iterations: int) -> FitResult:
    """The best point of an interrupted Levenberg–Marquardt, as a result (no uncertainty: its
    covariance, profiles and checks were not computed)."""
    return FitResult(
        adhesion=law_from({n: jnp.asarray(z) for n, z in zip(names, run.z)}, start), start=start,
        loss_history=np.asarray(run.history), initial_loss=float(run.history[0]), final_loss=float(run.chi2),
        gradient_norm=float(np.linalg.norm(2 * run.J.T @ run.r)), steps=len(run.history) - 1, stopped_early=False,
        v_range=tuple(float(x) for x in np.ravel(run.v_range)[:2]), free=tuple(names), settings={},
        stop_reason=f"interrupted after {iterations} iterations",
    )  # fmt: skip


def _row_report(rows: TableRows, point, why) -> list[dict]:
    """Per row at the optimum: its kind, and for an orbit k, stability, multipliers, period and
    the grazing monitors."""
    if hasattr(rows, "table"):  # a Joint: the table's rows
        rows, point = rows.table, point.parts[0]
    report = []
    for i, kind in enumerate(rows.kinds):
        entry = {"row": i, "V": float(rows.V[i]), "kind": kind, "how": why[i]}
        orbit = point.orbits.get(i) if point is not None else None
        if kind == "orbit" and orbit is not None:
            entry.update(
                slips=int(orbit["slips"]), stable=bool(np.max(orbit["multipliers"]) < 1.0),
                multipliers=[float(m) for m in orbit["multipliers"]], period=float(orbit["period"]),
                approach=float(orbit["approach"]), crossing=float(orbit["crossing"]), how=orbit["attractor"].how,
            )  # fmt: skip
        elif kind == "orbit" and point is not None and i in point.windowed:
            entry.update(slips=None, stable=False, how="no periodic attractor at the optimum: its window statistics")
        elif kind == "orbit":
            entry.update(slips=None, stable=False, how="no periodic attractor at the optimum")
        if point is not None and i in point.singular:
            entry["singular_elasticity"] = float(point.singular[i])
        if i in getattr(rows, "slips_found", {}):  # a record's instrument misses slips: F_mean alone
            entry["slips_found"] = float(rows.slips_found[i])
        report.append(entry)
    return report
