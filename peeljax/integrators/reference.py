"""The reference integrator: diffrax on the same homogenized ODE ψ (eq. ``hv``).

Adaptive (PID) step control, Kvaerno5 by default, output on a grid, and failures reported like
the α-method's: near an impasse point the step size collapses, which the ``dtmin`` bound turns
into a ``STALLED`` stop instead of zero-length steps until ``max_steps``.

:func:`solution_from_diffrax` turns a ``diffrax.diffeqsolve`` result into a :class:`Solution`;
the direct and inertial alternatives (:mod:`peeljax.alternatives`) use it too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import diffrax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..homogenized import HomogenizedODE
from ..solution import Solution, StepDiagnostics, StopReason, mask_after_stop
from ..structure import local_index

__all__ = ["integrate_reference", "solution_from_diffrax"]


def _stop_reason(result) -> Array:
    R = diffrax.RESULTS
    code = jnp.where(result == R.successful, StopReason.COMPLETED, StopReason.SOLVER_FAILED)
    code = jnp.where(result == R.max_steps_reached, StopReason.MAX_STEPS, code)
    code = jnp.where(result == R.dt_min_reached, StopReason.STALLED, code)
    return code.astype(jnp.int32)


def solution_from_diffrax(
    sol: diffrax.Solution,
    y0: Float[Array, " 4"],
    ts: Float[Array, " n"] | None = None,
    *,
    ys: Float[Array, "n 4"] | None = None,
    method: str = "diffrax",
    stats: Mapping[str, ArrayLike] | None = None,
    diagnostics: Callable[[Array, Array], StepDiagnostics] | None = None,
) -> Solution:
    """A :class:`Solution` from a ``diffrax.diffeqsolve`` run made with ``throw=False``.

    diffrax does not stop at a failure: it returns a ``result`` code and fills the output points
    it never reached with ``inf``. This maps that onto peeljax's conventions:

    * ``valid``: the leading points where the integrated state ``sol.ys`` is finite (and, for
      ``SaveAt(steps=True)``, the saved time too); states after them are NaN (``mask_after_stop``).
      The mask comes from ``sol.ys`` even when ``ys`` is given: a state derived from it (v(x) of
      the state-space form) may be NaN at a point the solver did reach;
    * ``status``: ``successful`` → ``COMPLETED``; ``max_steps_reached`` → ``MAX_STEPS``;
      ``dt_min_reached`` → ``STALLED`` (the PID controller's step collapsed below ``dtmin``: at an
      impasse point or the fold of φ, where v̇ blows up); any other failure → ``SOLVER_FAILED``;
    * ``t_stop``: the last valid output time (the start ``sol.t0`` when none was saved);
    * ``stats``: ``steps`` (diffrax's ``num_steps``, step attempts), then the ``stats`` given.

    Args:
        sol: the diffrax solution, saved on a grid (``SaveAt(ts=ts)``) or at the steps
            (``SaveAt(steps=True)``).
        y0: the initial state (α, ω, u, v); it stands in for the states after the stop before they
            are masked, so that functions of them (diagnostics, gradients) stay finite.
        ts: the output grid of ``SaveAt(ts=ts)``, kept whole in ``Solution.ts``. ``None`` for
            ``SaveAt(steps=True)``: the saved step times, NaN in the unused entries.
        ys: the states (α, ω, u, v) at the saved points when the integrated state is something
            else (default ``sol.ys``).
        method: ``Solution.method``.
        stats: statistics added after ``steps``.
        diagnostics: called as ``diagnostics(states, valid)`` with the states above (``y0`` after
            the stop), gives ``Solution.diagnostics`` (default none).
    """
    finite = jnp.all(jnp.isfinite(sol.ys), axis=1)
    # The points after a failure are inf: the last finite point is where the run stopped.
    valid = jnp.cumprod(finite).astype(bool)
    if ts is None:
        valid = valid & jnp.isfinite(sol.ts)
        ts = jnp.where(valid, sol.ts, jnp.nan)
    n_valid = jnp.sum(valid)
    t_stop = jnp.where(n_valid > 0, ts[jnp.maximum(n_valid - 1, 0)], sol.t0)
    ys = sol.ys if ys is None else ys
    ys_safe = jnp.where(valid[:, None], ys, y0)
    return Solution(
        ts=ts,
        ys=mask_after_stop(ys_safe, valid),
        valid=valid,
        status=_stop_reason(sol.result),
        t_stop=t_stop,
        stats={"steps": sol.stats["num_steps"], **(stats or {})},
        diagnostics=None if diagnostics is None else diagnostics(ys_safe, valid),
        method=method,
    )


def integrate_reference(
    ode: HomogenizedODE,
    y0: Float[Array, " 4"],
    ts: Float[Array, " n"],
    *,
    solver: diffrax.AbstractSolver | None = None,
    rtol: ArrayLike = 1e-8,
    atol: ArrayLike = 1e-10,
    dt0: ArrayLike | None = None,
    dtmin: ArrayLike | None = None,
    max_steps: int = 100_000,
) -> Solution:
    """Solve y' = ψ(y) with diffrax, saving at ``ts`` (``ts[0]`` is the start).

    Args:
        solver: any diffrax solver (default ``Kvaerno5()``).
        rtol, atol: PID controller tolerances.
        dt0: first step (default 1e-6 of the span).
        dtmin: smallest step before the run is declared stalled (default 1e-12 of the span).
        max_steps: step budget (static).
    """
    solver = diffrax.Kvaerno5() if solver is None else solver
    ts = jnp.asarray(ts, float)
    y0 = jnp.asarray(y0, float)
    span = ts[-1] - ts[0]
    dt0 = 1e-6 * span if dt0 is None else dt0
    dtmin = 1e-12 * span if dtmin is None else dtmin
    controller = diffrax.PIDController(rtol=rtol, atol=atol, dtmin=dtmin, force_dtmin=False)
    term = diffrax.ODETerm(lambda t, y, args: ode(y))
    sol = diffrax.diffeqsolve(
        term,
        solver,
        ts[0],
        ts[-1],
        dt0,
        y0,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
        throw=False,
    )

    def diagnostics(ys, valid):
        Js = jnp.vectorize(ode.schur_complement, signature="(4)->()")(ys)
        return StepDiagnostics(
            newton_iterations=jnp.zeros(ts.shape, jnp.int32),
            residual=jnp.full(ts.shape, jnp.nan),
            schur=jnp.where(valid, Js, jnp.nan),
            local_index=jnp.where(valid, local_index(Js, ode.tau), 0),
            condition=jnp.full(ts.shape, jnp.nan),
        )

    stats = {"accepted_steps": sol.stats["num_accepted_steps"], "rejected_steps": sol.stats["num_rejected_steps"]}
    return solution_from_diffrax(sol, y0, ts, stats=stats, diagnostics=diagnostics)
