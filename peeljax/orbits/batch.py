"""Many orbits in one compiled call: a lane per pull velocity, the lanes over every device.

Each lane shoots one orbit from its own start on the section, with its own number of slips
per period (k is traced: :mod:`peeljax.orbits.period`), by the program a single orbit runs
(:func:`peeljax.orbits.shoot`). As a sweep does (:mod:`peeljax._devices`), the lanes are dealt
to the devices (on a CPU one per core), each device running its share one lane after another
under ``shard_map`` (a ``vmap``ped while loop would run every lane until the slowest is done).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._devices import batch_mesh, deal, over_devices, put_lanes, to_host
from .._validation import check_positive, check_tolerance
from ..model import PeelingModel
from .api import PERIODS_PER_RUN, UNKNOWN_PERIOD_BOUND, DEFAULT_ORBIT_RTOL, check_iterations, orbit_of, orbit_shooting
from .orbit import PeriodicOrbit

__all__ = ["periodic_orbits"]


@eqx.filter_jit
def _lanes(shooting, model, V, start, slips, t_max, mesh):
    def lanes(shooting, model, V, start, slips, t_max):
        return jax.lax.map(lambda lane: orbit_of(shooting, model, *lane), (V, start, slips, t_max))

    return over_devices(lanes, mesh, (shooting, model), (V, start, slips, t_max))


def periodic_orbits(
    model: PeelingModel | None = None,
    V: ArrayLike = (1.1,),
    start: ArrayLike = ((0.3, 16.0),),
    slips: ArrayLike = 8,
    period: ArrayLike | None = None,
    *,
    rtol: float = DEFAULT_ORBIT_RTOL,
    atol: float | None = None,
    max_iterations: int = 20,
    devices=None,
) -> PeriodicOrbit:
    """The periodic orbits at many V at once, each from its own start (module docstring).

    Args:
        model: the model (default: the paper's), shared by every lane.
        V: the lanes' pull velocities [m/s], > 0, shape (n,).
        start: each lane's start on the section, (α, ω) — shape (n, 2) — or states (α, ω, u, v),
            shape (n, 4), whose α and ω are taken (e.g. the section points of orbits found before).
        slips: k per lane, a positive integer or (n,) of them.
        period: a guess of each lane's T [s] (bounds its runs at 3T; default 5 s), a number or (n,).
        rtol, atol, max_iterations: as :func:`peeljax.periodic_orbit`.
        devices: the devices to deal the lanes to (default: every device JAX sees).

    Returns:
        A :class:`PeriodicOrbit` whose fields have a leading lane axis; each lane's ``status``
        says whether it converged (never NaN).
    """
    model = PeelingModel() if model is None else model
    V = np.atleast_1d(np.asarray(V, float))
    if V.ndim != 1 or V.size == 0:
        raise ValueError(f"V must be a 1-d array of pull velocities, got shape {V.shape}")
    check_positive("V", V)
    start = np.asarray(start, float)
    if start.ndim != 2 or start.shape[0] != V.size or start.shape[1] not in (2, 4) or not np.all(np.isfinite(start)):
        raise ValueError(f"start must be finite, of shape ({V.size}, 2) or ({V.size}, 4) (one per V), got {start.shape}")
    slips = np.broadcast_to(np.asarray(slips), V.shape)
    if not np.issubdtype(slips.dtype, np.integer) or np.any(slips < 1):
        raise ValueError(f"slips must be positive integers (one per V, or one for all), got {slips!r}")
    t_max = (
        np.full(V.shape, UNKNOWN_PERIOD_BOUND)
        if period is None
        else PERIODS_PER_RUN * np.broadcast_to(np.asarray(period, float), V.shape)
    )
    if period is not None:
        check_positive("period", t_max)
    check_tolerance("rtol", rtol, upper=1.0)
    check_iterations(max_iterations)
    shooting = orbit_shooting(rtol=rtol, atol=atol, max_iterations=max_iterations)
    devices = jax.devices() if devices is None else list(devices)
    n, n_devices = V.size, len(devices)
    padded = -(-n // n_devices) * n_devices
    order = deal(np.concatenate([np.arange(n), np.full(padded - n, n - 1)]), n_devices)
    lanes = [V[order], start[order, :2], slips[order].astype(np.int32), t_max[order]]
    mesh = batch_mesh(devices)
    arrays = put_lanes(lanes, devices) if mesh is not None else [jnp.asarray(a) for a in lanes]
    out = to_host(_lanes(shooting, model, *arrays, mesh=mesh))
    back = np.empty(padded, int)
    back[order] = np.arange(padded)
    first = back[:n]
    return jax.tree_util.tree_map(lambda a: a[first] if np.ndim(a) and np.shape(a)[0] == padded else a, out)
