"""Observers: what a run records of each step, inside the compiled loop.

Every integrator (:meth:`peeljax.integrators.base.AbstractIntegrator.observe`: the uniform
mesh, the error-controlled α-method, a diffrax solver) can hand every step attempt to an
:class:`Observer` as an :class:`AcceptedStep`: the step's ends (t, y) in the integrator's carried
coordinates and its interpolant (:mod:`peeljax.integrators.dense`: the α-method's cubic
Hermite one, a diffrax solver's own), which the observer can evaluate anywhere inside it. Output is an observer
(:class:`StepPoints`, :class:`DenseOutput`, :class:`EveryNthPoint`); so are a sweep's per-lane
statistics (:mod:`peeljax.sweeps.engine`). Nothing is stored per step unless an
observer stores it, so a sweep lane's memory does not grow with its number of steps.
"""

from __future__ import annotations

import equinox as eqx
import equinox.internal as eqxi
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


__all__ = ["AcceptedStep", "DenseOutput", "EveryNthPoint", "Observer", "Observers", "StepPoints"]


class AcceptedStep(eqx.Module):
    """What an observer sees after each step attempt (carried coordinates).

    ``advance`` is False for a rejected attempt (or the step onto an impasse point): the
    observer must then leave its record unchanged. ``iterations`` is the attempt's Newton
    iterations (0 where the integrator does not report them). ``interpolant.evaluate(ts)``
    gives the states at times ts in [t0, t1] (a step cut at a fold ends at t1 < t0 + h, its
    interpolant being the whole attempt's).
    """

    t0: Array
    t1: Array
    h: Array
    y0: Array
    y1: Array
    J1: Array
    iterations: Array
    advance: Array
    interpolant: object

    def evaluate(self, ts: Float[Array, " m"]) -> Float[Array, "m n"]:
        """The step's dense output at times ``ts`` (carried coordinates)."""
        return self.interpolant.evaluate(ts)


class Observer(eqx.Module):
    """Records something of each accepted step inside the compiled loop (an abstract base).

    ``init`` gives the record at the start (t0, state y0 in carried coordinates, its J_t, and
    whether the start is usable), ``update`` the record after one attempt (masked by
    ``step.advance``); ``kind`` is the loop's (``"lax"`` or ``"checkpointed"``) for any loop
    of the observer's own.
    """

    def init(self, t0: Float[Array, ""], y0: Float[Array, " n"], J0: Float[Array, ""], ok: Bool[Array, ""]):
        raise NotImplementedError

    def update(self, record, step: AcceptedStep, kind: str):
        raise NotImplementedError


class _Output(eqx.Module):
    t: Array
    y: Array
    J: Array
    iterations: Array
    valid: Array
    next: Array  # step points: rows written; dense output: the first output time not yet reached


def _rows(rows: int, t0, y0, J0, ok, next) -> _Output:
    """``rows`` rows of NaN with the start in row 0."""
    return _Output(
        t=jnp.full(rows, jnp.nan).at[0].set(t0),
        y=jnp.full((rows, y0.shape[0]), jnp.nan).at[0].set(y0),
        J=jnp.full(rows, jnp.nan).at[0].set(J0),
        iterations=jnp.zeros(rows, jnp.int32),
        valid=jnp.zeros(rows, bool).at[0].set(ok),
        next=jnp.asarray(next, jnp.int32),
    )


def _put(out: _Output, row, write, step: AcceptedStep, valid, next) -> _Output:
    """``out`` with the step's end written into ``row`` where ``write``."""

    def put(array, value):
        return array.at[row].set(jnp.where(write, value, array[row]))

    return _Output(
        t=put(out.t, step.t1),
        y=put(out.y, step.y1),
        J=put(out.J, step.J1),
        iterations=put(out.iterations, step.iterations),
        valid=put(out.valid, valid),
        next=next,
    )


class StepPoints(Observer):
    """The accepted step points, in ``rows`` = max_steps + 1 rows padded with NaN."""

    rows: int = eqx.field(static=True)

    def init(self, t0, y0, J0, ok):
        return _rows(self.rows, t0, y0, J0, ok, next=1)

    def update(self, out, step, kind):
        row = jnp.minimum(out.next, self.rows - 1)
        return _put(out, row, step.advance, step, True, out.next + step.advance)


class DenseOutput(Observer):
    """Each accepted step's interpolant at the given times ``ts``."""

    ts: Array

    def init(self, t0, y0, J0, ok):
        at_start = self.ts <= t0
        return _Output(
            t=self.ts,
            y=jnp.where(at_start[:, None], y0, jnp.nan),
            J=jnp.full(self.ts.shape, jnp.nan),
            iterations=jnp.zeros(self.ts.shape, jnp.int32),
            valid=at_start & ok,
            next=jnp.sum(at_start).astype(jnp.int32),
        )

    def update(self, out, step, kind):
        n_out = self.ts.shape[0]
        t1 = step.t1

        # The output times in (t0, t1], one at a time (a step covers few of them).
        def more(d):
            k = d[0]
            return step.advance & (k < n_out) & (self.ts[jnp.minimum(k, n_out - 1)] <= t1)

        def fill(d):
            k, y, iterations, valid = d
            y_k = step.evaluate(self.ts[k][None])[0]
            return k + 1, y.at[k].set(y_k), iterations.at[k].set(step.iterations), valid.at[k].set(True)

        k, y, iterations, valid = eqxi.while_loop(
            more,
            fill,
            (out.next, out.y, out.iterations, out.valid),
            max_steps=n_out,
            kind=kind,
            checkpoints=n_out if kind == "checkpointed" else None,
        )
        return _Output(t=out.t, y=y, J=out.J, iterations=iterations, valid=valid, next=k)


class Observers(Observer):
    """Several observers at once; the record is the tuple of theirs."""

    observers: tuple

    def init(self, t0, y0, J0, ok):
        return tuple(o.init(t0, y0, J0, ok) for o in self.observers)

    def update(self, records, step, kind):
        return tuple(o.update(r, step, kind) for o, r in zip(self.observers, records))


class EveryNthPoint(Observer):
    """The state after every ``every``-th step attempt, and at t0: on a uniform mesh, every
    ``every``-th mesh point, in ``rows`` = n_steps // every + 1 rows (NaN once the run has stopped)."""

    every: int = eqx.field(static=True)
    rows: int = eqx.field(static=True)

    def init(self, t0, y0, J0, ok):
        return _rows(self.rows, t0, y0, J0, ok, next=0)  # next: the attempts seen

    def update(self, out, step, kind):
        attempts = out.next + 1
        row = jnp.minimum(attempts // self.every, self.rows - 1)
        return _put(out, row, attempts % self.every == 0, step, step.advance, attempts)
