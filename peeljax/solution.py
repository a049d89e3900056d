"""The result of a run: times, states, why and where it stopped, statistics, diagnostics."""

from __future__ import annotations

import enum

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

__all__ = ["Solution", "StopReason", "StepDiagnostics"]


class StopReason(enum.IntEnum):
    """Why a run ended. ``COMPLETED`` is the only success."""

    COMPLETED = 0
    NEWTON_FAILED = 1
    IMPASSE = 2
    NONFINITE = 3
    STALLED = 4
    MAX_STEPS = 5
    SOLVER_FAILED = 6

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
        "the step size collapsed below dtmin (the solution cannot be continued: typically an impasse "
        "point, where J_t -> 0 and dv/dt blows up)"
    ),
    StopReason.MAX_STEPS: "max_steps step attempts were used up before t_final",
    StopReason.SOLVER_FAILED: "the reference solver failed (diffrax reported an error)",
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


class Solution(eqx.Module):
    """A trajectory y = (α, ω, u, v) on a time grid with the reason it ended.

    States after ``t_stop`` are masked with NaN (``valid`` is False there): they are never
    computed values. Under ``vmap`` every field gains a leading batch axis.

    Attributes:
        ts: output times, ``ts[0] = t0``.
        ys: states, shape ``(len(ts), 4)``, NaN where not ``valid``.
        valid: True where ``ys`` holds a computed state.
        status: a :class:`StopReason` code (0 = completed).
        t_stop: the last time reached (``ts[-1]`` when completed).
        stats: run statistics (Newton iterations, safeguards fired, steps, …).
        diagnostics: per-time-point :class:`StepDiagnostics`.
    """

    ts: Float[Array, " n"]
    ys: Float[Array, "n 4"]
    valid: Bool[Array, " n"]
    status: Int[Array, ""]
    t_stop: Float[Array, ""]
    stats: dict[str, Array]
    diagnostics: StepDiagnostics | None
    method: str = eqx.field(static=True, default="alpha")

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

    def summary(self) -> dict:
        """Host-side summary of a single trajectory (the CLI's ``--json`` fields)."""
        if np.ndim(self.status) != 0:
            raise ValueError("summary() is for a single trajectory; index the batch first")
        v = np.asarray(self.v)[np.asarray(self.valid)]
        last = int(np.flatnonzero(np.asarray(self.valid))[-1])
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


def _to_python(value):
    array = np.asarray(value)
    return array.item() if array.ndim == 0 else array.tolist()


def mask_after_stop(ys: Array, valid: Array) -> Array:
    """NaN where not valid; the where keeps gradients of the valid part finite."""
    return jnp.where(valid[:, None], ys, jnp.nan)
