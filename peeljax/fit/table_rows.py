"""A stick-slip table's rows as the model predicts them at θ: each row on its own kind of attractor.

Every row of a :class:`~peeljax.fit.StickSlipTable` is one pull velocity V_i. What the model
predicts there depends on the attractor at V_i (:func:`row_kinds`, decided at the start):

* **steady** — steady peeling is stable at V_i (φ(·, V_i) has no fold, or v = V_i lies on a
  rising branch of φ): α = 0, v = V and the constraint (sac) gives the tension
  F = φ(V_i, V_i) (the lever l·sinα/L vanishes at α = 0 in either geometry). Such a row pins φ
  on its diagonal: only ``F_mean`` is predicted, any other statistic in the row is missing;
* **orbit** — the run at V_i settles on a periodic stick-slip orbit, or, where it settles too
  slowly (its near repeat's orbit unstable, or no repeat shown at all), a stable orbit of
  1 … ``SLOW_SLIPS`` slips is shot from its last slip: the five statistics over one period of
  it, exact, and their derivatives by the implicit function theorem
  (:mod:`peeljax.fit.attractors`, which finds and follows the orbit, through a period doubling
  onto the orbit born there: :meth:`TableRows._doubled`);
* **window** — stick-slip without a periodic attractor found (irregular, and no stable orbit
  of 1 … ``SLOW_SLIPS`` slips shot from the run's last slip): the run's statistics over
  ``[transient, transient + window]`` (:func:`peeljax.measurements.statistics.jump_statistics`,
  tapered, with the cycle-to-cycle scatter added to σ), as before there were orbits. An orbit
  row whose attractor is not periodic at a trial θ takes the same (:attr:`Point.windowed`).

:class:`TableRows` evaluates all of them at a point θ (log coefficients, c = c_start·exp(θ)):
the residuals r = (model − data)/σ of the measured entries (row-major), their Jacobian, the v
visited per row, and — for the orbit rows — where each orbit was shot from, so that the next
point follows it (:class:`Point`). A row whose attractor changed between two points (a
bifurcation crossed) is named in :attr:`Point.changes`.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from .._exported import compiled
from ..adhesion import AdhesionLaw
from ..model import PeelingModel
from ..orbits.api import orbit_shooting
from ..orbits.section import state_after_slip
from .attractors import Attractor, OrbitRows, classify, find_attractor, shoot_rows, steady_force, steady_rows
from ..measurements.statistics import STATISTICS
from .parameters import law_from, value_and_jacfwd
from .window_rows import MISSING_RESIDUAL, build_table_fit

__all__ = ["KINDS", "MAX_ELASTICITY", "Point", "TableRows", "attractor_rows", "row_kinds", "singular_rows"]

KINDS = ("steady", "orbit", "window")
SAME_POINT = 1e-7  # scaled section coordinates: P^d(s*) = s* (Newton's tolerance is 1e-10)
SAME_ORBIT = 1e-5  # relative: two shootings at one θ found one orbit (its statistics to ~1e-7)
# Past a period doubling the orbit of 2k slips is shot from the k-orbit's point moved by these
# (scaled) along the multiplier's eigenvector, both ways, the k-orbit deflated away (measured at
# 0.5 m/s on the whole-range table's truth: the doubled orbit lies 0.05, 0.10–0.15 and 0.16 from
# it at 0.008, 0.06 and 0.16 % of c1 past the doubling, where Newton converged on it within 20
# iterations from 6, 4 and 2 of these 6 starts)
DOUBLING_STARTS = (0.001, 0.01, 0.1)
DOUBLED_APART = 1e-6  # scaled: the doubled orbit's point is not the k-orbit's
# |∂ log statistic / ∂ log c| beyond which a row's derivative is singular (measured on tables at
# 0.5–4 m/s: 4–10 on rows away from a bifurcation, 141–1.6e6 near a grazing)
MAX_ELASTICITY = 50.0
# A record's row whose instrument finds fewer of the orbit's slips keeps F_mean alone (decided at
# the start, so that every point of the fit has the same residuals): its other statistics are of
# the slips that happen to cross the detection threshold, and move with details of the noise no
# record tells. Records at 2.4 m/s, 5 kHz, 0.5 % noise proportional to F find 27 % of the slips;
# their F_slip lies 4 standard deviations above the model's records with white noise of the same
# level, 0.2 with noise proportional to F in the model too (docs/fitting.md).
SLIPS_FOUND = 0.95
V_REST = 1e-4  # m/s: the bottom of the reported v range where the tape comes to rest


@dataclasses.dataclass
class Point:
    """The model at one θ: residuals, Jacobian and what the next point follows.

    Attributes:
        z: θ (p,); r: residuals (m,); J: ∂r/∂θ (m, p); v_range: per row (v_lo, v_hi).
        values, available: the model's statistics (n, 5) and which it produces.
        attractors: per row, the :class:`~peeljax.fit.attractors.Attractor` its orbit was shot
            from (None: not an orbit row, or its attractor lost at θ).
        orbits: per orbit row, what :func:`~peeljax.fit.attractors.shoot_rows` gave (row index
            → dict of that row's values).
        changes: rows whose attractor changed against the point this one was evaluated from
            ({"row", "V", "from", "to", "why"}).
        singular: rows whose derivative is singular (:func:`singular_rows`), with their
            largest elasticity: their rows of ``J`` are zero.
        windowed: orbit rows without a periodic attractor at z (lost to a torus or chaos, or
            not found again): their window statistics, as a window row's.
    """

    z: np.ndarray
    r: np.ndarray
    J: np.ndarray
    v_range: np.ndarray
    values: np.ndarray
    available: np.ndarray
    attractors: list
    orbits: dict
    changes: list = dataclasses.field(default_factory=list)
    branch: tuple = ()  # per row, how many attractor changes led here from the start (which branch)
    singular: dict = dataclasses.field(default_factory=dict)
    windowed: tuple = ()


_STARTS: dict = {}  # (model's leaves, V) → row_kinds' answer, the orbits reduced to their least k
_CHECKED: set = set()  # the keys of _STARTS whose orbit rows were shot and found attractors


def _key(model: PeelingModel, V) -> tuple:
    leaves = jax.tree_util.tree_leaves(model)
    return (model.geometry, tuple(float(x) for x in leaves), tuple(float(v) for v in np.asarray(V, float)))


def row_kinds(model: PeelingModel, V, *, find=find_attractor, program: OrbitRows | None = None
              ) -> tuple[list[str], list, list[str]]:  # fmt: skip
    """Each row's kind at the model (module docstring), its start (an
    :class:`~peeljax.fit.attractors.Attractor` for an orbit row) and, for a window row, why no
    orbit was found. Remembered per model and V (the runs are deterministic): fits that start
    from one φ find their rows' attractors once.

    ``program`` (an :class:`~peeljax.fit.attractors.OrbitRows` whose φ at θ = 0 is the model's):
    the orbits of the runs' repeats are shot, all in one call, and a row whose orbit is not an
    attractor, or whose runs showed no repeat (:class:`~peeljax.fit.attractors.NoRepeat`), is
    looked for among the stable orbits of 1 … ``SLOW_SLIPS`` slips from the runs' last slip
    (:func:`_slow_attractor`), else is a window row — a near repeat of a run can be close
    to an orbit that has lost its stability (measured: c1 × 1.07, c3 × 0.93, c6 × 1.07 at
    0.5 m/s, where the tape stops after every slip: a 2-slip orbit with multipliers
    1.036 e^{±iψ}, while the attractor, a 5-slip orbit with a multiplier −0.976, settles too
    slowly for the runs; a run still settling can show no repeat at all: docs/fitting.md)."""
    key = _key(model, V)
    cached = _STARTS.get(key)
    if cached is None:
        cached = _found_kinds(model, V, find)
    kinds, starts, why = (list(x) for x in cached)
    if program is not None and key not in _CHECKED:
        theta, V = np.zeros(len(program.names)), np.asarray(V, float)
        orbit = [i for i, kind in enumerate(kinds) if kind == "orbit"]
        shot = shoot_rows(program, theta, V[orbit], [starts[i] for i in orbit]) if orbit else None
        reasons = {i: classify(shot, j, None, 0, None) for j, i in enumerate(orbit)}
        for i, kind in enumerate(kinds):
            # a window row with a last slip: its runs may be too short for a slow attractor
            if (kind == "orbit" and not reasons[i]) or starts[i] is None:
                continue
            but = f", but {reasons[i]}" if kind == "orbit" else ""
            slow = _slow_attractor(program, theta, float(V[i]), starts[i])
            if slow is not None:
                kinds[i], starts[i], why[i] = "orbit", slow, f"{why[i]}{but}; {slow.how}"
            elif kind == "orbit":
                kinds[i], why[i] = "window", f"{why[i]}{but}: no periodic attractor"
        _CHECKED.add(key)
    _STARTS[key] = (kinds, starts, why)  # a window row's start: its runs' last slip (NoRepeat.last)
    return list(kinds), [a if kind == "orbit" else None for kind, a in zip(kinds, starts)], list(why)


SLOW_SLIPS = 12  # a slow attractor is looked for among the orbits of 1 … SLOW_SLIPS slips


def _slow_attractor(program: OrbitRows, theta, V: float, start: Attractor) -> Attractor | None:
    """A periodic attractor the runs did not settle on: the orbits of k = 1 … ``SLOW_SLIPS``
    slips at θ shot (one batched call) from the run's last slip, where its near repeat's orbit
    is unstable or it shows no repeat (``start``: k = 1, its period the mean slip interval);
    the stable one nearest that point, else None. Measured on the whole-range table's
    truth at 0.5 m/s (the tape stopping after every slip): the runs' near repeat of 2 slips is
    an unstable orbit (multipliers 1.04·e^{±iψ}), the attractor a 5-slip orbit with a multiplier
    −0.976, which the 3 and 8 s runs do not reach (docs/fitting.md)."""
    per_slip = start.period / max(start.slips, 1)
    trials = [Attractor(start.section, k, per_slip * k, start.how) for k in range(1, SLOW_SLIPS + 1)]
    shot = shoot_rows(program, theta, np.full(len(trials), V), trials)
    stable = [j for j in range(len(trials)) if not classify(shot, j, None, 0, None)]
    if not stable:
        return None
    scale = shot["section"][stable[0]] / shot["z"][stable[0]]
    distance = [np.max(np.abs(shot["section"][j] - start.section) / scale) for j in stable]
    j = stable[int(np.argmin(distance))]
    how = f"a stable orbit of {j + 1} slips shot from the run's last slip (k = 1 … {SLOW_SLIPS} tried)"
    return Attractor(shot["section"][j], j + 1, float(shot["period"][j]), how)


def _found_kinds(model: PeelingModel, V, find) -> tuple[list[str], list, list[str]]:
    steady = steady_rows(model, V)
    kinds, starts, why = [], [], []
    for Vi, is_steady in zip(np.asarray(V, float), steady):
        if is_steady:
            kinds.append("steady"), starts.append(None), why.append("steady peeling is stable here")
            continue
        found = find(model, float(Vi))
        if isinstance(found, Attractor):
            kinds.append("orbit"), starts.append(found), why.append(found.how)
        else:
            kinds.append("window"), starts.append(getattr(found, "last", None)), why.append(str(found))
    return kinds, starts, why


class _WindowStatistics(eqx.Module):
    """The window rows' statistics, availability, v range and scatter, with the statistics'
    forward-mode Jacobian (one tangent per free coefficient)."""

    fit: object  # peeljax.fit.window_rows.TableFit over the window rows

    def __call__(self, theta):
        names = self.fit.names

        def stats(th):
            values, available, v_range, scatter = self.fit.statistics_with_scatter(
                {n: th[k] for k, n in enumerate(names)}
            )
            return values, (available, v_range, scatter)

        (values, aux), jac = value_and_jacfwd(stats, theta)
        return values, jac, *aux


_window = compiled(lambda program, theta: program(theta), "table_rows_window")  # traced once per machine


class TableRows:
    """The table's rows at θ (module docstring): :meth:`start` at θ = 0, :meth:`evaluate` at a
    trial θ from a :class:`Point` whose attractors it follows.

    Args:
        data, sigma, measured: (n, 5) arrays over :data:`STATISTICS`.
        V: the rows' pull velocities (n,); kinds, starts: :func:`row_kinds`.
        model: spool and tape; start: φ at θ = 0; names: the free coefficients.
        program: the compiled orbit rows (:class:`~peeljax.fit.attractors.OrbitRows`).
        window_fit: a :class:`~peeljax.fit.window_rows.TableFit` over the window rows (None if none).
        cycle_scatter: add the window rows' cycle-to-cycle scatter to σ.
        window_options: :func:`~peeljax.fit.window_rows.build_table_fit`'s options: an orbit row
            without a periodic attractor at θ gets its window statistics (None: it is missing).

    Rows measured from force records get their instrument (:meth:`set_instruments`): the bias
    its sampling and noise add to the orbit's statistics (:mod:`peeljax.measurements.instrument`,
    :meth:`update_bias`) is added to them, its Monte Carlo error to σ.
    """

    def __init__(self, data, sigma, measured, V, kinds, starts, *, model: PeelingModel, start: AdhesionLaw, names,
                 program: OrbitRows | None, window_fit=None, cycle_scatter=True, window_options=None):  # fmt: skip
        self.data, self.sigma = np.asarray(data), np.asarray(sigma)
        self.measured = np.array(measured, bool)  # (a record's row may lose statistics its instrument misses)
        self.V = np.asarray(V, float)
        self.kinds, self.starts = list(kinds), list(starts)
        self.model, self.start_law, self.names = model, start, tuple(names)
        self.program, self.window_fit, self.cycle_scatter = program, window_fit, cycle_scatter
        self.window_options = window_options
        self.rows = {kind: [i for i, k in enumerate(self.kinds) if k == kind] for kind in KINDS}
        self.evaluations = 0
        self.bias = np.zeros_like(self.data, dtype=float)  # what each row's instrument adds (set_instruments)
        self.bias_error = np.zeros_like(self.data, dtype=float)  # its Monte Carlo standard error, added to σ
        self.covariance: dict = {}  # row → a record's statistics' covariance about the model's (update_bias)
        self.slips_found: dict = {}  # row → the fraction of its slips the instrument finds, where it drops some statistics
        self._slips_judged = False  # (update_bias: at the start only)
        self.instruments: dict = {}

    # -- records: the statistics as their instrument saw them -------------------------------
    def set_instruments(self, instruments: dict) -> None:
        """``instruments``: row → :class:`~peeljax.measurements.instrument.Instrument` of the record(s)
        that made it; their bias is added to the orbit rows' statistics (:meth:`update_bias`)."""
        self.instruments = dict(instruments)

    @property
    def has_instruments(self) -> bool:
        return bool(self.instruments)

    def update_bias(self, point: Point) -> float:
        """The instruments' bias and a record's covariance at ``point``'s orbits; returns the
        largest change of the bias in σ. On the first call (the start), a row whose instrument
        finds fewer than ``SLIPS_FOUND`` of its slips keeps F_mean alone, for the whole fit."""
        from ..measurements.instrument import instrument_bias

        model = eqx.tree_at(lambda m: m.adhesion, self.model, self.law(point.z))
        new, error = self.bias.copy(), self.bias_error.copy()
        first, self._slips_judged = not self._slips_judged, True
        for i, instrument in self.instruments.items():
            if i in point.orbits:
                new[i], error[i], self.covariance[i], found = instrument_bias(model, float(self.V[i]), point.orbits[i],
                                                                              instrument)  # fmt: skip
                if first and found < SLIPS_FOUND and self.measured[i, 0]:
                    self.slips_found[i] = found
                    self.measured[i, 1:] = False  # F_mean alone: the others are of the slips it happens to find
        scale = np.sqrt(self.sigma**2 + error**2)
        for i, cov in self.covariance.items():  # a record's row: its statistics' spread over the draws
            spread = np.sqrt(np.diag(cov))
            scale[i] = np.where(np.isfinite(spread), spread, scale[i])
        change = float(np.max(np.where(self.measured, np.abs(new - self.bias) / scale, 0.0), initial=0.0))
        self.bias, self.bias_error = new, error
        return change

    def _whiten(self, r_all: np.ndarray, J_all: np.ndarray, values, jac, available, sigma, orbits) -> None:
        """A record's row's residuals and Jacobian whitened by the covariance of its statistics
        over the record's phase and noise (:func:`~peeljax.measurements.instrument.record_covariance`,
        a synthetic likelihood): its statistics' own cycle-to-cycle standard errors are not the
        error of a record's means, which is set by where in the attractor's period its window
        falls (measured: 0.13 against 2.6 N for F_mean at V = 1.1 m/s, 1.9 against 5.3 at
        2.4; docs/fitting.md). Only rows on their orbit (the covariance is the orbit's); a
        statistic without a covariance keeps its σ. In place."""
        for i, cov in self.covariance.items():
            m = self.measured[i] & available[i]
            if i not in orbits or not m.any():
                continue
            c = np.where(np.isnan(cov), 0.0, cov)[np.ix_(m, m)]
            own = np.isnan(np.diag(cov))[m]
            c[own, :], c[:, own] = 0.0, 0.0
            c[own, own] = sigma[i, m][own] ** 2
            lower = np.linalg.cholesky(c)
            r_all[i, m] = scipy.linalg.solve_triangular(lower, values[i, m] - self.data[i, m], lower=True)
            J_all[i, m] = scipy.linalg.solve_triangular(lower, jac[i, m], lower=True)

    def forget(self, point: Point, rows: list[int]) -> Point:
        """``point`` with the attractors of ``rows`` forgotten (found again from rest when it is
        stepped from)."""
        return dataclasses.replace(point, attractors=[None if i in rows else a for i, a in enumerate(point.attractors)],
                                   windowed=tuple(i for i in point.windowed if i not in rows))  # fmt: skip

    # -- the model at θ ---------------------------------------------------------------------
    def law(self, z) -> AdhesionLaw:
        return law_from({n: jnp.asarray(z[k], float) for k, n in enumerate(self.names)}, self.start_law)

    def start(self) -> Point:
        point = self.evaluate(np.zeros(len(self.names)), None)
        key = _key(eqx.tree_at(lambda m: m.adhesion, self.model, self.start_law), self.V)
        if key in _STARTS:  # remember the orbits with their least k
            kinds, starts, why = _STARTS[key]
            reduced = [point.attractors[i] if kind == "orbit" and point.attractors[i] is not None else a
                       for i, (kind, a) in enumerate(zip(kinds, starts))]  # fmt: skip
            _STARTS[key] = (kinds, reduced, why)
        return point

    def evaluate(self, z, base: Point | None) -> Point:
        """The model at θ = ``z``, each orbit row followed from ``base`` (None: from the rows'
        starts, nothing to compare with)."""
        self.evaluations += 1
        z = np.asarray(z, float)
        n, p = len(self.V), z.size
        values = np.zeros((n, len(STATISTICS)))
        jac = np.zeros((n, len(STATISTICS), p))
        available = np.zeros((n, len(STATISTICS)), bool)
        sigma = self.sigma.astype(float).copy()
        v_range = np.tile([V_REST, V_REST], (n, 1)).astype(float)
        attractors = [None] * n
        orbits, changes = {}, []
        # steady rows: F_mean = φ(V, V)
        steady = self.rows["steady"]
        if steady:
            force, d_force = steady_force(self.model, self.start_law, self.names, z, self.V[steady])
            values[steady, 0], jac[steady, 0], available[steady, 0] = force, d_force, True
            v_range[steady] = self.V[steady, None]
        # orbit rows, followed from base
        rows = self.rows["orbit"]
        if rows:
            follow = [self.starts[i] if base is None else base.attractors[i] for i in rows]
            live = [j for j, a in enumerate(follow) if a is not None]
            found = dict(zip(live, self._shoot(z, [rows[j] for j in live], [follow[j] for j in live])))
            d_theta = z - (base.z if base is not None else np.zeros(p))
            why, doubled = ({}, {}) if base is None else self._not_followed(z, rows, live, follow, found, base, d_theta)
            # rows to find again (lost at the point stepped from, or not followed to z): one batched search
            again = {i: (None, "its attractor was lost at the point stepped from") for j, i in enumerate(rows)
                     if j not in live and not (base is not None and i in base.windowed)}  # fmt: skip
            again.update({rows[j]: (follow[j], reason) for j, reason in why.items()})
            refound = dict(zip(again, self._refind_rows(z, [(i, *again[i]) for i in again])))
            minimal = {}
            if base is None:  # the start: shot from the run's repeat, reduced to its least k
                stable = [j for j in live if not classify(_as_batch(found[j]), 0, None, 0, None)]
                minimal = dict(zip(stable, self._minimal_rows(z, [(rows[j], found[j]) for j in stable])))
            for j, i in enumerate(rows):
                if j not in live and base is not None and i in base.windowed:
                    found_i = None  # not periodic at the point stepped from: looked for again from rest at each optimum
                elif j not in live:  # lost at the point stepped from: look for it again from rest
                    found_i = refound[i]
                    if found_i is not None:
                        changes.append({"row": i, "V": float(self.V[i]), "from": None,
                                        "to": found_i["attractor"].slips, "why": "a periodic attractor again"})  # fmt: skip
                elif base is None:
                    found_i = minimal.get(j)
                elif j not in why:
                    found_i = found[j]
                    if j in doubled:
                        changes.append({"row": i, "V": float(self.V[i]), "from": follow[j].slips,
                                        "to": found_i["attractor"].slips, "why": doubled[j]})  # fmt: skip
                else:
                    previous = base.orbits.get(i)
                    found_i = refound[i]
                    # the same orbit found again (Newton had only failed from a long step): no change
                    if found_i is None or classify(_as_batch(found_i), 0, _as_batch(previous), 0, d_theta):
                        to = None if found_i is None else found_i["attractor"].slips
                        changes.append({"row": i, "V": float(self.V[i]), "from": follow[j].slips, "to": to,
                                        "why": why[j] if to is not None else why[j] + "; no periodic attractor found"})  # fmt: skip
                if found_i is None:
                    continue
                attractors[i] = found_i["attractor"]
                orbits[i] = found_i
                values[i], jac[i], available[i] = found_i["statistics"] + self.bias[i], found_i["jacobian"], True
                v_range[i, 1] = found_i["v_slip"]
        # window rows, and orbit rows whose attractor at z is not a periodic orbit
        lost = [i for i in rows if i not in orbits] if self.window_options is not None else []
        for window, fit in ((self.rows["window"], self.window_fit), (lost, self._lost_fit(lost))):
            if not window:
                continue
            w_values, w_jac, w_available, w_range, scatter = (
                np.asarray(a) for a in _window(_WindowStatistics(fit), jnp.asarray(z, float))
            )
            values[window], jac[window], available[window] = w_values, w_jac, w_available
            v_range[window] = np.maximum(w_range, V_REST)
            if self.cycle_scatter:
                sigma[window] = np.sqrt(sigma[window] ** 2 + scatter**2)
        singular = singular_rows(values, jac, available, range(n))
        jac[list(singular)] = 0.0
        sigma = np.sqrt(sigma**2 + self.bias_error**2)  # the instruments' Monte Carlo error (records)
        r_all = np.where(available, (values - self.data) / sigma, MISSING_RESIDUAL)
        J_all = np.where(available[..., None], jac / sigma[..., None], 0.0)
        self._whiten(r_all, J_all, values, jac, available, sigma, orbits)
        keep = self.measured
        branch = list(base.branch) if base is not None else [0] * n
        for change in changes:
            branch[change["row"]] += 1
        return Point(z=z, r=r_all[keep], J=J_all[keep], v_range=v_range, values=values, available=available,
                     attractors=attractors, orbits=orbits, changes=changes, branch=tuple(branch),
                     singular=singular, windowed=tuple(lost))  # fmt: skip

    def _lost_fit(self, lost: list[int]):
        """The window statistics' program of the orbit rows ``lost`` (every statistic; one
        program per number of such rows), or None where there are none."""
        if not lost:
            return None
        shape = (len(lost), len(STATISTICS))
        return build_table_fit(self.start_law, self.model, self.V[lost], np.zeros(shape), np.ones(shape),
                               np.ones(shape, bool), **self.window_options)  # fmt: skip

    # -- orbits -----------------------------------------------------------------------------
    def _not_followed(self, z, rows, live, follow, found, base: Point, d_theta) -> tuple[dict[int, str], dict[int, str]]:
        """Why the orbit shot is not the row's attractor followed from ``base`` (:func:`classify`),
        for each live row (index into ``rows``) where it is not, after Newton again from the
        section point its derivative predicts — those rows in one batched call — and past a
        period doubling (:meth:`_doubled`); ``found`` gets the retries that are. Also returns
        the rows that crossed a period doubling, with what happened in words."""
        why = {}
        for j in live:
            reason = classify(_as_batch(found[j]), 0, _as_batch(base.orbits.get(rows[j])), 0, d_theta)
            if reason:
                why[j] = reason
        guesses = []
        for j in why:
            previous = base.orbits[rows[j]]
            scale = np.asarray(previous["section"]) / np.asarray(previous["z"])
            guess = np.asarray(previous["section"]) + scale * (previous["z_jacobian"] @ d_theta)
            guesses.append(dataclasses.replace(follow[j], section=guess))
        for j, retry in zip(list(why), self._shoot(z, [rows[j] for j in why], guesses)):
            if not classify(_as_batch(retry), 0, _as_batch(base.orbits[rows[j]]), 0, d_theta):
                found[j] = retry
                del why[j]
        doubled = self._doubled(z, {j: rows[j] for j in why}, found)
        for j in doubled:
            del why[j]
        return why, doubled

    def _doubled(self, z, rows: dict[int, int], found: dict) -> dict[int, str]:
        """The rows (``rows``: index → table row) whose orbit shot at z converged but lost its
        stability through a multiplier real and beyond ±1 where a period doubling explains it:
        below −1, the k-orbit has crossed one, and the orbit of 2k slips born there is the
        attractor; above +1 with k even, the orbit may be a k/2-orbit run twice that crossed one,
        and the orbit of k slips born there is. That orbit is shot from the k-orbit's point moved
        along the multiplier's eigenvector (``DOUBLING_STARTS``, both ways), the point itself
        deflated away, all in one batched call; the first start that reaches a stable orbit apart
        from it is taken into ``found``. A supercritical doubling leaves the statistics per slip
        continuous (the doubled orbit is the k-orbit run twice at the crossing): no restart, no
        window statistics. Returns those rows, with what happened in words."""
        shots, whose = [], []
        for j, i in rows.items():
            row = found[j]
            if int(row["status"]) != 0:
                continue
            values, vectors = np.linalg.eig(np.asarray(row["monodromy"]))
            m = int(np.argmax(np.abs(values)))
            mu, k = values[m], int(row["slips"])
            if abs(mu.imag) > 1e-9 * abs(mu) or abs(mu.real) <= 1.0 or (mu.real > 0 and k % 2):
                continue
            slips = 2 * k if mu.real < 0 else k
            section = np.asarray(row["section"])
            scale = section / np.asarray(row["z"])
            e = np.real(vectors[:, m])  # (M is unscaled: its eigenvector too)
            e = e / np.max(np.abs(e / scale))
            if not np.all(np.isfinite(e)):
                continue
            period = float(row["period"]) * slips / k
            for a in DOUBLING_STARTS:
                for sign in (1.0, -1.0):
                    shots.append(Attractor(section + sign * a * e, slips, period, row["attractor"].how))
                    whose.append((j, i, section, mu.real, k))
        if not shots:
            return {}
        out = self._shoot(z, [w[1] for w in whose], shots, avoid=np.stack([w[2] for w in whose]))
        doubled = {}
        for (j, _, _, mu, k), shot in zip(whose, out):
            if j in doubled or classify(_as_batch(shot), 0, None, 0, None):
                continue
            if np.max(np.abs(shot["z"] - found[j]["z"])) <= DOUBLED_APART:
                continue
            slips = int(shot["slips"])
            how = (f"a period doubling crossed (multiplier {mu:.4g} of the {k}-slip orbit): the orbit of "
                   f"{slips} slips born there")  # fmt: skip
            shot["attractor"] = dataclasses.replace(shot["attractor"], how=how, minimal=True)
            found[j] = shot
            doubled[j] = how
        return doubled

    def _shoot(self, z, rows: list[int], attractors: list[Attractor], avoid=None) -> list[dict]:
        """Each row's orbit from its attractor at θ = z, as a dict of that row's values
        (``avoid``: :func:`~peeljax.fit.attractors.shoot_rows`'s)."""
        if not rows:
            return []
        out = shoot_rows(self.program, z, self.V[rows], attractors, avoid)
        found = []
        for j, a in enumerate(attractors):
            row = {key: value[j] for key, value in out.items()}
            row["attractor"] = Attractor(np.asarray(row["section"]), a.slips, float(row["period"]), a.how,
                                         a.minimal) if int(row["status"]) == 0 else a  # fmt: skip
            found.append(row)
        return found

    def _refind_rows(self, z, requests: list[tuple[int, Attractor | None, str]]) -> list[dict | None]:
        """Each requested row's attractor at θ = z found again (``requests``: the row, its
        previous orbit or None, why): a run from the previous orbit's state (or from the
        paper's start), shot and checked, or, where the run's repeat is not an attractor or it
        shows none, the stable orbit :func:`_slow_attractor` shoots from its last slip; None
        where there is none. The runs go one row at a time; the shots of all rows go in one
        batched call each (the rows side by side on the devices, each row's bits its own)."""
        if not requests:
            return []
        model = eqx.tree_at(lambda m: m.adhesion, self.model, self.law(z))
        found = []
        for i, previous, _ in requests:
            y0 = None if previous is None else state_after_slip(model, float(self.V[i]), previous.section)
            found.append(find_attractor(model, float(self.V[i]), y0=y0))
        ran = [k for k, f in enumerate(found) if isinstance(f, Attractor)]
        shots = dict(zip(ran, self._shoot(z, [requests[k][0] for k in ran], [found[k] for k in ran])))
        rows, slow = {}, {}
        for k, (i, _, _) in enumerate(requests):
            if k in shots and not classify(_as_batch(shots[k]), 0, None, 0, None):
                rows[k] = shots[k]
                continue
            # the runs' repeat is not an attractor, or they showed none: a slower attractor?
            start = found[k] if isinstance(found[k], Attractor) else found[k].last
            orbit = None if start is None else _slow_attractor(self.program, z, float(self.V[i]), start)
            if orbit is not None:
                slow[k] = orbit
        for k, row in zip(slow, self._shoot(z, [requests[k][0] for k in slow], list(slow.values()))):
            if not classify(_as_batch(row), 0, None, 0, None):
                rows[k] = row
        order = sorted(rows)
        out = [None] * len(requests)
        for k, row in zip(order, self._minimal_rows(z, [(requests[k][0], rows[k]) for k in order])):
            row["attractor"] = dataclasses.replace(row["attractor"],
                                                   how=f"found again ({requests[k][2]}): {row['attractor'].how}")  # fmt: skip
            out[k] = row
        return out

    def _minimal_rows(self, z, items: list[tuple[int, dict]]) -> list[dict]:
        """Each orbit (``items``: its row and the shot) with its least k: a near repeat of k
        events may be an orbit of k/m slips run m times (the same statistics per slip, other
        multipliers). Each proper divisor d of k is shot from the orbit's section point, every
        divisor of every row in one batched call: where P^d returns there (Newton converged on
        the point itself), the orbit has d slips per period, the smallest such d taken."""
        trials, whose = [], []
        for k, (i, row) in enumerate(items):
            a = row["attractor"]
            if a.minimal:
                continue
            slips = int(row["slips"])
            for d in range(1, slips):
                if slips % d == 0:
                    trials.append((i, Attractor(a.section, d, a.period * d / slips, a.how)))
                    whose.append((k, d))
        shots = self._shoot(z, [i for i, _ in trials], [a for _, a in trials])
        out = [row for _, row in items]
        done = set()
        for (k, d), trial in zip(whose, shots):
            row = items[k][1]
            if k in done or int(trial["status"]) != 0 or np.max(np.abs(trial["z"] - row["z"])) > SAME_POINT:
                continue
            if not classify(_as_batch(trial), 0, None, 0, None):
                trial["attractor"] = dataclasses.replace(trial["attractor"], how=f"{row['attractor'].how}: an orbit "
                                                         f"of {d} slips", minimal=True)  # fmt: skip
                out[k] = trial
                done.add(k)
        for k, (_, row) in enumerate(items):
            if k not in done:
                row["attractor"] = dataclasses.replace(row["attractor"], minimal=True)
        return out

    def from_rest(self, point: Point) -> list[int]:
        """The orbit rows whose attractor reached from rest (a run from the paper's initial data,
        as a peel test starts) is not the one ``point`` follows: several attractors coexist."""
        differ = []
        rows = self.rows["orbit"]
        for i, found in zip(rows, self._refind_rows(point.z, [(i, None, "from rest") for i in rows])):
            followed = point.orbits.get(i)
            if found is None and followed is None:
                continue
            # one orbit has k section points: compare what they share, k and the statistics
            if (found is None) != (followed is None) or int(found["slips"]) != int(followed["slips"]) or np.max(
                    np.abs(found["statistics"] / followed["statistics"] - 1)) > SAME_ORBIT:  # fmt: skip
                differ.append(i)
        return differ


def attractor_rows(model: PeelingModel, start: AdhesionLaw, V, data, sigma, measured, *, window_options: dict,
                   orbit_rtol: float, cycle_scatter: bool = True, follow_lost: bool = True) -> tuple[TableRows, list[str]]:  # fmt: skip
    """The :class:`TableRows` of (n, 5) ``data``/``sigma``/``measured`` at the pull velocities
    ``V`` with φ = ``start`` (``model``'s spool and tape), and why each row has its kind: each
    row's attractor found (:func:`row_kinds`, its orbits shot at ``orbit_rtol``), the window
    rows' program built with ``window_options`` (:func:`~peeljax.fit.window_rows.build_table_fit`'s,
    ``names`` among them). ``follow_lost``: an orbit row that loses its orbit at a trial θ takes
    its window statistics (else it is left without)."""
    V = np.asarray(V, float)
    names = tuple(window_options["names"])
    program = OrbitRows(orbit_shooting(rtol=orbit_rtol), model, start, names)
    kinds, starts, why = row_kinds(eqx.tree_at(lambda m: m.adhesion, model, start), V, program=program)
    window = [i for i, k in enumerate(kinds) if k == "window"]
    window_fit = None
    if window:
        window_fit = build_table_fit(start, model, V[window], data[window], sigma[window], measured[window],
                                     **window_options)  # fmt: skip
    rows = TableRows(data, sigma, measured, V, kinds, starts, model=model, start=start, names=names,
                     program=program if "orbit" in kinds else None, window_fit=window_fit,
                     cycle_scatter=cycle_scatter, window_options=window_options if follow_lost else None)  # fmt: skip
    return rows, why


def singular_rows(values, jac, available, rows) -> dict[int, float]:
    """The ``rows`` whose derivative is singular, with their largest elasticity
    |∂ log s / ∂ log c| (> :data:`MAX_ELASTICITY`).

    Near a grazing (a slip that barely reaches φ's fold) an orbit's statistics have derivatives
    that grow like the inverse square root of the distance to it: right only within that
    distance, beyond which the attractor is another orbit whose per-slip averages are close
    (a grazing changes the slips per period, not the averages). Such a row's derivative
    would pin the fit to a step of 1e-8 (measured: 8 rows at 0.5–4 m/s, elasticities 1.6e6
    and 2.2e3 at 3.5 and 4 m/s; Levenberg–Marquardt stopped at its start, every coefficient
    6–8 % off). The row stays in χ², which judges every step, but not in the step's direction
    nor in the linearized intervals (its Jacobian rows are zero). A window row's statistics can
    be as steep where a slip nearly touches the fold or the window's edge (measured: a
    covariance of 1e-33 at 4 m/s on the same table): every row is judged alike."""
    out = {}
    for i in rows:
        scale = np.where(available[i], np.abs(values[i]), np.inf)[:, None]
        elasticity = float(np.max(np.abs(jac[i]) / np.maximum(scale, 1e-300), initial=0.0))
        if elasticity > MAX_ELASTICITY:
            out[i] = elasticity
    return out


def _as_batch(row: dict) -> dict:
    """One row's dict as a batch of one (what :func:`~peeljax.fit.attractors.classify` reads)."""
    return {key: np.asarray(value)[None] for key, value in row.items() if key != "attractor"}
