"""The reference integrator: diffrax on the same homogenized ODE ψ (eq. ``hv``).

Adaptive (PID) step control, Kvaerno5 by default, output on a grid, and failures reported like
the α-method's: near an impasse point the step size collapses, which the ``dtmin`` bound turns
into a ``STALLED`` stop instead of zero-length steps until ``max_steps``.

:func:`solution_from_diffrax` turns a ``diffrax.diffeqsolve`` result into a :class:`Solution`;
the direct and inertial alternatives (:mod:`peeljax.alternatives`) use it too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._arrays import float_array, optional_float_array
from .._validation import check_adjoint, check_max_steps
from ..homogenized import HomogenizedODE
from ..solution import Solution, StepDiagnostics, StopReason, mask_after_stop
from ..structure import local_index
from .base import AbstractIntegrator, ObservedRun
from .dense import HermiteInterpolant
from .observers import AcceptedStep

__all__ = ["DiffraxIntegrator", "integrate_reference", "solution_from_diffrax"]


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


class DiffraxIntegrator(AbstractIntegrator):
    """Any diffrax solver, with diffrax's PID step control, as an integrator.

    :meth:`integrate` saves at ``ts`` (``SaveAt(ts=ts)``) or, with ``ts=None``, at the
    accepted steps (``SaveAt(t0=True, steps=True)``: ``max_steps + 1`` rows, NaN-padded);
    :meth:`observe` replays the accepted steps to an observer with the cubic Hermite
    interpolant through their ends (diffrax's own dense output for Kvaerno and other solvers
    with ``ThirdOrderHermitePolynomialInterpolation``). A collapsing step (below ``dtmin``)
    stops the run with ``STALLED``: diffrax has no impasse test of its own.

    Attributes:
        solver: a ``diffrax.AbstractSolver`` (default ``Kvaerno5()``).
        rtol, atol: the ``PIDController``'s tolerances (traced).
        dtmin: smallest step (None: 1e-12 of the span, at most 3e-12).
        dt0: first step (None: 1e-6 of the span).
        max_steps: diffrax's step budget (static).
        adjoint: ``"reverse"`` or ``"checkpointed"`` (``RecursiveCheckpointAdjoint``, for
            ``jax.grad``; ``simulate`` takes tangents for a few perturbed numbers) or
            ``"forward"`` (``ForwardMode``, for ``jax.jvp``).
    """

    dense_output: ClassVar[bool] = True
    solver: diffrax.AbstractSolver = diffrax.Kvaerno5()
    rtol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-8)
    atol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-10)
    dtmin: Float[Array, ""] | None = eqx.field(converter=optional_float_array, default=None)
    dt0: Float[Array, ""] | None = eqx.field(converter=optional_float_array, default=None)
    max_steps: int = eqx.field(static=True, default=100_000)
    adjoint: str = eqx.field(static=True, default="reverse")

    def __check_init__(self):
        if not isinstance(self.solver, diffrax.AbstractSolver):
            raise TypeError(f"solver must be a diffrax.AbstractSolver, got {type(self.solver).__name__}")
        check_adjoint(self.adjoint)
        check_max_steps(self.max_steps)

    @property
    def carried_log(self) -> tuple[int, ...]:
        return ()

    def _solve(self, ode, y0, t0, t_final, saveat):
        t0 = jnp.asarray(t0, float)
        t_final = jnp.asarray(t_final, float)
        span = t_final - t0
        dt0 = 1e-6 * span if self.dt0 is None else self.dt0
        dtmin = jnp.minimum(1e-12 * span, 3e-12) if self.dtmin is None else self.dtmin
        controller = diffrax.PIDController(rtol=self.rtol, atol=self.atol, dtmin=dtmin, force_dtmin=False)
        adjoint = diffrax.ForwardMode() if self.adjoint == "forward" else diffrax.RecursiveCheckpointAdjoint()
        return diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, y, args: ode.evaluate(y).psi), self.solver, t0, t_final, dt0, jnp.asarray(y0, float),
            saveat=saveat, stepsize_controller=controller, max_steps=self.max_steps, adjoint=adjoint, throw=False,
        )  # fmt: skip

    def integrate(self, ode, y0, t0, t_final, ts=None) -> Solution:
        y0 = jnp.asarray(y0, float)
        if ts is None:
            sol = self._solve(ode, y0, t0, t_final, diffrax.SaveAt(t0=True, steps=True))
        else:
            ts = jnp.asarray(ts, float)
            sol = self._solve(ode, y0, t0, t_final, diffrax.SaveAt(ts=ts))
        n = sol.ys.shape[0]

        def diagnostics(ys, valid):
            Js = jnp.vectorize(lambda y: ode.evaluate(y).J, signature="(n)->()")(ys)
            return StepDiagnostics(
                newton_iterations=jnp.zeros(n, jnp.int32),
                newton_correction=jnp.full(n, jnp.nan),
                schur=jnp.where(valid, Js, jnp.nan),
                local_index=jnp.where(valid, local_index(Js, ode.tau), 0),
                condition=jnp.full(n, jnp.nan),
            )

        stats = {"accepted_steps": sol.stats["num_accepted_steps"], "rejected_steps": sol.stats["num_rejected_steps"]}
        return solution_from_diffrax(sol, y0, ts, stats=stats, diagnostics=diagnostics, method=self.method_name)

    def observe(self, ode, y0, t0, t_final, observer) -> ObservedRun:
        y0 = jnp.asarray(y0, float)
        sol = self._solve(ode, y0, t0, t_final, diffrax.SaveAt(t0=True, steps=True))
        # Rows after the last accepted step are inf; so are all after a failure.
        n_points = jnp.sum(jnp.cumprod(jnp.isfinite(sol.ts) & jnp.all(jnp.isfinite(sol.ys), axis=1)))
        start = ode.evaluate(y0)
        start_ok = jnp.all(jnp.isfinite(start.psi)) & jnp.isfinite(start.J)

        def step(k, carry):
            record, psi0 = carry
            y1 = sol.ys[k + 1]
            end = ode.evaluate(y1)
            h = sol.ts[k + 1] - sol.ts[k]
            accepted = AcceptedStep(
                t0=sol.ts[k], t1=sol.ts[k + 1], h=h, y0=sol.ys[k], y1=y1, J1=end.J, iterations=jnp.asarray(0, jnp.int32),
                advance=jnp.asarray(True), interpolant=HermiteInterpolant(sol.ts[k], h, sol.ys[k], psi0, y1, end.psi),
            )  # fmt: skip
            return observer.update(record, accepted, "lax"), end.psi

        record0 = observer.init(jnp.asarray(t0, float), y0, start.J, start_ok)
        record, _ = jax.lax.fori_loop(0, jnp.maximum(n_points - 1, 0), step, (record0, start.psi))
        last = jnp.maximum(n_points - 1, 0)
        return ObservedRun(
            record=record,
            status=_stop_reason(sol.result),
            t_stop=jnp.where(n_points > 0, sol.ts[last], jnp.asarray(t0, float)),
            y_final=jnp.where(n_points > 0, sol.ys[last], jnp.nan),
            accepted_steps=sol.stats["num_accepted_steps"],
            rejected_steps=sol.stats["num_rejected_steps"],
            newton_iterations=jnp.asarray(0, jnp.int32),
            subdivided_steps=jnp.asarray(0, jnp.int32),
            max_subdivision_level=jnp.asarray(0, jnp.int32),
        )

    @property
    def method_name(self) -> str:
        return f"diffrax-{type(self.solver).__name__}"

    def settings(self) -> dict:
        return {
            "method": self.method_name,
            "rtol": float(self.rtol),
            "atol": float(self.atol),
            "dtmin": None if self.dtmin is None else float(self.dtmin),
            "max_steps": self.max_steps,
            "solver": {"name": type(self.solver).__name__},
        }


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
    """Solve y' = ψ(y) with diffrax, saving at ``ts`` (``ts[0]`` is the start): the
    :class:`DiffraxIntegrator` from ``ts[0]`` to ``ts[-1]``, with ``Solution.method = "diffrax"``.

    Args:
        solver: any diffrax solver (default ``Kvaerno5()``).
        rtol, atol: PID controller tolerances.
        dt0: first step (default 1e-6 of the span).
        dtmin: smallest step before the run is declared stalled (default 1e-12 of the span, at most 3e-12).
        max_steps: step budget (static).
    """
    integrator = DiffraxIntegrator(
        diffrax.Kvaerno5() if solver is None else solver, rtol, atol, dtmin, dt0, max_steps
    )
    ts = jnp.asarray(ts, float)
    return dataclasses.replace(integrator.integrate(ode, y0, ts[0], ts[-1], ts), method="diffrax")
