"""Which integrator a sweep runs on every lane: the uniform mesh or error control.

:func:`integrator_for` checks the options as :func:`peeljax.simulate` does (``dt`` given: the
uniform mesh; else error control) and returns a small description that knows its settings
(recorded in the sweep's metadata, compared on resume), its save times and how to run a
chunk (:mod:`peeljax.sweeps.engine`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._validation import check_mesh, check_positive
from ..integrators.controller import PIController
from ..integrators.dense import output_times
from ..simulate import check_error_control, refuse_with_dt
from . import engine

__all__ = ["ErrorControl", "UniformMesh", "integrator_for"]


@dataclasses.dataclass(frozen=True)
class UniformMesh:
    """Every lane on the same mesh of ``n_steps`` steps (:func:`engine.run_batch`)."""

    dt: float
    n_steps: int
    save_every: int | None

    def settings(self) -> dict:
        return {"dt": float(self.dt), "n_steps": self.n_steps, "save_every": self.save_every}

    def save_times(self, t_final: float) -> np.ndarray | None:
        if self.save_every is None:
            return None
        return float(t_final) / self.n_steps * self.save_every * np.arange(self.n_steps // self.save_every + 1)

    def run(self, model, solver, V, tau, params, t_final, window, truncation, mesh, lane_batch):
        return engine.run_batch(
            model, solver, V, tau, params, t_final, window, self.n_steps, self.save_every, truncation, mesh
        )


@dataclasses.dataclass(frozen=True)
class ErrorControl:
    """Each lane with its own step size (:func:`engine.run_batch_adaptive`)."""

    rtol: float
    atol: float
    save_dt: float | None
    dtmin: float | None
    max_steps: int
    t_final: float

    def settings(self) -> dict:
        return {
            "method": "alpha-adaptive",
            "rtol": self.rtol,
            "atol": self.atol,
            "save_dt": self.save_dt,
            "dtmin": self.dtmin,
            "max_steps": self.max_steps,
        }

    def save_times(self, t_final: float) -> np.ndarray | None:
        return None if self.save_dt is None else output_times(self.save_dt, float(t_final))

    def run(self, model, solver, V, tau, params, t_final, window, truncation, mesh, lane_batch):
        save_ts = self.save_times(self.t_final)
        dtmin = 1e-12 * self.t_final if self.dtmin is None else self.dtmin
        return engine.run_batch_adaptive(
            model, solver, PIController(rtol=self.rtol, atol=self.atol), V, tau, params, t_final, window,
            None if save_ts is None else jnp.asarray(save_ts), jnp.asarray(dtmin), self.max_steps, truncation,
            lane_batch, mesh,
        )  # fmt: skip


def integrator_for(dt, t_final, rtol, atol, save_dt, save_every, dtmin, max_steps) -> UniformMesh | ErrorControl:
    """Check the integrator's options (uniform mesh when ``dt`` is given, else error control)."""
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol, save_dt=save_dt, dtmin=dtmin)
        n_steps = check_mesh(dt, t_final)
        if save_every is not None and (
            isinstance(save_every, bool) or not isinstance(save_every, int) or not 1 <= save_every <= n_steps
        ):
            raise ValueError(
                f"save_every must be an integer in [1, {n_steps}] (the number of steps), got {save_every!r}"
            )
        return UniformMesh(float(dt), n_steps, save_every)
    if save_every is not None:
        raise ValueError("save_every counts uniform-mesh steps (dt given); with error control save on times: save_dt")
    rtol, atol = check_error_control(t_final, rtol, atol, dtmin, max_steps)
    if save_dt is not None:
        check_positive("save_dt", save_dt)
        if float(save_dt) > float(t_final):
            raise ValueError(f"save_dt must lie in (0, t_final] = (0, {float(t_final):g}], got {save_dt!r}")
    return ErrorControl(
        rtol, atol, None if save_dt is None else float(save_dt),
        None if dtmin is None else float(dtmin), int(max_steps), float(t_final),
    )  # fmt: skip
