"""Records fitted point by point, by Levenberg–Marquardt, with uncertainties.

A force record that does not stick-slip — the transient from rest settling to steady peeling,
or steady peeling itself — has no slips to take statistics of; it is fitted sample by sample:

    r_qi = (q_model(t_i; θ) − q_i)/σ_q,

q ∈ {F, v, alpha} the quantities the record holds, q_model the homogenized ODE's run at τ from
the paper's initial data at the record's V (its dense output at the record's times), σ_q the
record's own white-noise level of q (:func:`~peeljax.measurements.statistics.noise_level`;
floored at 1e-6 of the record's RMS).
r and its Jacobian come from one forward-mode pass (one tangent per free coefficient, through
the α-method's implicit steps); the fit is the table fit's Levenberg–Marquardt
(:mod:`peeljax.fit.table`), and its covariance is s²(JᵀJ)⁻¹ (:mod:`peeljax.fit.uncertainty`,
scaled by χ²/dof where that exceeds 1 — the noise estimate too small, or correlated noise).

:class:`PointRows` has the interface of :class:`~peeljax.fit.table_rows.TableRows` (``start``,
``evaluate``), so records fitted point by point and table rows can be fitted together
(:class:`Joint`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._exported import compiled
from ..adhesion import AdhesionLaw
from ..homogenized import HomogenizedODE
from ..integrators.select import integrator_for
from ..model import PeelingModel
from .table_rows import Point
from .window_rows import MISSING_RESIDUAL
from .parameters import law_from, value_and_jacfwd
from ..measurements.observations import Observation
from ..measurements.statistics import noise_level

__all__ = ["Joint", "PointRows", "noise_level"]

QUANTITIES = ("F", "v", "alpha")
_FLOOR = 1e-6  # σ_q ≥ this × the record's RMS of q (a noise-free record)


class _Series(eqx.Module):
    """The records padded to one length: per record V, times (R, m), values (R, Q, m), σ (R, Q),
    mask (R, Q, m)."""

    V: jax.Array
    t: jax.Array
    values: jax.Array
    sigma: jax.Array
    mask: jax.Array


class _PointResiduals(eqx.Module):
    """r(θ) and ∂r/∂θ of the records (module docstring), and the v range visited, compiled once."""

    model: PeelingModel
    start: AdhesionLaw
    tau: jax.Array
    integrator: object
    series: _Series
    names: tuple[str, ...] = eqx.field(static=True)
    t_final: float = eqx.field(static=True)

    def residuals(self, theta):
        law = law_from({n: theta[k] for k, n in enumerate(self.names)}, self.start)
        model = eqx.tree_at(lambda m: m.adhesion, self.model, law)
        s = self.series

        def one(args):
            V, t, values, sigma, mask = args
            sol = self.integrator.integrate(HomogenizedODE(model, V, self.tau), model.initial_state(V), 0.0,
                                            self.t_final, jnp.clip(t, 0.0, self.t_final))  # fmt: skip
            ys = jnp.where(sol.valid[:, None], sol.ys, 1.0)  # the double where: no NaN in a derivative
            q = {"F": model.tension(ys[:, 2], ys[:, 0]), "v": ys[:, 3], "alpha": ys[:, 0]}
            reached = sol.valid[: t.size] & (t <= jax.lax.stop_gradient(sol.t_stop) + 1e-9 * self.t_final)
            model_q = jnp.stack([q[name][: t.size] for name in QUANTITIES])
            r = (model_q - values) / sigma[:, None]
            r = jnp.where(reached[None, :], r, MISSING_RESIDUAL)
            v = jax.lax.stop_gradient(jnp.where(sol.valid, ys[:, 3], jnp.nan))
            return jnp.where(mask, r, 0.0), jnp.stack([jnp.nanmin(v), jnp.nanmax(v)])

        return jax.lax.map(one, (s.V, s.t, s.values, s.sigma, s.mask))

    def __call__(self, theta):
        (r, v_range), jac = value_and_jacfwd(self.residuals, theta)
        return r, jac, v_range


_evaluate = compiled(lambda program, theta: program(theta), "point_rows")  # traced once per machine


class PointRows:
    """Records fitted point by point (module docstring), with the interface of
    :class:`~peeljax.fit.table_rows.TableRows`.

    Args:
        observations: the records (each an :class:`~peeljax.fit.Observation`; ``F``, ``v``,
            ``alpha`` whichever it holds).
        model, start, names: spool and tape, φ at θ = 0, the free coefficients.
        tau: the homogenized ODE's τ [s] (> 0); rtol, atol: its tolerances; t_final: the runs' end
            (default: the last sample).
    """

    def __init__(self, observations: Sequence[Observation], *, model: PeelingModel, start: AdhesionLaw, names, tau,
                 rtol=1e-8, atol=1e-10, t_final=None, max_steps=None):  # fmt: skip
        self.observations, self.names = list(observations), tuple(names)
        self.kinds = ["points"] * len(self.observations)
        series = [[o.series(q) for q in QUANTITIES] for o in self.observations]
        m = max(len(s[0]) for row in series for s in row if s is not None)
        R = len(self.observations)
        t = np.zeros((R, m))
        values = np.zeros((R, len(QUANTITIES), m))
        sigma = np.ones((R, len(QUANTITIES)))
        mask = np.zeros((R, len(QUANTITIES), m), bool)
        for j, row in enumerate(series):
            times = [s[0] for s in row if s is not None]
            base = times[0]
            if any(tq.shape != base.shape or not np.array_equal(tq, base) for tq in times):
                raise ValueError(f"observation at V = {self.observations[j].V:g}: fitted point by point, its "
                                 "quantities must share their times")  # fmt: skip
            t[j, : base.size], t[j, base.size :] = base, base[-1]
            for k, s in enumerate(row):
                if s is None:
                    continue
                values[j, k, : s[1].size] = s[1]
                mask[j, k, : s[1].size] = True
                rms = float(np.sqrt(np.mean(s[1] ** 2)))
                sigma[j, k] = max(noise_level(s[1]), _FLOOR * max(rms, 1e-300))
        self.sigma = sigma
        self.measured_mask = mask
        t_final = float(np.max(t)) if t_final is None else float(t_final)
        budget = {} if max_steps is None else {"max_steps": max_steps}
        integrator = integrator_for(None, t_final=t_final, rtol=rtol, atol=atol, fold="stop", adjoint="forward", **budget)
        self.program = _PointResiduals(
            model=model, start=start, tau=jnp.asarray(float(tau)), integrator=integrator,
            series=_Series(V=jnp.asarray([o.V for o in self.observations], float), t=jnp.asarray(t),
                           values=jnp.asarray(values), sigma=jnp.asarray(sigma), mask=jnp.asarray(mask)),
            names=self.names, t_final=t_final,
        )  # fmt: skip
        self.evaluations = 0

    @property
    def size(self) -> int:
        """The number of residuals (the measured samples)."""
        return int(self.measured_mask.sum())

    def start(self) -> Point:
        return self.evaluate(np.zeros(len(self.names)), None)

    def evaluate(self, z, base=None) -> Point:
        self.evaluations += 1
        z = np.asarray(z, float)
        r, jac, v_range = (np.asarray(a) for a in _evaluate(self.program, jnp.asarray(z)))
        keep = self.measured_mask
        return Point(z=z, r=r[keep], J=jac[keep], v_range=v_range, values=np.zeros((0, 5)),
                     available=np.zeros((0, 5), bool), attractors=[], orbits={},
                     branch=())  # fmt: skip

    def from_rest(self, point) -> list[int]:
        return []

    def forget(self, point, rows):
        return point


class Joint:
    """Table rows and records fitted point by point together: their residuals and Jacobians
    stacked (the table's first), each part following its own attractors."""

    def __init__(self, table, points: PointRows):
        self.table, self.points = table, points
        self.kinds = list(table.kinds) + list(points.kinds)

    @property
    def evaluations(self) -> int:
        return self.table.evaluations

    def start(self) -> Point:
        return self._join(self.table.start(), self.points.start())

    def evaluate(self, z, base=None) -> Point:
        table = self.table.evaluate(z, None if base is None else base.parts[0])
        return self._join(table, self.points.evaluate(z))

    def from_rest(self, point) -> list[int]:
        return self.table.from_rest(point.parts[0])

    def forget(self, point, rows):
        return self._join(self.table.forget(point.parts[0], rows), point.parts[1])

    def update_bias(self, point) -> float:
        return self.table.update_bias(point.parts[0])

    @property
    def has_instruments(self) -> bool:
        return self.table.has_instruments

    @staticmethod
    def _join(table: Point, points: Point) -> Point:
        joined = dataclasses.replace(
            table, r=np.concatenate([table.r, points.r]), J=np.concatenate([table.J, points.J]),
            v_range=np.concatenate([table.v_range, points.v_range]),
        )  # fmt: skip
        joined.parts = (table, points)
        return joined
