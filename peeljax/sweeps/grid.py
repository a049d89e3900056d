"""The trajectories of a sweep: inputs checked and flattened to one entry per lane."""

from __future__ import annotations

import numpy as np

from . import engine

__all__ = ["axis", "check_parameter", "check_window", "trajectories"]


def axis(name: str, values) -> np.ndarray:
    try:
        array = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or a 1-D sequence of numbers, got {values!r}") from None
    if np.ndim(values) > 1:
        raise ValueError(f"{name} must be a number or a 1-D sequence, got shape {np.shape(values)}")
    if array.size == 0:
        raise ValueError(f"{name} is empty: give at least one value (allowed range: (0, inf))")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array[~np.isfinite(array)][:3].tolist()}")
    return array


def check_parameter(name: str, array: np.ndarray) -> None:
    positive = {"R", "I", "k", "l", "V", "c4"}
    if name in positive and np.any(array <= 0):
        raise ValueError(f"{name} must be > 0 (allowed range: (0, inf)), got {array[array <= 0][:3].tolist()}")
    if name == "tau":
        if np.any(array < 0):
            raise ValueError(f"tau must be >= 0 (allowed range: [0, inf)), got {array[array < 0][:3].tolist()}")
        if np.any(array == 0) and np.any(array > 0):
            raise ValueError(
                "tau = 0 (the DAE itself) and tau > 0 (the homogenized ODE) are different problems: "
                "sweep them separately"
            )


def trajectories(V, tau, params: dict, grid: str):
    """Flatten the inputs to one entry per trajectory; returns (V, tau, params, grid_shape)."""
    axes = {"V": axis("V", V), "tau": axis("tau", tau)}
    for name, values in params.items():
        if name not in engine.MODEL_PARAMETERS:
            raise ValueError(f"unknown model parameter {name!r}; sweepable: {', '.join(engine.MODEL_PARAMETERS)}")
        axes[name] = axis(name, values)
    for name, array in axes.items():
        check_parameter(name, array)
    if grid == "outer":
        shape = tuple(a.size for a in axes.values())
        mesh = np.meshgrid(*axes.values(), indexing="ij")
        flat = {name: m.reshape(-1) for name, m in zip(axes, mesh)}
        return flat["V"], flat["tau"], {n: flat[n] for n in params}, shape
    lengths = {name: a.size for name, a in axes.items()}
    n = max(lengths.values())
    bad = {name: size for name, size in lengths.items() if size not in (1, n)}
    if bad:
        raise ValueError(f"grid='pairs' needs equal lengths (or length 1): got {lengths}")
    flat = {name: np.broadcast_to(a, (n,)).copy() for name, a in axes.items()}
    return flat["V"], flat["tau"], {n_: flat[n_] for n_ in params}, None


def check_window(window) -> tuple[float, float]:
    try:
        w0, w1 = (float(w) for w in window)
    except (TypeError, ValueError):
        raise ValueError(f"window must be two numbers (w0, w1) with 0 <= w0 <= w1 <= 1, got {window!r}") from None
    if not (0.0 <= w0 <= w1 <= 1.0):
        raise ValueError(f"window must satisfy 0 <= w0 <= w1 <= 1 (fractions of t_final), got {window!r}")
    return w0, w1
