"""Which integrator a sweep runs on every lane, and which states it keeps.

:func:`sweep_plan` checks the options as :func:`peeljax.simulate` does (one place:
:func:`peeljax.integrators.integrator_for`) and adds the sweep's own: the saved states
(``save_every`` mesh steps on the uniform mesh, ``save_dt`` seconds otherwise). The
:class:`SweepPlan` knows its settings (recorded in the sweep's metadata, compared on resume),
its save times and how to run a chunk (:func:`peeljax.sweeps.engine.run_batch`, the same
engine for every integrator).
"""

from __future__ import annotations

import dataclasses

import diffrax
import jax.numpy as jnp
import numpy as np

from .._validation import check_choice, check_positive
from ..integrators.uniform_mesh import UniformMesh
from ..integrators.base import AbstractIntegrator
from ..integrators.dense import output_count, output_times
from ..integrators.observers import DenseOutput, EveryNthPoint, Observer
from ..integrators.reference import DiffraxIntegrator
from ..integrators.steppers import RungeKutta
from ..integrators.select import integrator_for, refuse_with_dt, resolve_max_steps
from . import engine

__all__ = ["DEFAULT_SWEEP_MAX_JUMPS", "SweepPlan", "sweep_plan"]

# Each lane keeps its last 64 jumps (a ring buffer, 5 values a slot; the window's cycle statistics
# are accumulated in the loop): the forces of two full repeats of 16 stick → slip events.
DEFAULT_SWEEP_MAX_JUMPS = 64


@dataclasses.dataclass(frozen=True)
class SweepPlan:
    """The integrator of every lane and the states kept: ``save_every`` steps or ``save_dt`` seconds."""

    integrator: AbstractIntegrator
    t_final: float
    save_every: int | None = None
    save_dt: float | None = None
    dae: bool = False  # τ = 0: the DAE itself on every lane
    start: str = "paper"

    @property
    def max_jumps(self) -> int | None:
        """Slots of each lane's jump record; None where no fold is located (the uniform mesh, a
        diffrax solver, and ``fold="stop"`` at τ > 0: the paper's impasse stop)."""
        events = getattr(self.integrator, "events", None)
        if events is None or (events.mode == "stop" and not self.dae):
            return None
        return events.max_jumps

    @property
    def uniform(self) -> bool:
        return isinstance(self.integrator, UniformMesh)

    def settings(self) -> dict:
        """The integrator's settings and the saving (JSON-able; compared when a sweep resumes)."""
        settings = {**self.integrator.settings(), "dae": self.dae, "start": self.start}
        if self.uniform:
            return {**settings, "save_every": self.save_every}
        return {**settings, "save_dt": self.save_dt}

    def save_count(self) -> int:
        """How many states each lane keeps (``save_times().size``, 0 for none), without making them."""
        if self.uniform:
            return 0 if self.save_every is None else self.integrator.n_steps // self.save_every + 1
        return 0 if self.save_dt is None else output_count(self.save_dt, self.t_final)

    def save_times(self) -> np.ndarray | None:
        if self.uniform:
            if self.save_every is None:
                return None
            n_steps = self.integrator.n_steps
            return self.t_final / n_steps * self.save_every * np.arange(n_steps // self.save_every + 1)
        return None if self.save_dt is None else output_times(self.save_dt, self.t_final)

    def save_observer(self) -> Observer | None:
        """What keeps the saved states: every ``save_every``-th mesh point, or the dense output at the save times."""
        if self.uniform:
            if self.save_every is None:
                return None
            return EveryNthPoint(self.save_every, self.integrator.n_steps // self.save_every + 1)
        save_ts = self.save_times()
        return None if save_ts is None else DenseOutput(jnp.asarray(save_ts))

    def run(self, model, V, tau, params, t_final, window, truncation, mesh, lane_batch, given=None) -> engine.BatchSummary:
        if self.uniform:
            lane_batch = V.shape[0]  # every lane takes the same steps: one vmap
        method = getattr(self.integrator, "method", None)
        implicit_rk = isinstance(method, RungeKutta) and isinstance(method.solver, diffrax.AbstractImplicitSolver)
        if isinstance(self.integrator, DiffraxIntegrator) or implicit_rk:
            # diffrax's implicit solvers fail to trace under shard_map (lineax's structure
            # check); without the mesh, XLA partitions the run over the sharded lanes itself.
            mesh = None
        return engine.run_batch(
            model, self.integrator, V, tau, params, t_final, window, self.save_observer(), truncation, lane_batch, mesh,
            self.dae, self.start, given,
        )  # fmt: skip


def sweep_plan(
    solver, rho, dt, t_final, rtol, atol, save_dt, save_every, dtmin, max_steps, fold=None, max_jumps=None,
    dae=False, start="paper",
) -> SweepPlan:  # fmt: skip
    """Check the options (uniform mesh when ``dt`` is given, else error control) and plan the sweep."""
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol, save_dt=save_dt, dtmin=dtmin)
    if start != engine.GIVEN_START:  # (a sweep's start array: checked there)
        check_choice("start", start, engine.STARTS)
    # A sweep keeps nothing per step: the budget only guards against runs that never end.
    max_steps = resolve_max_steps(max_steps, keeps_steps=False)
    # A sweep differentiates nothing: the plain while loop is the fastest.
    integrator = integrator_for(
        solver, rho=rho, dt=dt, t_final=t_final, rtol=rtol, atol=atol, dtmin=dtmin, max_steps=max_steps,
        adjoint="forward", fold=fold, max_jumps=DEFAULT_SWEEP_MAX_JUMPS if max_jumps is None else max_jumps, dae=dae,
    )  # fmt: skip
    integrator = engine.keep_last_jumps(integrator)  # a lane never stops for a full record
    if isinstance(integrator, UniformMesh):
        n_steps = integrator.n_steps
        if save_every is not None and (
            isinstance(save_every, bool) or not isinstance(save_every, int) or not 1 <= save_every <= n_steps
        ):
            raise ValueError(
                f"save_every must be an integer in [1, {n_steps}] (the number of steps), got {save_every!r}"
            )
        return SweepPlan(integrator, float(t_final), save_every=save_every, start=start)
    if save_every is not None:
        raise ValueError("save_every counts uniform-mesh steps (dt given); with error control save on times: save_dt")
    if save_dt is not None:
        check_positive("save_dt", save_dt)
        if float(save_dt) > float(t_final):
            raise ValueError(f"save_dt must lie in (0, t_final] = (0, {float(t_final):g}], got {save_dt!r}")
    return SweepPlan(
        integrator, float(t_final), save_dt=None if save_dt is None else float(save_dt), dae=dae, start=start
    )
