"""The reference integrator: diffrax on the same homogenized ODE ψ (eq. ``hv``).

Adaptive (PID) step control, Kvaerno5 by default, output on a grid, and failures reported like
the α-method's: near an impasse point the step size collapses, which the ``dtmin`` bound turns
into a ``STALLED`` stop instead of zero-length steps until ``max_steps``.
"""

from __future__ import annotations

import diffrax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..homogenized import HomogenizedODE
from ..solution import Solution, StepDiagnostics, StopReason, mask_after_stop
from ..structure import local_index

__all__ = ["integrate_reference"]


def _stop_reason(result) -> Array:
    R = diffrax.RESULTS
    code = jnp.where(result == R.successful, StopReason.COMPLETED, StopReason.SOLVER_FAILED)
    code = jnp.where(result == R.max_steps_reached, StopReason.MAX_STEPS, code)
    code = jnp.where(result == R.dt_min_reached, StopReason.STALLED, code)
    return code.astype(jnp.int32)


def integrate_reference(
    ode: HomogenizedODE,
    y0: Float[Array, "4"],
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
        jnp.asarray(y0, float),
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
        throw=False,
    )
    status = _stop_reason(sol.result)
    ys = sol.ys
    finite = jnp.all(jnp.isfinite(ys), axis=1)
    # diffrax fills the points after a failure with inf; the last finite point is where it stopped.
    valid = jnp.cumprod(finite).astype(bool)
    n_valid = jnp.sum(valid)
    t_stop = ts[jnp.maximum(n_valid - 1, 0)]
    ys_safe = jnp.where(valid[:, None], ys, y0)
    Js = jnp.vectorize(ode.schur_complement, signature="(4)->()")(ys_safe)
    diagnostics = StepDiagnostics(
        newton_iterations=jnp.zeros(ts.shape, jnp.int32),
        residual=jnp.full(ts.shape, jnp.nan),
        schur=jnp.where(valid, Js, jnp.nan),
        local_index=jnp.where(valid, local_index(Js, ode.tau), 0),
        condition=jnp.full(ts.shape, jnp.nan),
    )
    stats = {
        "steps": sol.stats["num_steps"],
        "accepted_steps": sol.stats["num_accepted_steps"],
        "rejected_steps": sol.stats["num_rejected_steps"],
    }
    return Solution(
        ts=ts,
        ys=mask_after_stop(ys_safe, valid),
        valid=valid,
        status=status,
        t_stop=t_stop,
        stats=stats,
        diagnostics=diagnostics,
        method="diffrax",
    )
