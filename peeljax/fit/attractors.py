"""Each stick-slip row's attractor: found from a run, followed from step to step, checked.

A table fit on the attractor's own statistics (:mod:`peeljax.fit.table`) needs, at every trial
point θ of Levenberg–Marquardt, the periodic orbit each row is on (:mod:`peeljax.orbits`):

* **found** once, at the start: a run of the DAE (τ = 0) from the paper's initial data, its
  repeat (:func:`peeljax.cycle_statistics` over its second half) or, where the run is too short
  to confirm one, its near repeat (:class:`peeljax.cycles.TooFewRepeats`) gives k (stick → slip
  events per period), the period and the state at the last slip, from which Newton shoots
  (:func:`find_attractor`); a run that shows neither continues once, longer, from where it
  ended, and where that one shows none either its last slip is kept (:class:`NoRepeat`), from
  which the stable orbits of a few slips are shot (:func:`peeljax.fit.table_rows.row_kinds`);
* **followed**: at a trial point every row is shot from the section point of the point it
  steps from, with its k (:class:`OrbitRows`: one compiled program for every row, k traced);
* **checked** (:func:`classify`): the orbit shot is the attractor the row was on only where
  Newton converged, every Floquet multiplier lies inside the unit circle, and the section point
  moved as its derivative predicts (|Δz − ∂z/∂θ·Δθ| within ``CONTINUITY`` of the step). Anything
  else — Newton failed, the orbit is unstable (a torus, period-doubling or fold bifurcation was
  crossed), or Newton jumped to another orbit with the same k (a grazing: a stick phase touched
  φ's maximum and the orbit it followed ended there) — means the step crossed a bifurcation; the
  row's attractor is then found again by a run from the old orbit's state under the trial θ
  (the system's own response to the change), as at the start. Past a period doubling (a
  multiplier through −1) the orbit of 2k slips born there is shot instead, from beside the
  k-orbit with Newton deflated away from it (:mod:`peeljax.fit.table_rows`): no run, and the
  statistics per slip continuous.

The orbit's statistics and their Jacobian come from the implicit function theorem on the fixed
point (:mod:`peeljax.orbits.shooting`): forward-mode passes through one period, two per Newton
iteration and 2 + p at its last point.
"""

from __future__ import annotations

import dataclasses
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._devices import batch_mesh, over_devices, put_lanes
from ..adhesion import AdhesionLaw
from ..branches import phi_folds
from ..cycles import cycle_statistics
from ..model import PeelingModel
from ..orbits.api import PERIODS_PER_RUN, orbit_of, orbit_shooting
from ..orbits.section import SlipSection
from ..orbits.shooting import FLOOR_RTOL, OrbitStatus, Shooting, at_floor, keep_converged
from ..simulate import simulate
from ..solution import Solution
from ..measurements.statistics import STATISTICS
from .parameters import law_from

__all__ = ["CONTINUITY", "Attractor", "NoRepeat", "OrbitRows", "RowOrbits", "classify", "find_attractor", "steady_rows"]

CONTINUITY = 0.25  # |Δz − ∂z/∂θ·Δθ| ≤ CONTINUITY·|∂z/∂θ·Δθ| + CONTINUITY_FLOOR: the same orbit, moved
CONTINUITY_FLOOR = 1e-6  # scaled section coordinates (radians, units of V/R)
RUNS = (3.0, 8.0)  # [s]: the runs that look for a repeat, the second from where the first ended
RUN_RTOL = 1e-7  # the runs only have to come close to the orbit: Newton does the rest


@dataclasses.dataclass(frozen=True)
class Attractor:
    """Where a row's periodic orbit is shot from: the section point s = (α, ω), k and a period
    guess T (bounding each period's run at 3T)."""

    section: np.ndarray
    slips: int
    period: float
    how: str = ""  # how it was found, in words
    minimal: bool = False  # k is the orbit's least number of slips per period (checked)


def _last_slip_state(sol: Solution) -> np.ndarray:
    """(α, ω) at the run's last stick → slip event, interpolated from its rows."""
    jumps = sol.jumps.as_numpy()
    t_slip = float(jumps["jump_t"][jumps["jump_up"]][-1])
    valid = np.asarray(sol.valid)
    ts, ys = np.asarray(sol.ts)[valid], np.asarray(sol.ys)[valid]
    return np.array([np.interp(t_slip, ts, ys[:, 0]), np.interp(t_slip, ts, ys[:, 1])])


@dataclasses.dataclass(frozen=True)
class NoRepeat:
    """Where a row's runs showed no repeat: why, in words, and where the last run's last slip
    was (an :class:`Attractor` of one slip whose period is the run's mean slip interval over
    its second half; None where the run stopped early or had no two slips there), from which
    an attractor the runs were too short to settle on can still be shot
    (:func:`peeljax.fit.table_rows.row_kinds`)."""

    why: str
    last: Attractor | None = None

    def __str__(self) -> str:
        return self.why


def _repeat_of(sol: Solution) -> tuple[int, float, str] | NoRepeat:
    """(k, T, how) of a run's repeat or near repeat over its second half, else why not, with
    the run's last slip where it ran to its end and slipped twice or more there."""
    t_stop = float(sol.t_stop)
    if not t_stop > 0 or sol.jumps is None:
        return NoRepeat("the run ended at once")
    stats = cycle_statistics(sol, t_stop, transient=0.5 * t_stop)
    if stats.repeat is not None:
        return stats.repeat.events, stats.repeat.period, f"a repeat of {stats.repeat.events} slips in a {t_stop:g} s run"
    near = stats.too_few
    if stats.slips > 0 and near is not None and near.events > 0:
        return near.events, near.period, f"a near repeat of {near.events} slips in a {t_stop:g} s run"
    if stats.slips == 0:
        why = "no stick → slip event in the run's second half"
    else:
        why = "no repeat in the run's second half (irregular)" if near is None else "too few slips to tell"
    ran = int(sol.status) == 0 and np.asarray(sol.valid).any()
    last = Attractor(_last_slip_state(sol), 1, stats.slip_interval.mean, why) if ran and stats.slip_interval.n else None
    return NoRepeat(why, last)


def find_attractor(model: PeelingModel, V: float, y0=None, runs=RUNS) -> Attractor | NoRepeat:
    """The start of a row's orbit (module docstring): from a run of ``runs[0]`` seconds from
    ``y0`` (default: the paper's initial data), else one of ``runs[1]`` from where it ended.
    Returns an :class:`Attractor` or, where no run shows a repeat, a :class:`NoRepeat` (why
    not, and the last run's last slip)."""
    found = NoRepeat("")
    for t_run in runs:
        sol = simulate(model, V=float(V), tau=0, t_final=float(t_run), y0=y0, rtol=RUN_RTOL, atol=1e-3 * RUN_RTOL)
        found = _repeat_of(sol)
        if not isinstance(found, NoRepeat):
            k, T, how = found
            return Attractor(_last_slip_state(sol), int(k), float(T), how)
        valid = np.asarray(sol.valid)
        if int(sol.status) != 0 or not valid.any():
            break
        y0 = np.asarray(sol.ys)[valid][-1]  # go on from where it ended
    return found


class OrbitRows(eqx.Module):
    """The periodic orbits of a table's stick-slip rows at θ, with their Jacobians in θ — one
    compiled program for every row (``__call__``; V, the start point, k and the period bound
    are traced, the rows run under ``vmap``).

    Attributes:
        shooting: how each orbit is shot (:func:`peeljax.orbits.orbit_shooting`).
        model: spool and tape; start: φ at θ = 0 (c = c_start·exp(θ) for ``names``).
        names: the free coefficients (static).
    """

    shooting: Shooting
    model: PeelingModel
    start: AdhesionLaw
    names: tuple[str, ...] = eqx.field(static=True)
    batch: str = eqx.field(static=True, default="map")  # rows one after another (measured 7x faster than vmap)

    def __call__(self, theta: Float[Array, "n p"], V: Float[Array, " n"], s0: Float[Array, "n 2"],
                 slips: Int[Array, " n"], t_max: Float[Array, " n"], avoid: Float[Array, "n 2"]) -> RowOrbits:  # fmt: skip
        """Row i's orbit at θ_i (each row its own θ: the rows of several points in one call);
        ``avoid``: a section point row i's Newton is kept away from (NaN: none)."""
        if self.batch == "map":
            return jax.lax.map(lambda row: self.row(*row), (theta, V, s0, slips, t_max, avoid))
        return jax.vmap(self.row)(theta, V, s0, slips, t_max, avoid)

    def row(self, theta, V, s0, slips, t_max, avoid) -> RowOrbits:
        def quantities(th):
            law = law_from({n: th[i] for i, n in enumerate(self.names)}, self.start)
            model = eqx.tree_at(lambda m: m.adhesion, self.model, law)
            orbit = orbit_of(self.shooting, model, V, s0, slips, t_max, avoid)
            section = SlipSection.at(model, V)
            stats = jnp.stack([orbit.statistics[s] for s in STATISTICS])
            z = orbit.section / section.scale
            v_slip = section.after_slip(orbit.section)[3]  # the fastest v of the period: just after a slip
            return (stats, z), (orbit, v_slip, stats)

        (d_stats, d_z), (orbit, v_slip, stats) = jax.jacfwd(quantities, has_aux=True)(theta)
        return RowOrbits(
            statistics=stats, jacobian=d_stats, section=orbit.section, z=orbit.section
            / SlipSection.at(orbit.model, V).scale, z_jacobian=d_z, slips=orbit.slips, period=orbit.period,
            status=orbit.status, multipliers=jnp.abs(orbit.multipliers), approach=orbit.approach,
            crossing=orbit.crossing, v_slip=jax.lax.stop_gradient(v_slip), residual=orbit.residual,
            monodromy=orbit.monodromy,
        )  # fmt: skip


class RowOrbits(eqx.Module):
    """What :class:`OrbitRows` gives per row (a leading axis over the rows).

    Attributes:
        statistics: the five statistics over one period (:data:`STATISTICS`); jacobian: their
            derivatives in θ (5 × p).
        section: s = (α, ω) on the section; z: scaled (s/(1 rad, V/R)); z_jacobian: ∂z/∂θ.
        slips, period: k and T; status: :class:`~peeljax.orbits.OrbitStatus`; multipliers:
            their moduli; approach, crossing: the grazing monitors (:class:`~peeljax.orbits.PeriodicOrbit`);
            v_slip: v just after the slip at the section [m/s]; residual: |P^k(z) − z| at the last
            iterate (scaled); monodromy: M = ∂P^k/∂s (2 × 2).
    """

    statistics: Array
    jacobian: Array
    section: Array
    z: Array
    z_jacobian: Array
    slips: Array
    period: Array
    status: Array
    multipliers: Array
    approach: Array
    crossing: Array
    v_slip: Array
    residual: Array
    monodromy: Array


@eqx.filter_jit
def _rows(program: OrbitRows, theta, V, s0, slips, t_max, avoid, mesh):
    """The rows under ``shard_map`` over ``mesh`` (one row per device), or as they are (None)."""
    return over_devices(lambda program, *row: program(*row), mesh, (program,), (theta, V, s0, slips, t_max, avoid))


def shoot_rows(program: OrbitRows, theta: np.ndarray, V, attractors: list[Attractor], avoid=None) -> dict[str, np.ndarray]:
    """The orbits of the rows at ``V`` from their ``attractors`` at θ ((p,) for all rows, or
    (n, p): one per row), as NumPy arrays with a leading axis over the rows; ``avoid`` (n, 2):
    a section point each row's Newton is kept away from (deflation; NaN or None: none).

    The rows go to the devices one each (on a CPU one device per core: the rows of a table
    run side by side), as many calls as it takes, the last padded with a repeat of its last
    row: one compiled program, of one row per device, serves tables of any length.

    A row whose Newton stops at its floor (not converged, |P^k(z) − z| below
    :data:`~peeljax.orbits.shooting.FLOOR_RESIDUAL`: the runs' own error near a grazing) is shot
    again from its last iterate with the runs at :data:`~peeljax.orbits.shooting.FLOOR_RTOL`, as
    the attractor map does (the same program: the tolerance is traced), and taken where it
    converges. Without it the row at 4 m/s of the whole-range table lost its orbit at every
    other step of c1 (0.05 %), its window statistics taken instead, 3.7 σ away."""
    out = _shoot_rows(program, theta, V, attractors, avoid)
    rtol = float(program.shooting.integrator.controller.rtol)
    floor = at_floor(out["status"], out["residual"], out["section"], out["period"])
    if floor.size == 0 or rtol <= FLOOR_RTOL:
        return out
    shooting = orbit_shooting(rtol=FLOOR_RTOL, max_iterations=int(program.shooting.max_iterations))
    tight = eqx.tree_at(lambda p: p.shooting, program, shooting)
    theta = np.broadcast_to(np.asarray(theta, float), (len(attractors), len(program.names)))
    last = [dataclasses.replace(attractors[j], section=out["section"][j], period=float(out["period"][j])) for j in floor]
    again = _shoot_rows(tight, theta[floor], np.asarray(V, float)[floor], last, None if avoid is None else np.asarray(avoid)[floor])
    keep_converged(out, again, floor)
    return out


def _shoot_rows(program: OrbitRows, theta: np.ndarray, V, attractors: list[Attractor], avoid=None) -> dict[str, np.ndarray]:
    """:func:`shoot_rows` without the second try at Newton's floor."""
    n = len(attractors)
    theta = np.broadcast_to(np.asarray(theta, float), (n, len(program.names)))
    avoid = np.full((n, 2), np.nan) if avoid is None else np.asarray(avoid, float).reshape(n, 2)
    lanes = [theta, np.asarray(V, float), np.stack([np.asarray(a.section, float) for a in attractors]),
             np.asarray([a.slips for a in attractors], np.int32),
             np.asarray([PERIODS_PER_RUN * a.period for a in attractors], float), avoid]  # fmt: skip
    devices = jax.local_devices()  # a fit is one process's work, even under jax.distributed
    mesh = batch_mesh(devices)
    outs = []
    for begin in range(0, n, len(devices)):  # every call dispatched before any is read
        rows = np.minimum(np.arange(begin, begin + len(devices)), n - 1)
        chunk = [a[rows] for a in lanes]
        chunk = put_lanes(chunk, devices) if mesh is not None else [jnp.asarray(a) for a in chunk]
        outs.append(_rows(program, *chunk, mesh=mesh))
    outs = [jax.tree_util.tree_map(np.asarray, o) for o in outs]
    return {f.name: np.concatenate([np.asarray(getattr(o, f.name)) for o in outs])[:n] for f in dataclasses.fields(RowOrbits)}


def classify(row: dict, i: int, before: dict | None, i_before: int | None, d_theta: np.ndarray) -> str:
    """"" (the orbit followed is the row's attractor) or why not (module docstring): row ``i``
    of :func:`shoot_rows`'s arrays against row ``i_before`` of ``before`` (None: nothing to
    compare with), θ having moved by ``d_theta``."""
    status = int(row["status"][i])
    if status != OrbitStatus.CONVERGED:
        return f"the orbit was not found ({OrbitStatus(status).name.lower()})"
    mult = float(np.max(row["multipliers"][i]))
    if not mult < 1.0:
        return f"the orbit is unstable (|multiplier| {mult:.3g})"
    if before is not None:
        predicted = before["z_jacobian"][i_before] @ d_theta
        moved = row["z"][i] - before["z"][i_before]
        if np.max(np.abs(moved - predicted)) > CONTINUITY * np.max(np.abs(predicted)) + CONTINUITY_FLOOR:
            return "Newton reached another orbit (its section point jumped)"
    return ""


def steady_rows(model: PeelingModel, V) -> np.ndarray:
    """True where steady peeling is stable at V: φ(·, V) has no fold, or v = V lies on one of its
    rising branches (∂φ/∂v(V, V) > 0); there the tension is F = φ(V, V) (α = 0)."""
    V = jnp.asarray(V, float)
    slope = jax.vmap(jax.grad(lambda v, Vi: model.phi(v, Vi)))(V, V)
    exist = jax.vmap(lambda Vi: phi_folds(model, Vi).exist)(V)
    return np.asarray(~exist | (slope > 0))


def steady_force(model: PeelingModel, start: AdhesionLaw, names, theta, V):
    """F_mean = φ(V, V) of the steady rows and its derivatives in θ (n, p)."""
    force, jac = _steady(start, tuple(names), jnp.asarray(theta, float), jnp.asarray(V, float))
    return np.asarray(force), np.asarray(jac)


@eqx.filter_jit
def _steady(start, names, theta, V):
    def force(th):
        law = law_from({n: th[i] for i, n in enumerate(names)}, start)
        return jax.vmap(lambda Vi: law(Vi, Vi))(V)

    return force(theta), jax.jacfwd(force)(theta)

