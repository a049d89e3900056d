"""Observers: what a run records of each step, inside the compiled loop.

Every integrator (:meth:`peeljax.integrators.base.AbstractIntegrator.observe`: the uniform
mesh, the error-controlled α-method, a diffrax solver) can hand every step attempt to an
:class:`Observer` as an :class:`AcceptedStep`: the step's ends (t, y) in the integrator's carried
coordinates and its interpolant (:mod:`peeljax.integrators.dense`: the α-method's cubic
Hermite one, a diffrax solver's own), which the observer can evaluate anywhere inside it. Output is an observer
(:class:`StepPoints`, :class:`DenseOutput`, :class:`EveryNthPoint`); so are a sweep's per-lane
statistics (:mod:`peeljax.sweeps.engine`). Nothing is stored per step unless an
observer stores it, so a sweep lane's memory does not grow with its number of steps.

A step that ends at a fold of φ where v jumps (``fold="jump"``) ends at the state just before
the jump (``y1``: the left limit); the state just after it, at the same time, is ``y_after``
(the right limit, where the next step starts). The run's own output keeps both, as
DifferentialEquations.jl's callbacks save both sides of an event: :class:`StepPoints` and
:class:`DenseOutput` given ``jump_rows`` write the pair as two rows with equal times, the
second marked in ``after_jump``.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..solution import PAIR_AT, PAIR_INDEX, PAIR_ITERATIONS, PAIR_SCHUR, PAIR_T, PAIR_Y, JumpSides, jump_row_sources


__all__ = ["AcceptedStep", "DenseOutput", "EveryNthPoint", "Observer", "Observers", "StepPoints", "observer_keeps_jumps"]


class AcceptedStep(eqx.Module):
    """What an observer sees after each step attempt (carried coordinates).

    ``advance`` is False for a rejected attempt (or the step onto an impasse point): the
    observer must then leave its record unchanged. ``jumped`` is True where the step ended
    at a fold and v jumped there: ``y1`` is then the state just before the jump and
    ``y_after`` the state just after it, both at ``t1``. ``iterations`` is the attempt's Newton
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
    # Where the step ended at a fold and v jumped there: the state just after the jump at t1
    # (carried coordinates) and its J_t. None from an integrator without jumps.
    jumped: Array | None = None
    y_after: Array | None = None
    J_after: Array | None = None

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

    def buffers(self, record) -> tuple:
        """The record's arrays the loop may keep as buffers (equinox's ``while_loop``): each
        location written once with a predicate (``eqxi.buffer_at_set``), never read in the loop,
        so that reverse mode neither copies them at its checkpoints nor carries their cotangents
        through every step. None by default."""
        return ()


class _Output(eqx.Module):
    """Output rows: times, states (carried coordinates), J_t, Newton iterations, validity and
    ``after_jump`` (True on the row holding the state just after a jump; the row before it
    holds the state just before, at the same time); read through the properties ``t``, ``y``,
    ``J``, ``iterations``, ``valid``, ``after_jump``.

    A dense output's rows after the written ones hold the output times not reached (after a
    stop: states NaN); with jump rows, see :class:`_GridWithJumps`.
    """

    row_t: Array
    row_y: Array
    row_J: Array
    row_iterations: Array
    row_valid: Array
    row_after_jump: Array
    next: Array  # step points: rows written; dense output: the first output time not yet reached
    keeps_jumps: bool = eqx.field(static=True, default=False)  # rows after jumps are kept

    def as_rows(self) -> "_Output":
        """The rows (this record itself)."""
        return self

    t = property(lambda self: self.row_t)
    y = property(lambda self: self.row_y)
    J = property(lambda self: self.row_J)
    iterations = property(lambda self: self.row_iterations)
    valid = property(lambda self: self.row_valid)
    after_jump = property(lambda self: self.row_after_jump)


def observer_keeps_jumps(record) -> bool:
    """Whether an output record keeps the state after each jump in a row of its own."""
    return bool(getattr(record, "keeps_jumps", False))


def _rows(rows: int, t0, y0, J0, ok, next, keeps_jumps: bool = False) -> _Output:
    """``rows`` rows of NaN with the start in row 0."""
    return _Output(
        row_t=jnp.full(rows, jnp.nan).at[0].set(t0),
        row_y=jnp.full((rows, y0.shape[0]), jnp.nan).at[0].set(y0),
        row_J=jnp.full(rows, jnp.nan).at[0].set(J0),
        row_iterations=jnp.zeros(rows, jnp.int32),
        row_valid=jnp.zeros(rows, bool).at[0].set(ok),
        row_after_jump=jnp.zeros(rows, bool),
        next=jnp.asarray(next, jnp.int32),
        keeps_jumps=keeps_jumps,
    )


def _put(out: _Output, row, write, step: AcceptedStep, valid, next) -> _Output:
    """``out`` with the step's end written into ``row`` where ``write``."""

    def put(array, value):
        return array.at[row].set(jnp.where(write, value, array[row]))

    return eqx.tree_at(
        lambda o: (o.row_t, o.row_y, o.row_J, o.row_iterations, o.row_valid, o.next),
        out,
        (put(out.row_t, step.t1), put(out.row_y, step.y1), put(out.row_J, step.J1),
         put(out.row_iterations, step.iterations), put(out.row_valid, valid), next),
    )  # fmt: skip


def _put_pair(out: _Output, row, write, jumped, step: AcceptedStep, next) -> _Output:
    """``out`` with the step's end in ``row`` where ``write`` and the state just after its jump
    in ``row + 1`` where ``jumped`` (marked ``after_jump``; the two rows have the step's end
    time). One two-row update per array: a second update of the same array in one step of
    the loop made XLA copy the array every step (measured 13x slower)."""

    def put(array, first, second):
        old = jax.lax.dynamic_slice_in_dim(array, row, 2)
        block = jnp.stack([jnp.where(write, first, old[0]), jnp.where(jumped, second, old[1])])
        return jax.lax.dynamic_update_slice_in_dim(array, block.astype(array.dtype), row, 0)

    return eqx.tree_at(
        lambda o: (o.row_t, o.row_y, o.row_J, o.row_iterations, o.row_valid, o.row_after_jump, o.next),
        out,
        (put(out.row_t, step.t1, step.t1), put(out.row_y, step.y1, step.y_after), put(out.row_J, step.J1, step.J_after),
         put(out.row_iterations, step.iterations, 0), put(out.row_valid, True, True),
         put(out.row_after_jump, False, True), next),
    )  # fmt: skip


def _saves_jumps(observer, step: AcceptedStep) -> bool:
    """Whether the observer keeps the state after a jump and the step can report one."""
    return observer.jump_rows > 0 and step.jumped is not None


class StepPoints(Observer):
    """The accepted step points, in ``rows`` = max_steps + 1 rows padded with NaN, plus
    ``jump_rows`` rows for the states just after the jumps (a step that ends at a jump writes
    two rows with its end time: the state before the jump, then the one after, marked
    ``after_jump``) and one spare row (NaN)."""

    rows: int = eqx.field(static=True)
    jump_rows: int = eqx.field(static=True, default=0)

    def init(self, t0, y0, J0, ok):
        spare = 1 if self.jump_rows else 0  # the pair's second row always fits
        return _rows(self.rows + self.jump_rows + spare, t0, y0, J0, ok, next=1, keeps_jumps=self.jump_rows > 0)

    def update(self, out, step, kind):
        last = self.rows + self.jump_rows - 1
        row = jnp.minimum(out.next, last)
        if not _saves_jumps(self, step):
            return _put(out, row, step.advance, step, True, out.next + step.advance)
        jumped = step.advance & step.jumped
        return _put_pair(out, row, step.advance, jumped, step, out.next + step.advance + jumped)


class _GridWithJumps(eqx.Module):
    """Dense output's record with jump rows: the output times' rows and the jumps' pairs kept apart
    in the loop, merged in time order when read (:meth:`as_rows`; the properties of :class:`_Output`).

    Apart, each array takes one update per step. In one set of rows, the output times' inner
    loop and the jump's pair both wrote the same arrays every step, and XLA copied them every
    step: with room for 10⁴ jumps, P1 with Tsit5 took 6.6 ms, now 1.9 (0.8 without jump rows;
    ``benchmarks/results/jump_rows_cost.md``). The pairs are two arrays of
    :class:`~peeljax.solution.JumpSides` rows (floats, counts), buffers of the loop written once per jump.
    """

    grid: _Output  # the output times' rows (no jump rows: row k is output time k)
    pairs: Array  # (m, 2, k): JumpSides.rows
    pair_counts: Array  # (m, 2, 3): JumpSides.counts
    written: Array  # pair rows written
    keeps_jumps: bool = eqx.field(static=True, default=True)

    def as_rows(self) -> _Output:
        """The rows in time order (:func:`peeljax.solution.jump_row_sources`): ``len(ts) + 2·m``,
        those after the rows in use repeating the last of them (``after_jump`` False)."""
        grid = self.grid
        n = grid.row_t.shape[0]
        ts, ys, valid, after, diagnostics, pair_at = JumpSides(self.pairs, self.pair_counts, self.written).unpacked(jnp, n)
        source, padding = jump_row_sources(n, pair_at, self.written)
        pairs = {"row_t": ts, "row_y": ys, "row_J": diagnostics.schur, "row_iterations": diagnostics.newton_iterations,
                 "row_valid": valid, "row_after_jump": after}  # fmt: skip
        rows = {f: jnp.concatenate([getattr(grid, f), q])[source] for f, q in pairs.items()}
        rows["row_after_jump"] = rows["row_after_jump"] & ~padding
        return _Output(**rows, next=grid.next, keeps_jumps=True)

    t = property(lambda self: self.as_rows().t)
    y = property(lambda self: self.as_rows().y)
    J = property(lambda self: self.as_rows().J)
    iterations = property(lambda self: self.as_rows().iterations)
    valid = property(lambda self: self.as_rows().valid)
    after_jump = property(lambda self: self.as_rows().after_jump)


class DenseOutput(Observer):
    """Each accepted step's interpolant at the given times ``ts``.

    ``jump_rows`` = m > 0: room for m jumps, each kept as two rows at its time inserted among
    the output times in time order (the state just before the jump, then the one just after,
    marked ``after_jump``): ``len(ts) + 2·m`` rows, those not used repeating the last (see
    :class:`_Output`). An output time equal to a jump's time holds the state before it (the
    row before the pair). Beyond m jumps the output times are still all written, the jumps no
    more.
    """

    ts: Array
    jump_rows: int = eqx.field(static=True, default=0)
    # (carried state, J_t) -> (output state, local index): a jump's rows are written finished, so
    # that nothing is computed after the loop on the 2·m rows kept for jumps (None: as carried)
    row_values: Callable | None = eqx.field(static=True, default=None)

    def init(self, t0, y0, J0, ok):
        at_start = self.ts <= t0
        grid = _Output(
            row_t=self.ts,
            row_y=jnp.where(at_start[:, None], y0, jnp.nan),
            row_J=jnp.full(self.ts.shape, jnp.nan),
            row_iterations=jnp.zeros(self.ts.shape, jnp.int32),
            row_valid=at_start & ok,
            row_after_jump=jnp.zeros(self.ts.shape, bool),
            next=jnp.sum(at_start).astype(jnp.int32),
        )
        if self.jump_rows == 0:
            return grid
        m = self.jump_rows
        width = PAIR_Y + jax.eval_shape(self._values, y0, J0)[0].shape[0]
        counts = jnp.zeros((m, 2, 3), jnp.int32)
        return _GridWithJumps(grid, jnp.full((m, 2, width), jnp.nan), counts, jnp.asarray(0, jnp.int32))

    def update(self, out, step, kind):
        if self.jump_rows == 0:
            return self._fill(out, step, kind)
        grid = self._fill(out.grid, step, kind)
        if step.jumped is None:
            return eqx.tree_at(lambda o: o.grid, out, grid)
        # The jump at t1, after the output times up to t1: the state before it (the step's end)
        # and after it, in slot p of the pairs for the p-th jump while room is left. Each slot
        # is written once where ``pair`` (the loop's buffers, :meth:`Observer.buffers`): reverse
        # mode then carries no cotangent of the 2·m rows through every step.
        count = out.written // 2
        pair = step.advance & step.jumped & (count < self.jump_rows)
        slot = jnp.minimum(count, self.jump_rows - 1)

        def row(y, J, iterations):
            y, index = self._values(y, J)
            floats = {PAIR_T: step.t1, PAIR_SCHUR: J}
            counts = {PAIR_AT: grid.next, PAIR_ITERATIONS: iterations, PAIR_INDEX: index}
            return (
                jnp.concatenate([jnp.stack([floats[c] for c in range(PAIR_Y)]).astype(float), y]),
                jnp.stack([counts[c] for c in range(3)]).astype(jnp.int32),
            )

        (before, before_counts), (after, after_counts) = row(step.y1, step.J1, step.iterations), row(step.y_after, step.J_after, 0)
        pairs = eqxi.buffer_at_set(out.pairs, slot, jnp.stack([before, after]), pred=pair)
        counts = eqxi.buffer_at_set(out.pair_counts, slot, jnp.stack([before_counts, after_counts]), pred=pair)
        return _GridWithJumps(grid, pairs, counts, out.written + 2 * pair)

    def buffers(self, record) -> tuple:
        """The pairs' arrays: slot p written once, by the p-th jump. (Decided on static fields
        only: equinox calls this on a tree whose None leaves are replaced.)"""
        return (record.pairs, record.pair_counts) if self.jump_rows else ()

    def _values(self, y, J):
        return (y, jnp.zeros((), jnp.int32)) if self.row_values is None else self.row_values(y, J)

    def _fill(self, out: _Output, step, kind) -> _Output:
        """The output times in (t0, t1], one at a time (a step covers few of them)."""
        n_out = self.ts.shape[0]

        def more(d):
            k = d[0]
            return step.advance & (k < n_out) & (self.ts[jnp.minimum(k, n_out - 1)] <= step.t1)

        def fill(d):
            k, y, iterations, valid = d
            y_k = step.evaluate(self.ts[k][None])[0]
            return k + 1, y.at[k].set(y_k), iterations.at[k].set(step.iterations), valid.at[k].set(True)

        k, y, iterations, valid = eqxi.while_loop(
            more,
            fill,
            (out.next, out.row_y, out.row_iterations, out.row_valid),
            max_steps=n_out,
            kind=kind,
            checkpoints=n_out if kind == "checkpointed" else None,
        )
        return eqx.tree_at(lambda o: (o.row_y, o.row_iterations, o.row_valid, o.next), out, (y, iterations, valid, k))


class Observers(Observer):
    """Several observers at once; the record is the tuple of theirs."""

    observers: tuple

    def init(self, t0, y0, J0, ok):
        return tuple(o.init(t0, y0, J0, ok) for o in self.observers)

    def update(self, records, step, kind):
        return tuple(o.update(r, step, kind) for o, r in zip(self.observers, records))

    def buffers(self, records) -> tuple:
        return tuple(b for o, r in zip(self.observers, records) for b in o.buffers(r))


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
