"""The compiled program of one run, and the host's assembly of what it returns.

Shared by :func:`peeljax.simulate` and :class:`peeljax.Simulator` (one program for both): the
model and options made into an ODE and checked (:func:`_prepare`), the run compiled once per
machine (:data:`_kept_run`, :mod:`peeljax._exported`), the output rows cut to the times asked
for and the jumps' rows merged among them (:func:`_finished`), and a jump record that filled
grown (:func:`grown_until_it_holds`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Literal, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._exported import ExportedProgram
from ._memory import check_output_memory
from ._validation import check_positive, check_tau, check_truncation, check_y0
from .constrained import ConstrainedDAE
from .homogenized import HomogenizedODE
from .integrators.adjoint import TANGENT_BYTES, TANGENT_LIMITS, reverse_by_tangents, undefined_where_unreached
from .integrators.base import AbstractIntegrator
from .integrators.uniform_mesh import UniformMesh
from .model import PeelingModel
from .solution import PAIR_AT, JumpSides, Solution, StopReason, _replaced, is_traced

__all__ = ["FIRST_MAX_JUMPS", "check_run_memory", "grown_until_it_holds", "is_dae"]

# Peak host memory of a run per output row [bytes], measured as the growth of the peak RSS
# from 2e6 to 4e6 rows (V = 1.1, tau = 0.01, t_final = 3): the dense output at ``ts`` 354,
# the accepted steps (``ts=None``, max_steps + 1 rows) 76, the uniform mesh 133; rounded up.
# Times, states, the diagnostics, the compiled loop's buffers and the returned copy.
ROW_BYTES = {"ts": 400, "steps": 100, "mesh": 150}
_ROWS = {"ts": "output times", "steps": "rows of accepted steps (max_steps + 1)", "mesh": "mesh points"}

# max_jumps=None called eagerly: the jump record's first size. Its room once cost ~50 ns a slot
# in every call whether a jump happened or not (with 10⁴ slots P1 took 1.36-1.58x its time with
# fold="stop"); 1, 16, 128 and 1024 slots now read the same (docs/performance.md). A run that fills it is run again
# with room for the jumps its rate predicts, a power of two (each size one program, cached).
FIRST_MAX_JUMPS = 1024


def check_run_memory(
    rows: int, kind: str, max_jumps: int = 0, *, remedy: str, limit: float | None = None, jump_rows: int = 0
) -> None:
    """Refuse a run whose output would not fit in memory (:func:`peeljax._memory.check_output_memory`).

    ``rows``: output rows of ``kind`` ``"ts"`` (dense output), ``"steps"`` (the accepted steps)
    or ``"mesh"`` (the uniform mesh); ``jump_rows``: the rows kept for the jumps' sides;
    ``max_jumps``: slots of the jump record (up to 6 arrays of 8 bytes).
    """
    total = float(rows + jump_rows) * ROW_BYTES[kind] + 48.0 * max_jumps
    sides = f" + {jump_rows:.4g} rows for the jumps' sides" if jump_rows else ""
    jumps = f" + a record of {max_jumps} jumps" if max_jumps else ""
    detail = f"{rows:.4g} {_ROWS[kind]}{sides} x ~{ROW_BYTES[kind]} bytes{jumps}"
    check_output_memory("the run's output", total, detail, remedy, limit)


def is_dae(tau) -> bool:
    """τ = 0 given as a host number: the DAE itself (:class:`ConstrainedDAE`) rather than eq. ``hv``."""
    return not isinstance(tau, jax.core.Tracer) and np.ndim(tau) == 0 and float(tau) == 0.0


@functools.cache
def _paper_model() -> PeelingModel:
    """The paper's model, made once: a module is immutable, and making it takes ~40 µs of a P1 call's ~0.9 ms."""
    return PeelingModel()


def _prepare(model, V, tau, y0, truncation, allow_dae=False):
    model = _paper_model() if model is None else model
    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    check_positive("V", V)
    check_tau(tau, allow_zero=allow_dae)
    check_y0(y0)
    check_truncation(truncation)
    for name in ("R", "I", "k", "l"):
        check_positive(f"model.{name}", getattr(model, name))
    if allow_dae and is_dae(tau):
        if truncation is not None:
            raise ValueError("truncation applies to tau > 0 (the homogenized ODE); tau=0 is the DAE itself")
        ode = ConstrainedDAE(model, V)
    else:
        ode = HomogenizedODE(model, V, tau, truncation)
    # None: the paper's initial data, computed inside the compiled run (eagerly, its dozen
    # small operations would cost more than a short run).
    return ode, (None if y0 is None else jnp.asarray(y0, float))


def _initial_state(ode, y0):
    return ode.model.initial_state(ode.V) if y0 is None else y0


def _integrate(integrator, ode, y0, t_final, ts):
    """The run; ``jax.grad`` of it by tangents of the few numbers perturbed
    (:func:`~peeljax.integrators.adjoint.reverse_by_tangents`) where the integrator's adjoint
    is ``"reverse"``. Here, before the paper's initial data are computed from the model, a
    φ coefficient is one perturbed number (after, the four of y0 too)."""
    inputs = (integrator, ode, y0, t_final, ts)
    if getattr(integrator, "adjoint", None) == "reverse":
        return reverse_by_tangents(_integrate_with, inputs, _tangent_limit(integrator, ode, ts))
    return _integrate_with(inputs, None)


def _tangent_limit(integrator, ode, ts) -> int:
    """Most perturbed numbers a reverse-mode derivative takes by tangents: the measured
    break-even (:data:`~peeljax.integrators.adjoint.TANGENT_LIMITS`), fewer where the k tangents
    of the output rows would take more than ``TANGENT_BYTES``."""
    events = getattr(integrator, "events", None)
    jumps = 0 if events is None else int(events.max_jumps)
    rows = integrator.max_steps + 1 + jumps if ts is None else ts.shape[0] + 2 * jumps
    limit = TANGENT_LIMITS["dae" if isinstance(ode, ConstrainedDAE) else "ode"]
    return int(min(limit, TANGENT_BYTES // (rows * ROW_BYTES["steps"])))


def _integrate_with(inputs, kind: Literal["lax", "checkpointed"] | None):
    """The run with a loop of ``kind`` (None: the integrator's own); the values it did not
    reach have NaN derivatives (:func:`~peeljax.integrators.adjoint.undefined_where_unreached`)."""
    integrator, ode, y0, t_final, ts = inputs
    if kind is not None:
        integrator = dataclasses.replace(integrator, adjoint="forward" if kind == "lax" else "checkpointed")
    solution = integrator.integrate(ode, _initial_state(ode, y0), 0.0, t_final, ts)
    return undefined_where_unreached(solution, inputs, reverse=getattr(integrator, "adjoint", None) == "checkpointed")


class StaticLeaf(NamedTuple):
    """A leaf that is not an array (a Python number or function of a φ of the user's, a diffrax
    solver's settings): part of the program's static part, compared by value, as
    ``eqx.filter_jit`` compares it."""

    value: object


def is_host_scalar(leaf) -> bool:
    return isinstance(leaf, (np.ndarray, np.generic)) and leaf.shape == () and leaf.dtype == np.float64


def leaf_kinds(leaves) -> tuple | None:
    """Each leaf's place in a run's program: True, a float64 scalar on the host (packed into one
    vector); False, another array (or a tracer); a :class:`StaticLeaf`, not an array. None where
    a leaf that is not an array cannot be hashed (the run then takes ``eqx.filter_jit``)."""
    kinds = []
    for leaf in leaves:
        if is_host_scalar(leaf):
            kinds.append(True)
        elif isinstance(leaf, (jax.Array, np.ndarray, np.generic)):
            kinds.append(False)
        else:
            try:
                hash(leaf)
            except TypeError:
                return None
            kinds.append(StaticLeaf(leaf))
    return tuple(kinds)


def _integrate_packed(packed, rest, *, treedef, scalars):
    """The run from its leaves sorted by :func:`leaf_kinds` (``scalars``)."""
    leaves, k, j = [], 0, 0
    for kind in scalars:
        if kind is True:
            leaves.append(packed[k])
            k += 1
        elif kind is False:
            leaves.append(rest[j])
            j += 1
        else:
            leaves.append(kind.value)
    return _integrate(*jax.tree_util.tree_unflatten(treedef, leaves))


_packed_jit = jax.jit(_integrate_packed, static_argnames=("treedef", "scalars"))
# the same program, its tracing kept on disk (peeljax._exported): a new process reads it back
_kept_run = ExportedProgram(
    "simulate",
    lambda static, packed, rest: _integrate_packed(packed, rest, treedef=static[0], scalars=static[1]),
    lambda static, packed, rest: _packed_jit(packed, rest, treedef=static[0], scalars=static[1]),
    host_outputs=True,
)
_filter_jit = eqx.filter_jit(_integrate)


def _run(integrator: AbstractIntegrator, ode, y0, t_final, ts) -> Solution:
    """The compiled run, with ``jax.jit``'s C++ dispatch.

    The float parameters held on the host (about 30: the model's, φ's, the integrator's)
    travel as one vector, one host-to-device copy instead of one each (a call's fixed cost is
    measured by ``benchmarks/studies/adaptive_drivers.py`` (retired: ``benchmarks/studies/README.md``));
    the integrator's static fields (step budgets, mesh size) are in the tree's structure, and
    so are the leaves that are not arrays (a φ of the user's with a Python float field or given
    as a function, a diffrax solver's settings), by value, as ``eqx.filter_jit`` takes them. A
    leaf that is not an array and cannot be hashed takes ``eqx.filter_jit`` itself.

    Run on concrete inputs, the solution's arrays are NumPy arrays on the host (:class:`~peeljax._exported.HostOutputs`):
    what :func:`simulate` does with them next (cut, merge, drop padding) is host work.
    """
    leaves, treedef = jax.tree_util.tree_flatten((integrator, ode, y0, t_final, ts))
    kinds = leaf_kinds(leaves)
    if kinds is None:
        solution = _filter_jit(integrator, ode, y0, t_final, ts)
        return solution if is_traced(solution) else jax.device_get(solution)
    packed = np.array([leaf for leaf, kind in zip(leaves, kinds) if kind is True], dtype=float)
    rest = [leaf for leaf, kind in zip(leaves, kinds) if kind is False]
    return _kept_run((treedef, kinds), packed, rest)  # concrete: NumPy arrays on the host


def _bucketed(ts: np.ndarray) -> np.ndarray:
    """``ts`` padded by repeating its last time to the next of 8, 10, 12, 14, 16, 20, 24, …
    rows (4, 5, 6 or 7 times a power of two): at most a quarter more rows, written at the last step.

    The compiled run's shape follows ``len(ts)``: a grid of another length would compile the
    run again (10 s at τ > 0 with the defaults, measured); one in the same bucket reuses the
    program. :func:`_first_rows` drops the added rows.
    """
    n = ts.shape[0]
    power = 1 << max(1, (n - 1).bit_length() - 3)  # n ≤ 8·power
    size = max(8, -(-n // power) * power)
    return np.concatenate([ts, np.full(size - n, ts[-1])])


def _first_rows(solution: Solution, n: int) -> Solution:
    """The run's rows at the n output times the caller gave: those :func:`_bucketed` added
    dropped, and each jump's count of output times before it (``PAIR_AT``) held to n."""
    fields = vars(solution)  # (one read: a module's attribute costs ~1 µs through equinox, per call)
    if np.shape(fields["ts"])[-1] == n:
        return solution
    rows = tuple(fields[name] for name in ("ts", "ys", "valid", "diagnostics", "after_jump"))
    sides = fields["jump_sides"]
    written = None if sides is None else vars(sides)["written"]
    no_jump = sides is None or (  # (merge reads it anyway)
        (isinstance(written, np.ndarray) or not is_traced(sides)) and int(written) == 0
    )
    (ts, ys, valid, diagnostics, after_jump), counts = _cut(rows, None if no_jump else vars(sides)["counts"], n)
    if counts is not None:
        sides = _replaced(sides, counts=counts)
    return _replaced(
        solution, ts=ts, ys=ys, valid=valid, diagnostics=diagnostics, after_jump=after_jump, jump_sides=sides
    )


def _cut(rows, counts, n: int):
    """The first n rows: NumPy views on the host, one compiled program where traced."""
    if isinstance(rows[0], np.ndarray):
        return _cut_with(np, rows, counts, n)
    return _cut_traced(rows, counts, n)


def _cut_with(xp, rows, counts, n: int):
    rows = jax.tree_util.tree_map(lambda a: a[:n], rows)
    if counts is not None:
        counts = xp.where(xp.arange(counts.shape[-1]) == PAIR_AT, xp.minimum(counts, n), counts)
    return rows, counts


_cut_traced = jax.jit(functools.partial(_cut_with, jnp), static_argnums=2)


def _finished(solution: Solution, ts) -> Solution:
    """The run as ``simulate`` returns it: the jumps' rows merged among the output times (on
    the host the rows in use; traced all, static shapes), the rows left for more steps dropped."""
    # (the methods called on the class: a bound method of a module is a module, ~10 µs to make)
    fields = vars(solution)
    if fields["jump_sides"] is not None:
        return JumpSides.merge(fields["jump_sides"], solution)
    if ts is not None and (isinstance(fields["ts"], np.ndarray) or not is_traced(solution)):
        return Solution.without_padding(solution)
    return solution


def grown_until_it_holds(solution: Solution, size: int, integrator_with, run, ts, max_steps, memory_limit, t_final):
    """``solution`` of a run whose jump record had ``size`` slots, or, where they were filled,
    the run again with room for the rest (:func:`_room_for_the_rest`) until its record holds
    every jump or the next size would exceed ``memory_limit`` (the run then stops as before,
    its reason naming max_jumps). ``integrator_with(size)``: the integrator; ``run``: its run."""
    # (a run inside jit whose inputs are all constants is traced nonetheless: it cannot grow)
    while not is_traced(solution.status) and int(solution.status) == StopReason.MAX_JUMPS:
        size = _room_for_the_rest(solution, size, t_final)
        integrator = integrator_with(size)
        try:
            _check_memory(integrator, ts, max_steps, memory_limit)
        except ValueError:
            break
        solution = run(integrator)
    return solution


def _room_for_the_rest(solution: Solution, size: int, t_final: float) -> int:
    """A jump record for the whole run, from one that ``size`` jumps filled at ``t_stop``: twice
    the jumps at their rate so far to ``t_final`` (the first come late, after the start's
    transient), as a power of two (≥ 4·size): a run again costs more than room left unused."""
    t_stop = float(solution.t_stop)
    expected = 2 * size * float(t_final) / t_stop if t_stop > 0 else 4 * size
    return max(4 * size, 1 << math.ceil(math.log2(max(expected, 1.0))))


def _check_memory(integrator, ts, max_steps, limit) -> None:
    events = getattr(integrator, "events", None)
    max_jumps = 0 if events is None else int(events.max_jumps)
    if isinstance(integrator, UniformMesh):
        rows, kind, remedy = integrator.n_steps + 1, "mesh", "a larger dt or a shorter t_final"
    elif ts is not None:  # and two rows per jump (both sides)
        rows, kind, remedy = ts.size, "ts", "fewer output times ts"
    else:
        rows, kind, remedy = max_steps + 1, "steps", "a smaller max_steps, or output at fewer times ts"
    sides = 0 if isinstance(integrator, UniformMesh) else (2 if ts is not None else 1) * max_jumps
    remedy += (", a smaller max_jumps" if max_jumps else "") + ", or raise memory_limit"
    check_run_memory(rows, kind, max_jumps, remedy=remedy, limit=limit, jump_rows=sides)
