"""The paper's uniform mesh: the α-method with a fixed step h = (t_final − t0)/N under ``lax.scan``.

Kept for reproducing the paper's runs (``dt=``); error control is :mod:`.adaptive`. Derivatives go through each step's ``custom_jvp`` (:mod:`.alpha`);
``checkpoint_every`` bounds reverse mode's memory.

Reverse mode stores no step's linearization: each step is rematerialized (``jax.checkpoint``
with nothing saveable), so the forward pass keeps only the carried state per step and the
reverse pass recomputes the step from it, then its tangent. A step's linearization is the
replay of its substep path (:meth:`~peeljax.integrators.alpha.AlphaMethod._replay`): stored,
it is ~600 arrays per step (the residuals of both branches of the replay's ``cond``), and the
compiled gradient of the paper's 82-step run spent about half of its compile time on them
(``benchmarks/compile_cost.py`` (retired: ``benchmarks/studies/README.md``): XLA's CPU time 32.5 → 18 s); recomputed, the gradient's run
is no slower (0.82–0.89× the stored one's, both compiled in one process and called in turn:
the step's Newton solves cost less than storing and reading back its linearization). Values and derivatives are unchanged (to 7e-15); forward-mode
derivatives and plain runs do not see it.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..homogenized import ODE
from ..solution import Solution, StepDiagnostics, mask_after_stop
from ..structure import local_index
from .alpha import AlphaMethod, alpha_advance, alpha_start, to_physical
from .base import AbstractIntegrator, ObservedRun
from .dense import HermiteInterpolant
from .observers import AcceptedStep

__all__ = ["UniformMesh", "integrate_alpha"]


def _checkpoint_chunk(checkpoint_every, n_steps: int) -> int | None:
    if checkpoint_every is None or checkpoint_every is False:
        return None
    if checkpoint_every == "sqrt" or checkpoint_every is True:
        return max(1, round(n_steps**0.5))
    if isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int) or checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be None, 'sqrt' or a positive integer, got {checkpoint_every!r}")
    return min(checkpoint_every, n_steps)


# Rematerialize each step in reverse mode (module docstring); False stores the steps' linearizations
# (the compile-time benchmark's "before").
_REMAT_STEPS = True


def _rematerialized(body):
    """``body`` recomputed in the reverse pass from its carry, nothing of it stored (module docstring)."""
    if not _REMAT_STEPS:
        return body
    return jax.checkpoint(body, prevent_cse=False, policy=jax.checkpoint_policies.nothing_saveable)


def _checkpointed_scan(body, init, n_steps: int, chunk: int):
    """``lax.scan(body, init, None, length=n_steps)`` as ⌊n/c⌋ chunks of c steps, each under
    ``jax.checkpoint`` (nothing inside a chunk is stored for the reverse pass), plus a tail."""
    n_chunks, tail = divmod(n_steps, chunk)

    @jax.checkpoint
    def run_chunk(state, _):
        return jax.lax.scan(body, state, None, length=chunk)

    state, outs = jax.lax.scan(run_chunk, init, None, length=n_chunks)
    outs = jax.tree_util.tree_map(lambda a: a.reshape((n_chunks * chunk,) + a.shape[2:]), outs)
    if tail:
        state, tail_outs = jax.lax.scan(body, state, None, length=tail)
        outs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), outs, tail_outs)
    return state, outs


def integrate_alpha(
    ode: ODE,
    solver: AlphaMethod,
    y0: Float[Array, "4"],
    t0: ArrayLike,
    t_final: ArrayLike,
    n_steps: int,
    *,
    checkpoint_every: int | None = None,
) -> Solution:
    """Integrate y' = ψ(y) with the α-method on a uniform mesh of ``n_steps`` steps (static).

    One ``lax.scan`` of :func:`alpha_advance` over the steps; after a stop the remaining steps
    are skipped and their states masked. Pure and traceable: ``jit``/``vmap`` over ode,
    solver, y0 and the times. Validation is the caller's job (see :func:`peeljax.simulate`).

    Differentiable (``jax.grad``/``jax.jvp``) with respect to every float leaf of ``ode``
    (model parameters, φ's coefficients, V, τ), y0 and the times; see the module docstring.
    ``checkpoint_every`` = c (static) splits the scan into chunks of c steps under
    ``jax.checkpoint``: reverse mode then stores one state per chunk and recomputes a chunk's
    steps when it gets there, so its memory grows like N/c + c (∝ √N for c ≈ √N, the choice
    ``checkpoint_every="sqrt"`` makes) for about one more forward run of time. Values are
    unchanged.
    """
    t0 = jnp.asarray(t0, float)
    h = (jnp.asarray(t_final, float) - t0) / n_steps
    y0 = jnp.asarray(y0, float)
    ode, state0 = alpha_start(ode, solver, y0)
    start_ok = state0.status == 0

    @_rematerialized
    def body(state, _):
        state, info, ok = alpha_advance(ode, solver, state, h)
        return state, (state.y, state.J, ok, info)

    chunk = _checkpoint_chunk(checkpoint_every, n_steps)
    if chunk is None:
        final, (ys, Js, oks, infos) = jax.lax.scan(body, state0, None, length=n_steps)
    else:
        final, (ys, Js, oks, infos) = _checkpointed_scan(body, state0, n_steps, chunk)

    ts = t0 + h * jnp.arange(n_steps + 1)
    valid = jnp.concatenate([start_ok[None], oks])
    ys = to_physical(solver, jnp.concatenate([state0.y[None], ys]))
    Js = jnp.concatenate([state0.J[None], Js])
    n_valid = jnp.sum(valid)
    t_stop = jnp.where(start_ok, ts[jnp.maximum(n_valid - 1, 0)], t0)
    diagnostics = StepDiagnostics(
        newton_iterations=jnp.concatenate([jnp.zeros(1, jnp.int32), infos.newton_iterations]),
        newton_correction=jnp.concatenate([jnp.zeros(1), infos.newton_correction]),
        schur=jnp.where(valid, Js, jnp.nan),
        local_index=jnp.where(valid, local_index(Js, ode.tau), 0),
        condition=jnp.concatenate([jnp.full(1, jnp.nan), infos.condition]),
    )
    stats = {
        "steps": jnp.maximum(n_valid - 1, 0),
        "accepted_steps": jnp.maximum(n_valid - 1, 0),
        # a step retried on substeps counts as one rejection (the uniform mesh's retries)
        "rejected_steps": jnp.sum(infos.level > 0),
        "step_size": h,
        "newton_iterations": jnp.sum(infos.newton_iterations),
        "max_newton_iterations": jnp.max(infos.newton_iterations),
        "subdivided_steps": jnp.sum(infos.level > 0),
        "max_subdivision_level": jnp.max(infos.level),
    }
    return Solution(
        ts=ts,
        ys=mask_after_stop(ys, valid),
        valid=valid,
        status=final.status,
        t_stop=t_stop,
        stats=stats,
        diagnostics=diagnostics,
        method="alpha",
    )


class UniformMesh(AbstractIntegrator):
    """The α-method on a uniform mesh of ``n_steps`` steps (the paper's) as an integrator.

    :meth:`integrate` is :func:`integrate_alpha`: output at the n_steps + 1 mesh points
    (``ts`` must be None: the mesh has no dense output of its own). :meth:`observe` runs the
    same steps and shows each to an observer (a sweep lane's statistics over the mesh points).

    Attributes:
        method: the :class:`AlphaMethod`.
        n_steps: steps on [t0, t_final] (static).
        dt: the requested step, recorded in :meth:`settings` (the mesh's step is
            (t_final − t0)/n_steps).
        checkpoint_every: see :func:`integrate_alpha` (static).
    """

    dense_output: ClassVar[bool] = False
    method: AlphaMethod = AlphaMethod()
    n_steps: int = eqx.field(static=True, default=246)
    dt: float | None = eqx.field(static=True, default=None)
    checkpoint_every: int | str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if isinstance(self.n_steps, bool) or not isinstance(self.n_steps, int) or self.n_steps < 1:
            raise ValueError(f"n_steps must be a positive integer, got {self.n_steps!r}")
        _checkpoint_chunk(self.checkpoint_every, self.n_steps)

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.method.carried_log

    def integrate(self, ode, y0, t0, t_final, ts=None) -> Solution:
        if ts is not None:
            raise ValueError("the uniform mesh outputs its own points: ts must be None (error control has dense output)")
        return integrate_alpha(ode, self.method, y0, t0, t_final, self.n_steps, checkpoint_every=self.checkpoint_every)

    def observe(self, ode, y0, t0, t_final, observer) -> ObservedRun:
        """The scan of :func:`integrate_alpha` (forward only), each step shown to ``observer``.

        A step the safeguard subdivided is shown whole (its ends); after a stop the steps
        are shown with ``advance`` False.
        """
        t0 = jnp.asarray(t0, float)
        h = (jnp.asarray(t_final, float) - t0) / self.n_steps
        ode, state = alpha_start(ode, self.method, jnp.asarray(y0, float))
        start_ok = state.status == 0
        zero = jnp.asarray(0, jnp.int32)

        def body(carry, index):
            state, record, t_last, accepted, newton, subdivided, level = carry
            new, info, ok = alpha_advance(ode, self.method, state, h)
            t1 = t0 + h * (index + 1)
            step = AcceptedStep(
                t0=t1 - h, t1=t1, h=h, y0=state.y, y1=new.y, J1=new.J, iterations=info.newton_iterations, advance=ok,
                interpolant=HermiteInterpolant(t1 - h, h, state.y, state.psi, new.y, new.psi),
            )  # fmt: skip
            carry = (
                new, observer.update(record, step, "lax"), jnp.where(ok, t1, t_last), accepted + ok,
                newton + info.newton_iterations, subdivided + (info.level > 0), jnp.maximum(level, info.level),
            )  # fmt: skip
            return carry, None

        init = (state, observer.init(t0, state.y, state.J, start_ok), t0, zero, zero, zero, zero)
        steps = jnp.arange(self.n_steps, dtype=jnp.int32)
        (final, record, t_last, accepted, newton, subdivided, level), _ = jax.lax.scan(body, init, steps)
        return ObservedRun(
            record=record,
            status=final.status,
            t_stop=t_last,
            y_final=jnp.where(start_ok, to_physical(self.method, final.y), jnp.nan),
            accepted_steps=accepted,
            rejected_steps=zero,  # a subdivided step is counted by subdivided_steps
            newton_iterations=newton,
            subdivided_steps=subdivided,
            max_subdivision_level=level,
        )

    def settings(self) -> dict:
        return {"dt": self.dt, "n_steps": self.n_steps, "solver": self.method.settings()}
