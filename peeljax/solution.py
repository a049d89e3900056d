"""The result of a run: times, states, why and where it stopped, statistics, diagnostics."""

from __future__ import annotations

import dataclasses
import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

__all__ = ["JumpRecord", "Solution", "StepDiagnostics", "StopReason"]


class StopReason(enum.IntEnum):
    """Why a run ended. ``COMPLETED`` is the only success."""

    COMPLETED = 0
    NEWTON_FAILED = 1
    IMPASSE = 2
    NONFINITE = 3
    STALLED = 4
    MAX_STEPS = 5
    SOLVER_FAILED = 6
    MAX_JUMPS = 7
    FOLD = 8

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    StopReason.COMPLETED: "completed",
    StopReason.NEWTON_FAILED: (
        "Newton's method did not converge within its iteration cap, even on the smallest "
        "subdivided step (near J_t = 0 the iteration matrix is near-singular: see diagnostics.schur)"
    ),
    StopReason.IMPASSE: (
        "impasse point: J_t changed sign within a step while F~·f did not, so dv/dt blows up "
        "and the homogenized solution ends there"
    ),
    StopReason.NONFINITE: "a state or dψ/dt became non-finite",
    StopReason.STALLED: (
        "the step size collapsed below dtmin: the step the run needs here is smaller than dtmin allows, "
        "either because the solution cannot be continued (typically an impasse point, where J_t -> 0 and "
        "dv/dt blows up) or because dtmin itself is too large (a start from rest and the restart after a "
        "jump take steps of ~1e-12 to 1e-11 s: give a smaller dtmin)"
    ),
    StopReason.MAX_STEPS: "max_steps step attempts were used up before t_final",
    StopReason.SOLVER_FAILED: "the reference solver failed (diffrax reported an error)",
    StopReason.MAX_JUMPS: "max_jumps jumps were recorded before t_final (raise max_jumps to go on)",
    StopReason.FOLD: (
        "a fold of phi was reached (fold='stop'): here the tape slips or re-sticks, v jumps to the other "
        "stable branch of G(x) = phi(v, V); fold='jump' carries the run through it"
    ),
}


class StepDiagnostics(eqx.Module):
    """Per-time-point diagnostics, one entry per output time (entry 0 is the initial state).

    Attributes:
        newton_iterations: Newton iterations of the step that ended at this time (summed over
            substeps when the step was subdivided; 0 at t = 0 and after a stop).
        newton_correction: max-norm of the last Newton correction of the step, scaled by
            ``atol + rtol·|y|`` (relative for v); ≤ 1 ⇔ converged to tolerance (the maximum
            over substeps when the step was subdivided).
        schur: J_t(τ) at the state (Lemma 1).
        local_index: ⌈log_τ|J_t|⌉ + 1 (Lemma 2, see :func:`peeljax.local_index`).
        condition: 2-norm condition number of the Newton iteration matrix (NaN when not requested).
    """

    newton_iterations: Int[Array, " n"]
    newton_correction: Float[Array, " n"]
    schur: Float[Array, " n"]
    local_index: Int[Array, " n"]
    condition: Float[Array, " n"]


class JumpRecord(eqx.Module):
    """Every jump of v at a fold of φ in a run, in ``max_jumps`` slots padded with NaN.

    At a fold, x = (α, ω, u) is unchanged (so are F and G = (1 + l·sinα/L)·F) and v jumps to
    the other stable root of G(x) = φ(v, V): stick → slip at φ's maximum (``up`` True),
    slip → stick at its minimum (``up`` False). Under ``vmap`` every field gains a leading
    batch axis.

    Two layouts (``ring``, static):

    * a plain record (default): slot k < ``count`` holds the k-th jump; once the slots are
      full nothing more is written (the loop stops the run at the next fold, ``MAX_JUMPS``);
    * a ring buffer: the k-th jump goes to slot k mod ``max_jumps`` and ``count`` goes on, so
      the slots hold the last :attr:`kept` = min(count, max_jumps) jumps and a run never stops
      for a full record. :meth:`latest` gives them in time order, :meth:`slot_valid` says which
      slots hold one.

    Attributes:
        t: jump times [s].
        up: True for stick → slip (v jumps up), False for slip → stick.
        v_before, v_after: v just before and just after the jump [m/s] (v_after = 0: the
            tape lands fully stuck, G below φ(0⁺, V)).
        G: the shear force G = (1 + l·sinα/L)·F at the jump [N] (continuous across it).
        count: the number of jumps recorded (a ring buffer: every jump of the run so far).
        F: the tape tension F = (k/l)·u at the jump [N] (what a load cell measures; F is
            continuous across the jump, maximal at stick → slip and minimal at slip → stick).
            None in a record built by hand without it.
        ring: the ring-buffer layout (static; see above).
        statistics: running statistics updated at every recorded jump
            (:class:`~peeljax.integrators.cycle_accumulator.CycleAccumulator`: the cycle
            statistics of a window, however many jumps it holds); None: none kept.

    Every float field carries derivatives: a jump's time by the implicit function theorem on
    its fold event, its forces and v through the state there (:mod:`peeljax.integrators.events`).
    """

    t: Float[Array, " m"]
    up: Bool[Array, " m"]
    v_before: Float[Array, " m"]
    v_after: Float[Array, " m"]
    G: Float[Array, " m"]
    count: Int[Array, ""]
    F: Float[Array, " m"] | None = None
    ring: bool = eqx.field(static=True, default=False)
    statistics: eqx.Module | None = None

    @classmethod
    def empty(cls, max_jumps: int, *, ring: bool = False, statistics: eqx.Module | None = None) -> "JumpRecord":
        nan = jnp.full(max_jumps, jnp.nan)
        return cls(
            t=nan, up=jnp.zeros(max_jumps, bool), v_before=nan, v_after=nan, G=nan, count=jnp.asarray(0, jnp.int32), F=nan,
            ring=ring, statistics=statistics,
        )  # fmt: skip

    @property
    def max_jumps(self) -> int:
        return self.t.shape[-1]

    @property
    def kept(self) -> Int[Array, "..."]:
        """How many slots hold a jump: min(count, max_jumps)."""
        return jnp.minimum(self.count, self.max_jumps)

    @property
    def full(self) -> Bool[Array, "..."]:
        """True when a plain record has no free slot (a ring buffer is never full)."""
        if self.ring:
            return jnp.zeros(jnp.shape(self.count), bool)
        return self.count >= self.max_jumps

    def slot_valid(self) -> Bool[Array, "... m"]:
        """Which slots hold a jump (a ring buffer's slots fill in order, then all hold one)."""
        return jnp.arange(self.max_jumps) < jnp.asarray(self.kept)[..., None]

    def latest(self) -> "JumpRecord":
        """The jumps the slots hold, in time order, as a plain record: slot k < its ``count``
        (= :attr:`kept`) holds the k-th of them, the oldest first; NaN after. For a ring buffer
        these are the last min(count, max_jumps) jumps of the run; a plain record is returned as
        it is. ``statistics`` is left out."""
        if not self.ring:
            return dataclasses.replace(self, statistics=None)
        m = self.max_jumps
        count = jnp.asarray(self.count)[..., None]
        # the oldest kept jump is number count − kept, in slot (count − kept) mod m
        slots = (count - jnp.minimum(count, m) + jnp.arange(m)) % max(m, 1)
        valid = self.slot_valid()

        def ordered(array, fill):
            if array is None:
                return None
            return jnp.where(valid, jnp.take_along_axis(array, slots, axis=-1), fill)

        return JumpRecord(
            t=ordered(self.t, jnp.nan), up=ordered(self.up, False), v_before=ordered(self.v_before, jnp.nan),
            v_after=ordered(self.v_after, jnp.nan), G=ordered(self.G, jnp.nan), count=self.kept,
            F=ordered(self.F, jnp.nan),
        )  # fmt: skip

    def buffers(self) -> tuple:
        """The slot arrays: written in place, as buffers of a while loop (never read in it)."""
        return (self.t, self.up, self.v_before, self.v_after, self.G, self.F)

    def record(self, do: Bool[Array, ""], t, up, v_before, v_after, G, F=jnp.nan, y=None) -> "JumpRecord":
        """This record with one more jump where ``do`` (nothing changes where not, or when a
        plain record is full); ``statistics`` see the jump too (and ``y``, the state at the fold)."""
        if self.ring:
            slot = self.count % max(self.max_jumps, 1)
            write = jnp.asarray(do)
            counted = write
        else:
            slot = jnp.minimum(self.count, self.max_jumps - 1)
            write = do & (self.count < self.max_jumps)
            counted = write

        def put(array, value):
            if self.max_jumps == 0:
                return array
            if isinstance(array, (jax.Array, np.ndarray)):
                return array.at[slot].set(jnp.where(write, value, array[slot]))
            # A buffer of equinox's while loop (written in place, never read in the loop).
            return array.at[slot].set(value, pred=write)

        statistics = self.statistics
        if statistics is not None:
            statistics = statistics.add(write, t, up, v_before, v_after, G, y)
        return JumpRecord(
            t=put(self.t, t), up=put(self.up, up), v_before=put(self.v_before, v_before),
            v_after=put(self.v_after, v_after), G=put(self.G, G), count=self.count + counted,
            F=None if self.F is None else put(self.F, F), ring=self.ring, statistics=statistics,
        )  # fmt: skip

    def as_numpy(self) -> dict[str, np.ndarray]:
        """The jumps the record holds, in time order, as host arrays keyed ``jump_t``,
        ``jump_up``, … (a plain record: its first ``count`` slots; a ring buffer: its last
        :attr:`kept` jumps, :meth:`latest`)."""
        record = self.latest() if self.ring else self
        n = int(np.asarray(record.count))
        return {
            "jump_t": np.asarray(record.t)[:n],
            "jump_up": np.asarray(record.up)[:n],
            "jump_v_before": np.asarray(record.v_before)[:n],
            "jump_v_after": np.asarray(record.v_after)[:n],
            "jump_G": np.asarray(record.G)[:n],
            **({} if record.F is None else {"jump_F": np.asarray(record.F)[:n]}),
        }


def is_traced(tree) -> bool:
    """Whether any array of ``tree`` is traced (inside ``jit``, ``vmap``, ``grad``, ``jvp``)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


def jump_row_sources(n: int, pair_at, written, xp=jnp):
    """Where the rows of a dense output with both sides of its jumps come from.

    The output times' ``n`` rows and the jumps' pair rows (pair p: the state before jump p in
    row 2p, after it in 2p + 1; ``written`` rows in use) are merged in time order: output time
    k goes to row k + 2·#(pairs written at or before it), pair row q to ``pair_at[q // 2] + q``
    (``pair_at[p]``: the output times written before jump p; the slots not used hold n).
    Returns ``(source, padding)``: for each merged row its index in the rows of the output
    times followed by the pair rows, and whether it only pads. ``xp=jnp`` (traceable): ``n +
    2·m`` rows, those after the ones in use repeating the last of them (``padding``);
    ``xp=np`` (host): the ``n + written`` rows in use.
    """
    pairs = pair_at.shape[-1]
    k = xp.arange(n)
    to_grid = k + 2 * xp.searchsorted(pair_at, k, side="right")
    q = xp.arange(2 * pairs)
    used = q < written
    to_pairs = xp.repeat(pair_at, 2) + q
    if xp is np:
        source = np.empty(n + int(written), np.int64)
        source[to_grid] = k
        source[to_pairs[used]] = n + q[used]
        return source, np.zeros(source.shape, bool)
    total = n + 2 * pairs
    source = (
        jnp.zeros(total, k.dtype)
        .at[to_grid].set(k, mode="drop")
        .at[jnp.where(used, to_pairs, total)].set(n + q, mode="drop")
    )  # fmt: skip
    end = n + written
    padding = jnp.arange(total) >= end
    return jnp.where(padding, source[jnp.maximum(end - 1, 0)], source), padding


# The columns of a jump's rows as the loop writes them, one write per array and step: the floats
# (JumpSides.rows; they carry derivatives) and the counts (JumpSides.counts; integers, none).
PAIR_T, PAIR_SCHUR, PAIR_Y = 0, 1, 2
PAIR_AT, PAIR_ITERATIONS, PAIR_INDEX = 0, 1, 2


def _replaced(module: eqx.Module, **changes) -> eqx.Module:
    """``dataclasses.replace`` of a module whose fields keep their types, without re-running its
    ``__init__`` (equinox's checks: 31 µs against 4 µs for a :class:`Solution`, 2 % of a 3 s
    run; :func:`peeljax.simulate` makes one such copy per call).

    Made by ``object.__new__``, not ``copy.copy``: equinox's ``Module.__new__`` records every
    module it makes as initialising until its ``__init__`` ends, and holds on to it; a copy never
    runs ``__init__``, so each one (and its arrays) was kept for the life of the process (2 per
    ``simulate`` call, 250 MB over 1000 calls of P1, measured)."""
    new = object.__new__(type(module))
    new.__dict__.update(module.__dict__)
    for name, value in changes.items():
        object.__setattr__(new, name, value)
    return new


class JumpSides(eqx.Module):
    """Both sides of each jump of a dense output, kept apart from the rows at the output times
    between the compiled run and the host, which merges them (:meth:`merge`).

    Merged in the compiled run, the rows kept for ``max_jumps`` jumps (2·10⁴ for 10⁴ jumps) took
    longer to merge, evaluate and copy than a 3 s run without any jump took to compute; the loop
    writes them finished (physical state, J_t, local index) into one array, and the host merges
    the rows in use only. :func:`peeljax.simulate` merges on the host; under ``jit``/``vmap``
    the rows are merged in the compiled program.

    Attributes:
        rows: ``(m, 2, 2 + 4)``: jump p's state before it in ``rows[p, 0]``, after it in
            ``rows[p, 1]``; columns: time, J_t, the state (``PAIR_T``, ``PAIR_SCHUR``,
            ``PAIR_Y``). NaN where unused.
        counts: ``(m, 2, 3)`` integers: the output times written before the jump, Newton
            iterations, local index (``PAIR_AT``, ``PAIR_ITERATIONS``, ``PAIR_INDEX``). Apart
            from the floats: ``jax.grad`` by tangents keeps k tangents of every float the run
            returns, and these have none (P4's gradient: the room for 10⁴ jumps in tangents
            took 4.4 of its 10 ms; measured).
        written: rows in use (two per jump kept).
    """

    rows: Float[Array, "m 2 k"]
    counts: Int[Array, "m 2 3"]
    written: Int[Array, ""]

    def unpacked(self, xp, grid_rows: int, rows: int | None = None) -> tuple:
        """``(ts, ys, valid, after_jump, diagnostics, pair_at)`` of the 2·m pair rows (the first
        ``rows`` of them); ``pair_at``: per jump, ``grid_rows`` where unused."""
        flat = xp.reshape(self.rows, (-1, self.rows.shape[-1]))
        counts = xp.reshape(self.counts, (-1, self.counts.shape[-1]))
        if rows is not None:
            flat, counts = flat[:rows], counts[:rows]
        q = xp.arange(flat.shape[0])
        valid = q < self.written
        pair_at = counts[::2, PAIR_AT]
        pair_at = xp.where(valid[::2], pair_at, grid_rows).astype(np.int64 if xp is np else jnp.int32)
        count = lambda column: xp.where(valid, counts[:, column], 0).astype(np.int32)  # noqa: E731
        nan = xp.full(q.shape, np.nan)
        diagnostics = StepDiagnostics(
            newton_iterations=count(PAIR_ITERATIONS), newton_correction=nan, schur=flat[:, PAIR_SCHUR],
            local_index=count(PAIR_INDEX), condition=nan,
        )  # fmt: skip
        return flat[:, PAIR_T], flat[:, PAIR_Y:], valid, valid & (q % 2 == 1), diagnostics, pair_at

    def merge(self, solution: Solution) -> Solution:
        """``solution`` (its rows: the output times) with the jumps' rows inserted in time order:
        on the host the rows in use; traced (under ``jit``, ``vmap``, ``grad``) all
        ``len(ts) + 2·max_jumps``, those after the rows in use repeating the last of them."""
        fields, written = vars(solution), vars(self)["written"]  # (a module's attribute: ~1 µs through equinox)
        n = np.shape(fields["ts"])[-1]
        # (under jax.jvp some leaves are traced, others not; a run's NumPy arrays are on the host)
        traced = not isinstance(written, np.ndarray) and is_traced((solution, self))
        if not traced and fields["after_jump"] is not None and int(written) == 0:
            return _replaced(solution, jump_sides=None)  # no jump: the rows are the output times'
        after = jnp.zeros(n, bool) if solution.after_jump is None else solution.after_jump
        grid = (solution.ts, solution.ys, solution.valid, after, solution.diagnostics)
        if traced:
            *pairs, pair_at = self.unpacked(jnp, n)
            source, padding = jump_row_sources(n, pair_at, self.written)
            merged = jax.tree_util.tree_map(lambda g, q: jnp.concatenate([g, q])[source], grid, tuple(pairs))
            merged = (*merged[:3], merged[3] & ~padding, merged[4])
        elif int(self.written) == 0:  # no jump: the rows are the output times'
            merged = grid
        else:  # on the host (indexing on the device would compile per row count)
            grid, sides = jax.device_get((grid, self))
            written = int(sides.written)
            *pairs, pair_at = sides.unpacked(np, n, written)
            source, _ = jump_row_sources(n, pair_at, written, xp=np)
            merged = jax.tree_util.tree_map(lambda g, q: np.concatenate([g, q])[source], grid, tuple(pairs))
        ts, ys, valid, after_jump, diagnostics = merged
        return _replaced(
            solution, ts=ts, ys=ys, valid=valid, after_jump=after_jump, diagnostics=diagnostics, jump_sides=None
        )


class Solution(eqx.Module):
    """A trajectory y = (α, ω, u, v) on a time grid with the reason it ended.

    States after ``t_stop`` are masked with NaN (``valid`` is False there): they are never
    computed values. Under ``vmap`` every field gains a leading batch axis. A run made on the
    host (:func:`peeljax.simulate`, :class:`peeljax.Simulator` with concrete inputs) holds
    read-only NumPy arrays; traced (under ``jit``, ``vmap``, ``grad``), JAX arrays.

    **Both sides of every jump.** Where v jumps at a fold of φ (``fold="jump"``), the rows
    keep the left and the right limit at the jump time t_j, as DifferentialEquations.jl's
    callbacks save both sides of an event: two consecutive rows with ``ts`` equal to t_j, the
    first holding the state just before the jump (v⁻, ``jumps.v_before``), the second the state
    just after it (v⁺, ``jumps.v_after``; α, ω and u are the same in both). ``after_jump`` is
    True on the second row, ``before_jump`` on the first. On the accepted steps (``ts=None``)
    the pair is the step that ends at the fold and the start of the next; with output times
    ``ts`` the pairs are inserted among them in time order (an output time equal to a jump's
    time holds the state before it): ``len(ts)`` rows plus two per jump (:func:`peeljax.simulate`;
    under ``jit`` ``len(ts) + 2·max_jumps``, the unused rows at the end repeating the last one,
    so that ``ys[-1]`` is the state at ``ts[-1]``: :meth:`without_padding` drops them on the
    host). Everything computed from the rows (extrema,
    :meth:`summary`, :func:`peeljax.analyze`, the figures) sees v⁺. A quantity that needs one
    state per time takes ``ts[~after_jump]`` (the left limits; ``ts[~before_jump]`` the right
    ones). Interpolating between rows, :func:`numpy.interp` takes the right limit at t_j
    itself and is exact on either side.

    Attributes:
        ts: output times, ``ts[0] = t0``.
        ys: states, shape ``(len(ts), 4)``, NaN where not ``valid``.
        valid: True where ``ys`` holds a computed state.
        status: a :class:`StopReason` code (0 = completed).
        t_stop: the last time reached (``ts[-1]`` when completed).
        stats: run statistics (Newton iterations, safeguards fired, steps, …). A run through
            the folds at τ = 0 also has ``fold_closest_miss`` (the closest the force came to a
            fold and turned away, a fraction of the fold distance's scale), its time
            ``fold_closest_miss_t``, and ``grazed_at``: the time of a miss within 10·rtol, a
            grazing after which no derivative exists (NaN; otherwise ``grazed_at`` is NaN).
        diagnostics: per-time-point :class:`StepDiagnostics`.
        jumps: the :class:`JumpRecord` of a run carried through the folds of φ (``fold="jump"``);
            None for a run without jumps.
        after_jump: True on each row that holds the state just after a jump (the row before it,
            at the same time, holds the state just before); None where the rows do not keep the
            jumps (a run without jump record, or one run with ``save_jumps=False``, or read from a
            file written before they were kept: :func:`peeljax.analyze` then inserts the jump
            record's v⁻ and v⁺ itself).
        jump_sides: between the compiled run and the host only: the jumps' rows not yet merged
            into these (:class:`JumpSides`; :meth:`without_padding` merges them). None otherwise.
    """

    ts: Float[Array, " n"]
    ys: Float[Array, "n 4"]
    valid: Bool[Array, " n"]
    status: Int[Array, ""]
    t_stop: Float[Array, ""]
    stats: dict[str, Array]
    diagnostics: StepDiagnostics | None
    method: str = eqx.field(static=True, default="alpha")
    jumps: JumpRecord | None = None
    after_jump: Bool[Array, " n"] | None = None
    jump_sides: JumpSides | None = None

    # -------------------------------------------------------------- states by name
    @property
    def alpha(self) -> Array:
        return self.ys[..., 0]

    @property
    def omega(self) -> Array:
        return self.ys[..., 1]

    @property
    def u(self) -> Array:
        return self.ys[..., 2]

    @property
    def v(self) -> Array:
        return self.ys[..., 3]

    @property
    def before_jump(self) -> Array | None:
        """True on each row that holds the state just before a jump (the row before an
        ``after_jump`` row, at the same time); None where the rows do not keep the jumps."""
        if self.after_jump is None:
            return None
        after = jnp.asarray(self.after_jump)
        return jnp.concatenate([after[..., 1:], jnp.zeros_like(after[..., :1])], axis=-1)

    # -------------------------------------------------------------- outcome
    @property
    def completed(self) -> Array:
        return self.status == StopReason.COMPLETED

    @property
    def reason(self) -> str | list[str]:
        """The stop reason(s) in words (host values; a list for a batch)."""
        codes = np.asarray(self.status)
        if codes.ndim == 0:
            return StopReason(int(codes)).message
        return [StopReason(int(c)).message for c in codes.ravel()]

    @property
    def status_name(self) -> str | list[str]:
        """``"completed"`` or ``"stopped"`` (a list for a batch)."""
        codes = np.asarray(self.status)
        names = np.where(codes == 0, "completed", "stopped")
        return str(names) if codes.ndim == 0 else names.ravel().tolist()

    def without_padding(self) -> Solution:
        """This single trajectory without its padding rows: the rows that hold no time (NaN in
        ``ts``: the accepted steps' rows after the last one) and the rows a dense output keeps
        for jumps that did not happen (at the end, repeating the last row: its time, its state,
        ``after_jump`` False). Host side (the number of rows depends on the run: not under
        ``jit``/``vmap``), its rows NumPy arrays; :func:`peeljax.simulate` returns its output at
        ``ts`` so.
        """
        if np.ndim(self.status) != 0:
            raise ValueError("without_padding() is for a single trajectory; index the batch first")
        if self.jump_sides is not None:  # the rows in use, merged on the host: no padding
            return JumpSides.merge(self.jump_sides, self)
        ts = np.asarray(self.ts)
        keep = np.isfinite(ts)
        keep[0] = True  # the start, even of a run whose start was refused
        if self.after_jump is not None:  # a dense output's unused jump rows repeat its last row
            after = np.asarray(self.after_jump, bool)
            kept = np.flatnonzero(keep)
            # the trailing rows that repeat the time before them and follow no jump (vectorized:
            # a row-by-row walk back over 2·10⁴ unused rows took 14 ms, 10x the run)
            repeat = (ts[kept[1:]] == ts[kept[:-1]]) & ~after[kept[1:]]
            real = np.flatnonzero(~repeat)
            last = int(real[-1]) + 2 if real.size else 1
            keep[kept[last:]] = False
        if keep.all():
            return self

        def rows(array):  # on the host: indexing the device array would compile a gather per row count
            return np.asarray(array)[keep]

        return _replaced(
            self, ts=rows(self.ts), ys=rows(self.ys), valid=rows(self.valid),
            diagnostics=None if self.diagnostics is None else jax.tree_util.tree_map(rows, self.diagnostics),
            after_jump=None if self.after_jump is None else rows(self.after_jump),
        )  # fmt: skip

    def summary(self) -> dict:
        """Host-side summary of a single trajectory (the CLI's ``--json`` fields)."""
        if np.ndim(self.status) != 0:
            raise ValueError("summary() is for a single trajectory; index the batch first")
        v = np.asarray(self.v)[np.asarray(self.valid)]
        if v.size == 0:  # a run whose initial state was already rejected: no velocity to say
            v = np.full(1, np.nan)
        rows = np.flatnonzero(np.asarray(self.valid))
        last = int(rows[-1]) if rows.size else 0
        out = {
            "status": self.status_name,
            "reason": self.reason,
            "t_stop": float(self.t_stop),
            "steps": _to_python(self.stats["steps"]) if "steps" in self.stats else last,
            "v_final": float(v[-1]),
            "v_min": float(v.min()),
            "v_max": float(v.max()),
        }
        # Statistics never overwrite a summary key.
        out.update({key: _to_python(value) for key, value in self.stats.items() if key not in out})
        return out

    @classmethod
    def load(cls, path) -> Solution:
        """Removed: use :func:`peeljax.load` (``peeljax.load(path)``), which returns the same
        :class:`~peeljax.saved.SavedRun`. Reading a file here made this module import
        :mod:`peeljax.saved`, which imports this one: an import circle.

        Raises:
            AttributeError: always, naming the replacement.
        """
        raise AttributeError(
            "Solution.load was removed: use peeljax.load(path), which returns the same SavedRun "
            "(a Solution with the run's model, V and tau)"
        )

    def save(self, path, **run) -> None:
        """Write the run to ``path``, the ``.npz`` that ``peeljax simulate --out`` writes and
        :func:`peeljax.load` reads back (:func:`peeljax.saved.run_arrays`).

        ``run``: what the Solution does not hold — ``V`` and ``tau`` (required), ``model`` (default
        the paper's), and optionally ``t_final``, ``dt``, ``rho``, ``rtol``, ``atol``, ``fold``,
        ``max_jumps``, ``transient``; a :class:`~peeljax.saved.SavedRun` supplies its own. The
        file is replaced only once complete: a failed write leaves the previous file as it was.
        """
        from .run_file import write_run  # it knows the model, which this module does not import

        write_run(path, self, **run)


def _to_python(value):
    array = np.asarray(value)
    return array.item() if array.ndim == 0 else array.tolist()


def mask_after_stop(ys: Array, valid: Array) -> Array:
    """NaN where not valid; the where keeps gradients of the valid part finite."""
    return jnp.where(valid[:, None], ys, jnp.nan)
