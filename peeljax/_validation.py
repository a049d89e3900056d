"""Checks of user input, run in plain Python before anything is traced or compiled.

Traced values (inside ``jit``/``vmap``/``grad``) cannot be inspected and are passed through.
"""

from __future__ import annotations

import math

import jax
import numpy as np

__all__ = [
    "check_choice",
    "check_max_steps",
    "check_mesh",
    "check_output_times",
    "check_positive",
    "check_rho",
    "check_tau",
    "check_tolerance",
    "check_y0",
    "is_concrete",
]


def is_concrete(value) -> bool:
    return not isinstance(value, jax.core.Tracer)


def _shown(value):
    """A value for an error message: a plain number for a 0-d array."""
    return float(value) if isinstance(value, (np.ndarray, np.generic)) and np.ndim(value) == 0 else value


def _finite_array(name: str, value, allowed: str | None = None) -> np.ndarray:
    """``value`` as a float array, refused where it is no number or not finite (naming the ``allowed`` range)."""
    within = "" if allowed is None else f" (allowed range: {allowed})"
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number{within}, got {_shown(value)!r}") from None
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite{within}, got {_shown(value)!r}")
    return array


def _plain_positive(value) -> bool:
    """A fast yes for the common case, a Python or 0-d NumPy number that is finite and > 0."""
    if type(value) is float or type(value) is int or (isinstance(value, np.ndarray) and value.shape == ()):
        number = float(value)
        return math.isfinite(number) and number > 0
    return False


def check_positive(name: str, value) -> None:
    """``name`` must be finite and > 0 (every entry, if an array)."""
    if _plain_positive(value) or not is_concrete(value):
        return
    array = _finite_array(name, value, "(0, inf)")
    if np.any(array <= 0):
        raise ValueError(f"{name} must be > 0 (allowed range: (0, inf)), got {_shown(value)!r}")


TAU_MAX = 1e6  # s


def check_tau(tau, allow_zero: bool = False) -> None:
    """τ ∈ (0, 1e6] s, or [0, 1e6] with ``allow_zero`` (τ = 0: the DAE itself). Beyond 1e6 s the
    homogenized v is frozen (dv/dt ∝ 1/τ: at τ = 1e10 s v moves from 1.1e-10 to 4.4e-10 m/s in
    3 s), and from τ ≈ 1e150 J_t overflows."""
    if not is_concrete(tau):
        return
    low = "[0" if allow_zero else "(0"
    array = _finite_array("tau", tau, f"{low}, {TAU_MAX:g}]")
    if np.any(array < 0) or (not allow_zero and np.any(array == 0)):
        relation = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"tau must be {relation} (allowed range: {low}, {TAU_MAX:g}]), got {_shown(tau)!r}")
    if np.any(array > TAU_MAX):
        raise ValueError(
            f"tau must be <= {TAU_MAX:g} s (allowed range: {low}, {TAU_MAX:g}]): beyond it the homogenized v "
            f"does not move (dv/dt is proportional to 1/tau), got {_shown(tau)!r}"
        )


def check_rho(rho) -> None:
    """ρ ∈ [0, 1)."""
    if not is_concrete(rho):
        return
    array = _finite_array("rho", rho, "[0, 1)")
    if np.any((array < 0) | (array >= 1)):
        raise ValueError(f"rho must lie in [0, 1), got {_shown(rho)!r}")


def check_mesh(dt, t_final) -> int:
    """dt and t_final (Python numbers: they set the mesh's shape); returns N = round(t_final/dt) ≥ 1."""
    for name, value in (("dt", dt), ("t_final", t_final)):
        if not is_concrete(value) or np.ndim(value) != 0:
            raise ValueError(f"{name} sets the number of steps and must be a concrete scalar, got {_shown(value)!r}")
        check_positive(name, value)
    dt, t_final = float(dt), float(t_final)
    if dt > t_final:
        raise ValueError(f"dt must be <= t_final (allowed range: (0, {t_final}]), got dt={dt}")
    ratio = t_final / dt  # inf for a subnormal dt: no integer count (round(inf) raises OverflowError)
    n_steps = max(1, round(ratio)) if math.isfinite(ratio) else math.inf
    if n_steps > 100_000_000:
        raise ValueError(
            f"dt={dt} gives {n_steps} steps over t_final={t_final}; the limit is 1e8 steps (allowed range: "
            f"[{t_final / 1e8:.3g}, {t_final:g}])"
        )
    return n_steps


def check_tolerance(name: str, value, upper: float = math.inf) -> None:
    """A tolerance in (0, upper): a finite Python or numpy number (it is not traced)."""
    if not is_concrete(value) or np.ndim(value) != 0:
        raise ValueError(f"{name} must be a number in (0, {upper:g}), got {_shown(value)!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in (0, {upper:g}), got {_shown(value)!r}") from None
    if not (0.0 < number < upper):  # also refuses NaN
        raise ValueError(f"{name} must lie in (0, {upper:g}), got {_shown(value)!r}")


ADJOINTS = ("reverse", "checkpointed", "forward")


def check_adjoint(adjoint) -> None:
    """How a loop is differentiated: "reverse" (jax.grad: tangents of a few perturbed inputs,
    else the checkpointed loop), "checkpointed" (jax.grad, always the checkpointed loop) or
    "forward" (jax.jvp)."""
    if adjoint not in ADJOINTS:
        raise ValueError(f"adjoint must be one of {', '.join(map(repr, ADJOINTS))}, got {adjoint!r}")


MAX_STEPS_LIMIT = 2**31 - 1  # the loop counts attempts in int32


def check_max_steps(max_steps) -> None:
    if (
        isinstance(max_steps, bool)
        or not isinstance(max_steps, (int, np.integer))
        or not 1 <= max_steps <= MAX_STEPS_LIMIT
    ):
        raise ValueError(f"max_steps must be a positive integer (allowed range: [1, {MAX_STEPS_LIMIT}]), got {max_steps!r}")


def check_output_times(ts, t_final) -> np.ndarray:
    """Output times: a non-empty 1-D array, finite, non-decreasing, within [0, t_final]."""
    if not is_concrete(ts):
        raise ValueError("ts sets the output's shape and must be a concrete array, not a traced value")
    array = _finite_array("ts", ts)
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"ts must be a non-empty 1-D array of times, got shape {array.shape}")
    if np.any(np.diff(array) < 0):
        raise ValueError("ts must be non-decreasing")
    if array[0] < 0 or array[-1] > float(t_final):
        raise ValueError(f"ts must lie in [0, t_final] = [0, {float(t_final):g}], got [{array[0]:g}, {array[-1]:g}]")
    return array


def check_y0(y0) -> None:
    """y0 = (α, ω, u, v): four finite numbers with v > 0 (φ is defined for v > 0)."""
    if y0 is None or not is_concrete(y0):
        return
    array = _finite_array("y0", y0, "four finite numbers (alpha, omega, u, v) with v > 0")
    if array.shape[-1:] != (4,):
        raise ValueError(f"y0 must hold four numbers (alpha, omega, u, v) with v > 0, got shape {array.shape}")
    if np.any(array[..., 3] <= 0):
        raise ValueError(f"y0: the peeling velocity v must be > 0 (allowed range: (0, inf)), got {array[..., 3]}")


def check_choice(name: str, value, allowed) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(str, allowed))}; got {_shown(value)!r}")


def check_truncation(truncation) -> None:
    if truncation is None:
        return
    if isinstance(truncation, bool) or not isinstance(truncation, int) or truncation < 0:
        raise ValueError(f"truncation must be None or an integer >= 0, got {truncation!r}")


