"""One period of a stick-slip orbit: the return map after k stick → slip events, and what a
record of that period shows.

From a point s of the section Σ (:mod:`peeljax.orbits.section`) the tape slips (v jumps to the
slip branch at fixed x), and the DAE (τ = 0) is integrated by the one error-controlled loop
with its fold events (:mod:`peeljax.integrators.events`): every fold is located, jumped and
recorded. Stick → slip and slip → stick jumps alternate, so the next stick → slip fold after
the start is the second fold: a jump record of one slot stops the run there, at the fold,
before its jump (``StopReason.MAX_JUMPS``). Its state is the return map after one event,
P(s) (:func:`one_slip`); the return map after k events is its k-fold composition,

    P^k = P ∘ … ∘ P,

run as a loop whose trip count k is a traced integer: one compiled program serves every number
of slips per period, as continuation needs where k changes along a branch. The loop
differentiates every event time and jumped state by the implicit function theorem, so
forward-mode derivatives of P^k include the saltation of every jump.

The same runs give the period's statistics exactly — the five a stick-slip table holds
(:data:`peeljax.measurements.STATISTICS`), over one period [0, T] of the orbit:

* ``F_mean``: the time average of the tension F over the period, ∫₀ᵀ F dt / T, by 4-point
  Gauss–Legendre quadrature on each accepted step's own interpolant
  (:class:`ForceIntegral`; in pseudo-time ∫ F·(dt/ds) ds);
* ``F_slip``, ``F_stick``: the means of F at the k stick → slip and the k slip → stick jumps;
* ``period``: the mean time between slips, T/k;
* ``slip_duration``: the mean time from a stick → slip jump to the next slip → stick jump.

And how close the period comes to a grazing (:class:`ForceIntegral`'s ``approach``): the
largest fold distance G − φ(v̂) the stick phases reach while G falls (an interior maximum of
G short of the fold: where it reaches 0, a new slip appears and k changes), and likewise
φ(v̌) − G while G rises in a slip phase (a slip that nearly re-sticks). Negative; 0 at a
grazing.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..branches import SLIP, branch_of
from ..constrained import ConstrainedDAE
from ..integrators.adaptive import ErrorControl
from ..integrators.dense import PhysicalTimeInterpolant
from ..integrators.log_variables import from_log
from ..integrators.observers import AcceptedStep, Observer
from ..model import PeelingModel
from ..solution import StopReason
from .section import SlipSection

__all__ = ["ForceIntegral", "OnePeriod", "Slip", "one_period", "one_slip", "period_statistics"]

# numpy constants: a jnp array made at import would start XLA before jax.distributed.initialize can run
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(4)


class ForceIntegral(Observer):
    """∫ F dt over the accepted steps, 4-point Gauss–Legendre on each step's interpolant, and
the closest approach to a grazing at those nodes (module docstring): the record is
(∫ F dt, approach).

    The interpolant of a step in pseudo-time (:class:`~peeljax.DesingularizedDAE`) carries t as
    a component: there ∫ F dt = ∫ F(y(s))·t'(s) ds over the step's [s0, s1], t'(s) by
    autodiff of the interpolant. The error is the interpolant's (the stepper's dense output,
    fourth order for Tsit5): below the run's tolerance (measured in ``tests/test_orbits.py``).
    """

    model: PeelingModel
    V: Float[Array, ""]
    folds: object  # φ's folds at V (:class:`~peeljax.branches.Folds`)
    log_components: tuple[int, ...] = eqx.field(static=True)

    def init(self, t0, y0, J0, ok):
        return jnp.zeros(()), jnp.asarray(-jnp.inf)

    def update(self, record, step: AcceptedStep, kind: str):
        interpolant = step.interpolant
        if isinstance(interpolant, PhysicalTimeInterpolant):
            inner, a, b, time_index = interpolant.interpolant, interpolant.s0, interpolant.s1, interpolant.time_index
        else:
            inner, a, b, time_index = interpolant, step.t0, step.t1, None

        folds = self.folds

        def at_node(s):
            def state(q):
                return from_log(inner.evaluate(q[None])[0], self.log_components)

            y, dy = jax.jvp(state, (s,), (jnp.ones_like(s),))
            F = self.model.tension(y[2], y[0])
            rate = jnp.ones_like(s) if time_index is None else dy[time_index]
            # The fold distance while G turns back short of the fold (module docstring).
            G, G_dot = jax.jvp(self.model.shear_force, (y[:3],), (dy[:3],))
            slipping = branch_of(y[3], folds) == SLIP
            approach = jnp.where(
                slipping, jnp.where(G_dot > 0, folds.phi_min - G, -jnp.inf), jnp.where(G_dot < 0, G - folds.phi_max, -jnp.inf)
            )
            return F * rate, approach

        total, approach = record
        nodes = 0.5 * (a + b) + 0.5 * (b - a) * _NODES
        integrand, approaches = jax.vmap(at_node)(nodes)
        part = 0.5 * (b - a) * jnp.sum(_WEIGHTS * integrand)
        closest = jnp.maximum(approach, jnp.max(approaches))
        return jnp.where(step.advance, total + part, total), jnp.where(step.advance, closest, approach)


class _Return(eqx.Module):  # the fields a slip and a period share (a period's: sums over its slips)
    end: Float[Array, "2"]
    end_state: Float[Array, "4"]
    time: Float[Array, ""]
    force_integral: Float[Array, ""]
    F_slip: Float[Array, ""]
    F_stick: Float[Array, ""]
    slip_duration: Float[Array, ""]
    approach: Float[Array, ""]
    crossing: Float[Array, ""]
    reached: Bool[Array, ""]
    status: Int[Array, ""]
    steps: Int[Array, ""]


class Slip(_Return):
    """One return to the section: from s through a slip and a stick to the next slip.

    Attributes:
        end: the coordinates P(s) of the next stick → slip fold; end_state: the state there.
        time: the time to it [s]; force_integral: ∫ F dt over it [N·s].
        F_slip: F at the slip at s; F_stick: F at the re-stick [N]; slip_duration: the time
            from the slip to the re-stick [s].
        approach: the closest approach to a grazing (module docstring) [N].
        crossing: Ġ where the run reaches the next stick → slip fold [N/s]: positive for a
            transversal crossing, 0 where the slip is about to vanish (a grazing).
        reached: the run came to the next stick → slip fold (else ``status`` says why not).
        status: the run's :class:`~peeljax.StopReason`; steps: its step attempts.
    """


def one_slip(section: SlipSection, integrator: ErrorControl, s: Float[Array, "2"], t_max: Float[Array, ""]) -> Slip:
    """From s on Σ to the next stick → slip fold (module docstring); the integrator's fold
    events keep one jump (the re-stick); ``t_max`` bounds the run."""
    model, V, folds = section.model, section.V, section.folds
    y0 = section.after_slip(s)
    stepper = integrator.stepper
    observer = ForceIntegral(model, V, folds, stepper.carried_log)
    run = integrator.observe(ConstrainedDAE(model, V, folds), y0, 0.0, t_max, observer)
    force_integral, approach = run.record
    restick = run.jumps.count > 0
    x = run.y_final[:3]
    crossing = jax.jvp(model.shear_force, (x,), (model.f(x, folds.v_max, V),))[1]
    return Slip(
        end=section.coordinates(run.y_final),
        end_state=run.y_final,
        time=run.t_stop,
        force_integral=force_integral,
        F_slip=model.tension(y0[2], y0[0]),
        F_stick=jnp.where(restick, run.jumps.F[0], 0.0),
        slip_duration=jnp.where(restick, run.jumps.t[0], 0.0),
        approach=approach,
        crossing=crossing,
        reached=run.status == StopReason.MAX_JUMPS,
        status=run.status,
        steps=run.accepted_steps + run.rejected_steps,
    )


class OnePeriod(_Return):
    """k returns to the section from s (module docstring): sums over its slips.

    Attributes:
        end: P^k(s); end_state: the state there, before its slip.
        time: T, the time from s to P^k(s) [s]; force_integral: ∫₀ᵀ F dt [N·s].
        slips: the slips run (k where ``reached``).
        F_slip, F_stick, slip_duration: sums over the slips [N, N, s].
        approach: the closest approach to a grazing over the period [N].
        crossing: the slowest crossing of the section over the period, min Ġ [N/s].
        reached: every return came (else ``status`` says why the last did not).
        status: the last run's :class:`~peeljax.StopReason`; steps: step attempts in all.
    """

    slips: Int[Array, ""]


def one_period(
    section: SlipSection, integrator: ErrorControl, s: Float[Array, "2"], slips: Int[Array, ""], t_max: Float[Array, ""]
) -> OnePeriod:
    """P^k(s) and the period's sums: ``slips`` = k returns (a traced integer), each by
    :func:`one_slip`, within ``t_max`` in all."""
    zero = jnp.zeros(())
    start = OnePeriod(
        end=jnp.asarray(s, float), end_state=section.state(s), time=zero, force_integral=zero,
        slips=jnp.asarray(0, jnp.int32), F_slip=zero, F_stick=zero, slip_duration=zero,
        approach=jnp.asarray(-jnp.inf), crossing=jnp.asarray(jnp.inf), reached=jnp.asarray(True), status=jnp.asarray(StopReason.MAX_JUMPS, jnp.int32),
        steps=jnp.asarray(0, jnp.int32),
    )  # fmt: skip

    def more(p: OnePeriod):
        return (p.slips < slips) & p.reached

    def another(p: OnePeriod) -> OnePeriod:
        slip = one_slip(section, integrator, p.end, jnp.maximum(t_max - p.time, 0.0))
        return OnePeriod(
            end=slip.end, end_state=slip.end_state, time=p.time + slip.time,
            force_integral=p.force_integral + slip.force_integral, slips=p.slips + 1, F_slip=p.F_slip + slip.F_slip,
            F_stick=p.F_stick + slip.F_stick, slip_duration=p.slip_duration + slip.slip_duration,
            approach=jnp.maximum(p.approach, slip.approach), crossing=jnp.minimum(p.crossing, slip.crossing),
            reached=slip.reached, status=slip.status,
            steps=p.steps + slip.steps,
        )  # fmt: skip

    return jax.lax.while_loop(more, another, start)


def period_statistics(period: OnePeriod) -> dict[str, Array]:
    """The five statistics of one period (module docstring), keyed as a stick-slip table's
    columns: ``F_mean``, ``F_slip``, ``F_stick`` [N], ``period``, ``slip_duration`` [s].
    Finite where the period was not completed (its status says so)."""
    k = jnp.maximum(period.slips, 1)
    T = period.time
    return {
        "F_mean": period.force_integral / jnp.where(T > 0, T, 1.0),
        "F_slip": period.F_slip / k,
        "F_stick": period.F_stick / k,
        "period": T / k,
        "slip_duration": period.slip_duration / k,
    }
