"""The model's statistics at a table's pull velocities as the fit predicts them, and synthetic
tables made of them (hidden-truth exercises, coverage benchmarks, the docs' examples).

:func:`model_statistics` runs the model exactly as :func:`~peeljax.fit.fit_stick_slip` does
with its ``method``; :func:`synthetic_table` adds noise to those statistics and gives a
:class:`~peeljax.fit.StickSlipTable` with its standard deviations.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..adhesion import AdhesionLaw
from ..model import PeelingModel
from ..measurements.statistics import STATISTICS
from ..measurements.stick_slip_table import StickSlipTable
from .table import TableFit, attractor_statistics, build_table_fit

__all__ = ["model_statistics", "synthetic_table"]


@eqx.filter_jit
def _statistics(fit: TableFit, theta):
    return fit.statistics(theta)


def model_statistics(law: AdhesionLaw, V, *, model: PeelingModel | None = None, method: str = "orbit", tau: float = 0.0,
                     transient: float = 0.5, window: float = 1.0, n_samples: int = 401, rtol: float = 1e-7,
                     atol: float = 1e-10, max_jumps: int = 4096, max_steps: int = 400_000,
                     taper: float | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:  # fmt: skip
    """The model's stick-slip statistics at the pull velocities ``V`` (a sequence, or a
    :class:`~peeljax.fit.StickSlipTable`), as :func:`~peeljax.fit.table.fit_stick_slip`
    predicts them with φ = ``law`` and its ``method``: ``"orbit"`` (default: each row on its
    attractor — steady peeling's φ(V, V), the periodic orbit's statistics over one period, or the
    tapered window statistics where there is no periodic attractor;
    :func:`peeljax.fit.table.attractor_statistics`) or ``"window"`` (the statistics over
    ``[transient, transient + window]`` of a run from the paper's start).

    Returns:
        ({statistic: (n,) values, NaN where the model does not produce it}, the (n, 2) range of
        v visited in each row).
    """
    V = np.asarray(V.V if isinstance(V, StickSlipTable) else V, float).reshape(-1)
    model = PeelingModel() if model is None else model
    if method == "orbit":
        window_options = {"transient": transient, "window": window, "n_samples": n_samples, "max_jumps": max_jumps,
                          "max_steps": max_steps, "taper": 0.25 if taper is None else taper}  # fmt: skip
        point, _, _ = attractor_statistics(law, V, model=model, window_fit_options=window_options)
        values = np.where(point.available, point.values, np.nan)
        return {s: values[:, j] for j, s in enumerate(STATISTICS)}, point.v_range
    if method != "window":
        raise ValueError(f"method must be 'orbit' or 'window', got {method!r}")
    shape = (V.size, len(STATISTICS))
    fit = build_table_fit(
        law, model, V, np.zeros(shape), np.ones(shape), np.ones(shape, bool), names=("c1",), tau=tau,
        transient=transient, window=window, n_samples=n_samples, rtol=rtol, atol=atol, max_jumps=max_jumps,
        max_steps=max_steps, taper=0.0 if taper is None else taper,
    )  # fmt: skip
    values, available, v_range = _statistics(fit, {"c1": jnp.zeros(())})
    values = np.where(np.asarray(available), np.asarray(values, float), np.nan)
    return {s: values[:, j] for j, s in enumerate(STATISTICS)}, np.asarray(v_range, float)


def synthetic_table(law: AdhesionLaw, V, *, noise: float = 0.01, seed: int = 0, **settings) -> StickSlipTable:
    """A stick-slip table made by the model with φ = ``law`` at the pull velocities ``V``: each
    statistic of :func:`model_statistics` (``settings`` are its options) times 1 + noise·N(0, 1)
    (``seed``), with standard deviations noise·|value| — for hidden-truth exercises."""
    stats, _ = model_statistics(law, V, **settings)
    rng = np.random.default_rng(seed)
    columns = {}
    for name in STATISTICS:
        exact = np.asarray(stats[name])
        columns[name] = exact * (1 + noise * rng.normal(size=exact.shape))
        columns[f"{name}_std"] = noise * np.abs(exact)
    return StickSlipTable.from_dict(V=np.asarray(V, float), **columns)
