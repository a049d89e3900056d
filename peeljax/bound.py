"""A simulator bound to its options: :func:`peeljax.simulate` for callers that run it in a loop.

:func:`peeljax.simulate` checks its options, builds the integrator and the ODE, packs about
thirty parameters and copies them to the device on a call: ~0.2 ms around a compiled run
of a few tenths of a millisecond (``benchmarks/studies/results/adaptive_drivers.md``); on a
second call with the same options it makes a :class:`Simulator` and keeps it.
:class:`Simulator` does all of that once, for every option but V, τ and y0; a call checks V
and τ with plain float comparisons, writes them into the packed parameter vector of
``simulate._run`` and runs ``simulate``'s own program, compiled ahead of time
(``jax.jit(...).lower(...).compile()``).
"""

from __future__ import annotations

import collections
import functools
import math

import diffrax
import jax
import numpy as np
from jaxtyping import ArrayLike

from ._arrays import float_array
from ._validation import TAU_MAX, check_output_times, check_positive, check_tau, check_y0
from .homogenized import HomogenizedODE
from .integrators.alpha import AlphaMethod
from .integrators.base import AbstractIntegrator
from .integrators.select import DEFAULT_MAX_JUMPS, integrator_for, refuse_with_dt, resolve_max_steps
from .model import PeelingModel
from .run_program import (
    FIRST_MAX_JUMPS, _bucketed, _check_memory, _finished, _first_rows, _kept_run, _prepare, _run,
    grown_until_it_holds, is_dae, is_host_scalar, leaf_kinds,
)  # fmt: skip
from .solution import Solution, StopReason, is_traced

__all__ = ["Simulator"]

_INF = math.inf


def _number(value) -> float | None:
    """A plain host number (Python, NumPy float64, 0-d float array) as a float; else None."""
    kind = type(value)
    if kind is float or kind is int or kind is np.float64:
        return float(value)
    if kind is np.ndarray and value.shape == () and value.dtype.kind == "f":
        return float(value)
    return None


def _scalar(name: str, value) -> float:
    """A concrete V or τ that passed simulate's check, as a float: a call runs one V and one τ."""
    if np.ndim(value) != 0:
        raise ValueError(
            f"{name} must be a scalar for a Simulator call, got shape {np.shape(value)}: "
            "use jax.vmap over the call, or peeljax.sweep, for many values"
        )
    return float(value)


class _Program:
    """The compiled run of one kind of call (τ > 0 or τ = 0, without or with y0), on the device.

    The leaves of ``(integrator, ode, y0, t_final, ts)`` sorted once as ``simulate._run``
    sorts them on every call: the float64 scalars (the model's, φ's, the integrator's, V, τ,
    t_final) one host vector, ``template``, in which a call writes V and τ (and y0 into
    ``rest``); the other arrays (``ts``) copied to the device once. The executable is
    ``simulate``'s own program (``run_program._kept_run``: read back from disk, or traced in
    this process where programs are not kept there), compiled ahead of time on first use: the
    same computation as ``simulate``'s, and one compilation for both in a process.
    A leaf that is not an array (a Python float or function of a φ of the user's, a diffrax
    solver's settings) is part of the program's static part, by value (``leaf_kinds``).
    ``fast`` is False where such a leaf cannot be hashed: ``simulate`` then takes
    ``eqx.filter_jit``, and so does the call.
    """

    def __init__(self, integrator: AbstractIntegrator, ode, y0, t_final, ts):
        leaves, self.treedef = jax.tree_util.tree_flatten((integrator, ode, y0, t_final, ts))
        kinds = leaf_kinds(leaves)
        self.fast = kinds is not None
        self.scalars = kinds if self.fast else tuple(is_host_scalar(leaf) for leaf in leaves)
        packed = [leaf for leaf, kind in zip(leaves, self.scalars) if kind is True]
        rest = [leaf for leaf, kind in zip(leaves, self.scalars) if kind is False]
        self.template = np.array(packed, dtype=float)
        self.i_V = _position(packed, ode.V)
        self.i_tau = _position(packed, ode.tau) if isinstance(ode, HomogenizedODE) else None
        self.i_y0 = None if y0 is None else _position(rest, y0)
        self.rest = jax.device_put(rest) if self.fast else rest
        self.executable = None

    def compile(self):
        if self.executable is None:
            leaves, structure = jax.tree_util.tree_flatten((self.template, self.rest))
            signature = (self.treedef, self.scalars, structure, tuple((np.shape(x), np.asarray(x).dtype.str) for x in leaves))
            self.executable = _EXECUTABLES.get(signature)
            if self.executable is None:
                self.executable = _EXECUTABLES[signature] = self._compiled(leaves, structure)
                if len(_EXECUTABLES) > KEPT_EXECUTABLES:
                    _EXECUTABLES.popitem(last=False)
            else:
                _EXECUTABLES.move_to_end(signature)
        return self.executable

    def _compiled(self, leaves, structure):
        # simulate's program: read back from disk (peeljax._exported), or traced in this process
        kept = _kept_run.program((self.treedef, self.scalars), structure, leaves)
        compiled = kept.lower(*leaves).compile()
        return lambda packed, rest: kept.unpack(compiled(packed, *rest))


# The compiled programs of the Simulators in the process, by signature (the tree of the
# integrator, ODE and output times, and the arrays' shapes), the most recently used last:
# Simulators of other models or options with the same structure share one compilation
# (``simulate`` makes one per options). A Simulator keeps its own in any case.
_EXECUTABLES: collections.OrderedDict = collections.OrderedDict()
KEPT_EXECUTABLES = 32


def _position(leaves: list, leaf) -> int:
    return next(i for i, other in enumerate(leaves) if other is leaf)


class Simulator:
    """:func:`peeljax.simulate` with every option but V, τ and y0 bound: for runs in a loop.

    ``Simulator(model, t_final=..., rtol=..., ts=..., ...)`` takes the options of
    :func:`peeljax.simulate` but V, tau and y0 (same names, defaults and meaning), checks
    them once with ``simulate``'s own checks and messages (:func:`integrator_for`,
    :mod:`peeljax._validation`: bad options raise here, before anything compiles), and builds
    the integrator, the model's packed parameters and ``ts`` (on the device) once. Then
    ``sim(V, tau)`` (optionally ``y0=``) returns the :class:`Solution` that
    ``simulate(model, V=V, tau=tau, y0=y0, **options)`` returns, from the same compiled
    program: bit-identical ``ys``, ``ts``, ``status`` and jumps. Each call still checks V
    (finite, > 0) and τ (finite, in [0, 1e6]), as plain float comparisons, raising
    ``simulate``'s errors.

    τ = 0 selects the DAE (:class:`~peeljax.ConstrainedDAE`), τ > 0 the homogenized ODE:
    different programs. Each kind (and each with a ``y0``) is compiled ahead of time on the
    first call that needs it, or by :meth:`compile`, and kept: later calls with other V and τ
    compile nothing. The program is ``simulate``'s, so a ``simulate`` call with the same
    options in the same process reuses the compilation, and the other way round. Options
    that only τ > 0 allows (``dt``, a diffrax ``solver``, ``fold="follow"``, ``truncation``)
    raise ``simulate``'s error on a call with τ = 0, not at construction.

    A traced V, τ or y0 (inside ``jax.grad``, ``jax.vmap``, ``jax.jit``) takes ``simulate``'s
    own route (``simulate._run``) with the bound options, so gradients and batches are
    ``simulate``'s. So does a run with a leaf that is not an array and cannot be hashed (then
    only the option checks are saved); a leaf that is not an array but can be (a Python float
    or function of a φ of the user's, a diffrax solver's settings) is part of the compiled
    program, by value.

    Per call, the checks of ``simulate`` are saved. ``simulate`` itself keeps a ``Simulator``
    for options it sees a second time (:func:`peeljax.simulate._kept_simulator`): P1 through
    ``simulate`` then takes 1.02–1.06× its time through a ``Simulator`` (``benchmarks/guard.py``'s
    ``simulator_call``; 1.3–1.4× before).

    Example::

        import jax
        import numpy as np
        import peeljax as pj

        sim = pj.Simulator(t_final=3.0, rtol=1e-6, atol=1e-9, ts=np.linspace(0, 3, 301))
        for V in (1.1, 2.0, 4.0):
            sol = sim(V, 0.01)  # what pj.simulate(V=V, tau=0.01, t_final=3.0, ...) returns
        stick_slip = sim(1.1, 0.0)  # τ = 0: the DAE, v jumping at the folds (its own program)
        slope = jax.grad(lambda V: sim(V, 0.01).v[-1])(1.1)
    """

    def __init__(
        self,
        model: PeelingModel | None = None,
        *,
        t_final: float = 3.0,
        ts: ArrayLike | None = None,
        dt: float | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        rho: ArrayLike = 0.0,
        solver: str | AlphaMethod | diffrax.AbstractSolver | None = None,
        fold: str | None = None,
        max_steps: int | None = None,
        max_jumps: int | None = None,
        dtmin: float | None = None,
        truncation: int | None = None,
        adjoint: str = "reverse",
        checkpoint_every: int | str | None = None,
        memory_limit: float | None = None,
    ):
        # simulate's checks, in its order, for τ > 0 (the homogenized ODE).
        if dt is not None:
            refuse_with_dt(dt, ts=ts)
        max_steps = resolve_max_steps(max_steps, keeps_steps=ts is None)
        # max_jumps=None: simulate's record, grown on a call that fills it (fixed when traced)
        self._grows = max_jumps is None
        self._integrator_of = functools.partial(
            integrator_for, solver, rho=rho, dt=dt, t_final=t_final, rtol=rtol, atol=atol, dtmin=dtmin,
            max_steps=max_steps, adjoint=adjoint, checkpoint_every=checkpoint_every, fold=fold,
            merge_jump_rows=False,  # simulate's program: the jumps' rows merged on the host
        )  # fmt: skip
        integrator_of = functools.partial(self._integrator_of, max_jumps=FIRST_MAX_JUMPS if self._grows else max_jumps)
        self._on_the_host = functools.partial(integrator_of, folds_at_first_jump=True)  # concrete calls
        integrator = integrator_of(dae=False)
        self.ts = None if ts is None else check_output_times(ts, t_final)
        self._run_ts = None if ts is None else _bucketed(self.ts)  # simulate's program: its rows cut alike
        _check_memory(integrator, self.ts, max_steps, memory_limit)
        self._max_steps, self._memory_limit = max_steps, memory_limit
        ode, _ = _prepare(model, 1.0, 1.0, None, truncation, allow_dae=True)  # the model's checks
        self.model: PeelingModel = ode.model
        self.truncation = truncation
        self.t_final = float_array(t_final)
        self.integrators: dict[bool, AbstractIntegrator] = {False: integrator}
        # τ = 0 (the DAE): an option it refuses raises simulate's error on a call with τ = 0.
        self._dae_error = None
        try:
            self.integrators[True] = integrator_of(dae=True)
            _prepare(self.model, 1.0, 0.0, None, truncation, allow_dae=True)
        except (TypeError, ValueError) as error:
            self._dae_error = (type(error), error.args)
        self._programs: dict[tuple[bool, bool], _Program] = {}

    def _refuse_dae(self) -> None:
        if self._dae_error is not None:
            kind, args = self._dae_error
            raise kind(*args)

    def _program(self, dae: bool, with_y0: bool) -> _Program:
        program = self._programs.get((dae, with_y0))
        if program is None:
            if dae:
                self._refuse_dae()
            ode, _ = _prepare(self.model, 1.0, 0.0 if dae else 1.0, None, self.truncation, allow_dae=True)
            y0 = np.zeros(4) if with_y0 else None
            program = _Program(self._on_the_host(dae=dae), ode, y0, self.t_final, self._run_ts)
            self._programs[(dae, with_y0)] = program
        return program

    def compile(self, dae: bool = False, with_y0: bool = False) -> Simulator:
        """Compile now the program of τ > 0 (``dae=False``) or of τ = 0, without or with y0; returns self."""
        program = self._program(dae, with_y0)
        if program.fast:
            program.compile()
        return self

    def __call__(self, V: ArrayLike, tau: ArrayLike, y0: ArrayLike | None = None) -> Solution:
        """``simulate(model, V=V, tau=tau, y0=y0, **options)``: V > 0 [m/s] and τ ≥ 0 [s], scalars."""
        t, v = _number(tau), _number(V)
        # simulate's checks in its order: a comparison for a plain number, else its own code.
        if t is None or not 0.0 <= t <= TAU_MAX:
            if isinstance(tau, jax.core.Tracer):
                return self._general(V, tau, y0)
            check_tau(tau, allow_zero=True)
            t = _scalar("tau", tau)
        if v is None or not 0.0 < v < _INF:
            if isinstance(V, jax.core.Tracer):
                return self._general(V, tau, y0)
            check_positive("V", V)
            v = _scalar("V", V)
        with_y0 = y0 is not None
        if with_y0 and (isinstance(y0, jax.core.Tracer) or np.shape(y0) != (4,)):
            return self._general(V, tau, y0)
        program = self._programs.get((t == 0.0, with_y0)) or self._program(t == 0.0, with_y0)
        if not program.fast:
            return self._general(V, tau, y0)
        packed = program.template.copy()
        packed[program.i_V] = v
        if program.i_tau is not None:
            packed[program.i_tau] = t
        rest = program.rest
        if with_y0:
            check_y0(y0)
            rest = list(rest)
            rest[program.i_y0] = np.asarray(y0, dtype=float)
        solution = (program.executable or program.compile())(packed, rest)
        if self._grows and int(solution.status) == StopReason.MAX_JUMPS:
            ode, y0 = _prepare(self.model, v, t, y0, self.truncation, allow_dae=True)
            solution = self._grown(solution, ode, y0, t == 0.0)
        return self._unpadded(solution)

    def _integrator(self, dae: bool, max_jumps: int, on_the_host: bool = False) -> AbstractIntegrator:
        return self._integrator_of(dae=dae, max_jumps=max_jumps, folds_at_first_jump=on_the_host)

    def _unpadded(self, solution: Solution) -> Solution:
        return _finished(solution if self.ts is None else _first_rows(solution, self.ts.shape[0]), self.ts)

    def _general(self, V, tau, y0) -> Solution:
        """simulate's route (a traced V, τ or y0; a batch of y0; a diffrax solver): its checks, ODE, ``_run``."""
        check_tau(tau, allow_zero=True)
        dae = is_dae(tau)
        if dae:
            self._refuse_dae()
        ode, y0 = _prepare(self.model, V, tau, y0, self.truncation, allow_dae=True)
        if not self._grows:
            return self._unpadded(_run(self.integrators[dae], ode, y0, self.t_final, self._run_ts))
        if is_traced((V, tau, y0)):  # simulate's record, its size fixed before the run
            return self._unpadded(_run(self._integrator(dae, DEFAULT_MAX_JUMPS), ode, y0, self.t_final, self._run_ts))
        integrator = self._on_the_host(dae=dae)
        return self._unpadded(self._grown(_run(integrator, ode, y0, self.t_final, self._run_ts), ode, y0, dae))

    def _grown(self, solution: Solution, ode, y0, dae: bool) -> Solution:
        """simulate's growth of a record that the run filled (:func:`~peeljax.simulate.grown_until_it_holds`)."""
        if is_traced(solution.status) or int(solution.status) != StopReason.MAX_JUMPS:
            return solution
        return grown_until_it_holds(
            solution, FIRST_MAX_JUMPS, lambda max_jumps: self._integrator(dae, max_jumps, on_the_host=True),
            lambda integrator: _run(integrator, ode, y0, self.t_final, self._run_ts), self.ts, self._max_steps,
            self._memory_limit, float(self.t_final),
        )  # fmt: skip
