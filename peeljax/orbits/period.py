"""One period of a stick-slip orbit: the return map after k stick → slip events, and what a
record of that period shows.

From a point s of the section Σ (:mod:`peeljax.orbits.section`) the tape slips (v jumps to the
slip branch at fixed x), and the DAE (τ = 0) is integrated by the one error-controlled loop
with its fold events (:mod:`peeljax.integrators.events`): every fold is located, jumped and
recorded. Stick → slip and slip → stick jumps alternate, so the k-th stick → slip fold after
the start is the 2k-th fold: a jump record of 2k − 1 slots stops the run there, at the fold,
before its jump (``StopReason.MAX_JUMPS``), and its state is P^k(s), the return map after k
events. The loop differentiates every event time and jumped state by the implicit function
theorem, so forward-mode derivatives of P^k include the saltation of every jump.

The same run gives the period's statistics exactly — the five a stick-slip table holds
(:data:`peeljax.fit.STATISTICS`), over one period [0, T] of the orbit:

* ``F_mean``: the time average of the tension F over the period, ∫₀ᵀ F dt / T, by 4-point
  Gauss–Legendre quadrature on each accepted step's own interpolant
  (:class:`ForceIntegral`; in pseudo-time ∫ F·(dt/ds) ds);
* ``F_slip``, ``F_stick``: the means of F at the k stick → slip and the k slip → stick jumps;
* ``period``: the mean time between slips, T/k;
* ``slip_duration``: the mean time from a stick → slip jump to the next slip → stick jump.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..constrained import ConstrainedDAE
from ..integrators.adaptive import ErrorControl
from ..integrators.dense import PhysicalTimeInterpolant
from ..integrators.log_variables import from_log
from ..integrators.observers import AcceptedStep, Observer
from ..model import PeelingModel
from ..solution import JumpRecord, StopReason
from .section import SlipSection

__all__ = ["ForceIntegral", "OnePeriod", "one_period", "period_statistics"]

_NODES, _WEIGHTS = (jnp.asarray(a) for a in np.polynomial.legendre.leggauss(4))


class ForceIntegral(Observer):
    """∫ F dt over the accepted steps: 4-point Gauss–Legendre on each step's interpolant.

    The interpolant of a step in pseudo-time (:class:`~peeljax.DesingularizedDAE`) carries t as
    a component: there ∫ F dt = ∫ F(y(s))·t'(s) ds over the step's [s0, s1], t'(s) by
    autodiff of the interpolant. The error is the interpolant's (the stepper's dense output,
    fourth order for Tsit5): below the run's tolerance (measured in ``tests/test_orbits.py``).
    """

    model: PeelingModel
    log_components: tuple[int, ...] = eqx.field(static=True)

    def init(self, t0, y0, J0, ok):
        return jnp.zeros(())

    def update(self, total, step: AcceptedStep, kind: str):
        interpolant = step.interpolant
        if isinstance(interpolant, PhysicalTimeInterpolant):
            inner, a, b, time_index = interpolant.interpolant, interpolant.s0, interpolant.s1, interpolant.time_index
        else:
            inner, a, b, time_index = interpolant, step.t0, step.t1, None

        def integrand(s):
            y = from_log(inner.evaluate(s[None])[0], self.log_components)
            F = self.model.tension(y[2], y[0])
            if time_index is None:
                return F
            rate = jax.jvp(lambda q: inner.evaluate(q[None])[0, time_index], (s,), (jnp.ones_like(s),))[1]
            return F * rate

        nodes = 0.5 * (a + b) + 0.5 * (b - a) * _NODES
        part = 0.5 * (b - a) * jnp.sum(_WEIGHTS * jax.vmap(integrand)(nodes))
        return total + jnp.where(step.advance, part, 0.0)


class OnePeriod(eqx.Module):
    """A run from s on Σ through k stick → slip events (module docstring).

    Attributes:
        end: the coordinates P^k(s) of the k-th stick → slip fold.
        end_state: the state (α, ω, u, v) there, before its jump.
        time: the time T from s to P^k(s) [s].
        force_integral: ∫₀ᵀ F dt [N·s].
        jumps: the 2k jumps of the period, the slip at s (t = 0) first.
        reached: True where the run stopped at the k-th stick → slip fold (else it ended for
            ``status`` before: the orbit's events changed, or the run could not go on).
        status: the run's :class:`~peeljax.StopReason` (``MAX_JUMPS`` when ``reached``).
        steps: accepted + rejected step attempts.
    """

    end: Float[Array, "2"]
    end_state: Float[Array, "4"]
    time: Float[Array, ""]
    force_integral: Float[Array, ""]
    jumps: JumpRecord
    reached: Bool[Array, ""]
    status: Int[Array, ""]
    steps: Int[Array, ""]


def one_period(
    section: SlipSection, integrator: ErrorControl, s: Float[Array, "2"], t_max: Float[Array, ""]
) -> OnePeriod:
    """The run from s on Σ to its k-th stick → slip fold, k = (record size + 1)/2 of the
    integrator's fold events (module docstring); ``t_max`` bounds it."""
    model, V = section.model, section.V
    y0 = section.after_slip(s)
    stepper = integrator.stepper
    run = integrator.observe(ConstrainedDAE(model, V, section.folds), y0, 0.0, t_max, ForceIntegral(model, stepper.carried_log))
    reached = run.status == StopReason.MAX_JUMPS
    x0 = section.state(s)[:3]
    first = JumpRecord(
        t=jnp.zeros(1), up=jnp.ones(1, bool), v_before=section.folds.v_max[None], v_after=y0[3][None],
        G=section.folds.phi_max[None], count=jnp.asarray(1, jnp.int32), F=model.tension(x0[2], x0[0])[None],
    )  # fmt: skip
    jumps = JumpRecord(
        t=jnp.concatenate([first.t, run.jumps.t]),
        up=jnp.concatenate([first.up, run.jumps.up]),
        v_before=jnp.concatenate([first.v_before, run.jumps.v_before]),
        v_after=jnp.concatenate([first.v_after, run.jumps.v_after]),
        G=jnp.concatenate([first.G, run.jumps.G]),
        count=run.jumps.count + 1,
        F=jnp.concatenate([first.F, run.jumps.F]),
    )
    return OnePeriod(
        end=section.coordinates(run.y_final),
        end_state=run.y_final,
        time=run.t_stop,
        force_integral=run.record,
        jumps=jumps,
        reached=reached,
        status=run.status,
        steps=run.accepted_steps + run.rejected_steps,
    )


def period_statistics(period: OnePeriod) -> dict[str, Array]:
    """The five statistics of one period (module docstring), keyed as a stick-slip table's
    columns: ``F_mean``, ``F_slip``, ``F_stick`` [N], ``period``, ``slip_duration`` [s]."""
    jumps = period.jumps
    # Slots past the count (a run that ended early: ``reached`` False) count as nothing, so
    # the statistics stay finite and so do their derivatives; the orbit's status says why.
    valid = jnp.arange(jumps.max_jumps) < jumps.count
    up = valid & jumps.up
    down = valid & ~jumps.up
    F = jnp.where(valid, jumps.F, 0.0)
    t = jnp.where(valid, jumps.t, 0.0)
    F_slip = jnp.sum(jnp.where(up, F, 0.0)) / jnp.maximum(jnp.sum(up), 1)
    F_stick = jnp.sum(jnp.where(down, F, 0.0)) / jnp.maximum(jnp.sum(down), 1)
    # Jumps alternate, the slip at t = 0 first: slip i starts at slot 2i and ends at slot 2i + 1.
    ended = valid[1::2]
    durations = jnp.where(ended, t[1::2] - t[0::2], 0.0)
    slips = (jumps.max_jumps + 1) // 2
    T = period.time
    return {
        "F_mean": period.force_integral / jnp.where(T > 0, T, 1.0),
        "F_slip": F_slip,
        "F_stick": F_stick,
        "period": T / slips,
        "slip_duration": jnp.sum(durations) / jnp.maximum(jnp.sum(ended), 1),
    }
