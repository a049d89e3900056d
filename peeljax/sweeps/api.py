"""``peeljax.sweep``: many (V, τ[, model parameter]) trajectories, batched, chunked, resumable."""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Int

from .._validation import check_choice, check_mesh, check_positive, check_truncation
from ..adhesion import AdhesionLaw
from ..integrators.alpha import AlphaMethod
from ..integrators.controller import PIController
from ..integrators.dense import output_times
from ..model import PeelingModel
from ..simulate import DEFAULT_MAX_STEPS, check_error_control, checked_solver, refuse_with_dt
from ..solution import StopReason
from . import engine
from .storage import ChunkStore

__all__ = ["PER_TRAJECTORY_KEYS", "SweepResult", "sweep", "sweep_settings"]

PER_TRAJECTORY_KEYS: tuple[str, ...] = (
    "V",
    "tau",
    "completed",
    "status",
    "t_stop",
    "v_mean",
    "v_std",
    "v_min",
    "v_max",
    "v_final",
    "events",
    "v_slip",
    "window_count",
    "newton_iterations",
    "subdivided_steps",
    "max_subdivision_level",
    "accepted_steps",
    "rejected_steps",
)
_SUMMARY_FIELDS = PER_TRAJECTORY_KEYS[3:]
_BYTES_PER_TRAJECTORY = 8 * len(PER_TRAJECTORY_KEYS)


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """Per-trajectory summaries of a sweep (NumPy arrays, leading axis: the n trajectories).

    Attributes:
        V, tau: the pull velocity and τ of each trajectory, shape (n,).
        params: other model parameters swept (name → (n,) array; empty if none).
        completed, status: reached t_final / the :class:`StopReason` code.
        t_stop: time of the last accepted state.
        v_mean, v_std, v_min, v_max: v over the window ``window`` (NaN if the run never
            reached it). Error control: time averages, (1/T)∫v dt and the root of
            (1/T)∫(v − v_mean)² dt over the covered part of the window (T = window_time), and
            the extremes of the dense output; uniform mesh: the mean and population standard
            deviation of the accepted mesh points in the window (see
            :mod:`peeljax.sweeps.engine`).
        v_final: v at t_stop. window_count: accepted step points in the window.
        window_time: the part of the window the run covered, [w0·t_final, min(w1·t_final, t_stop)].
        events: stick-slip events in the window (upward crossings of v_slip).
        v_slip: v at the maximum of φ(·, V) (inf if φ has none).
        newton_iterations, accepted_steps, rejected_steps: the work done (the uniform mesh
            rejects nothing); subdivided_steps, max_subdivision_level: the uniform mesh's
            safeguard (0 with error control).
        ts, ys: save times (S,) and states (n, S, 4) = (α, ω, u, v), NaN after a stop;
            None unless ``save_dt`` (error control) or ``save_every`` (uniform mesh) was given.
        grid_shape: (len(V), len(tau), len(p1), …) for ``grid="outer"``, else None.
        settings: everything that determined the result (JSON-able).
        computed_chunks: the chunks this call computed (the others were loaded from ``out``).
    """

    V: Float[np.ndarray, " n"]
    tau: Float[np.ndarray, " n"]
    params: dict
    completed: Bool[np.ndarray, " n"]
    status: Int[np.ndarray, " n"]
    t_stop: Float[np.ndarray, " n"]
    v_mean: Float[np.ndarray, " n"]
    v_std: Float[np.ndarray, " n"]
    v_min: Float[np.ndarray, " n"]
    v_max: Float[np.ndarray, " n"]
    v_final: Float[np.ndarray, " n"]
    events: Int[np.ndarray, " n"]
    v_slip: Float[np.ndarray, " n"]
    window_count: Int[np.ndarray, " n"]
    newton_iterations: Int[np.ndarray, " n"]
    subdivided_steps: Int[np.ndarray, " n"]
    max_subdivision_level: Int[np.ndarray, " n"]
    accepted_steps: Int[np.ndarray, " n"]
    rejected_steps: Int[np.ndarray, " n"]
    window_time: Float[np.ndarray, " n"]
    ts: Float[np.ndarray, " S"] | None
    ys: Float[np.ndarray, "n S 4"] | None
    grid_shape: tuple[int, ...] | None
    settings: dict
    computed_chunks: tuple[int, ...] = ()

    def __len__(self) -> int:
        return int(self.V.shape[0])

    @property
    def reasons(self) -> list[str]:
        """The :class:`StopReason` name of each trajectory."""
        return [StopReason(int(code)).name.lower() for code in self.status]

    def grid(self, name: str) -> np.ndarray:
        """A per-trajectory array reshaped to ``grid_shape`` (outer grids only)."""
        if self.grid_shape is None:
            raise ValueError("grid() needs a sweep with grid='outer'")
        value = self.params[name] if name in self.params else getattr(self, name)
        return np.asarray(value).reshape(self.grid_shape + np.shape(value)[1:])

    def arrays(self) -> dict[str, np.ndarray]:
        """The .npz contents: the per-trajectory keys, ``param_<name>``, and ``ts``/``ys`` if saved."""
        out = {key: np.asarray(getattr(self, key)) for key in (*PER_TRAJECTORY_KEYS, "window_time")}
        out.update({f"param_{name}": np.asarray(value) for name, value in self.params.items()})
        if self.ys is not None:
            out["ts"], out["ys"] = np.asarray(self.ts), np.asarray(self.ys)
        return out


# ---------------------------------------------------------------------------- inputs
def _axis(name: str, values) -> np.ndarray:
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


def _check_parameter(name: str, array: np.ndarray) -> None:
    positive = {"R", "I", "k", "l", "V", "tau", "c4"}
    if name in positive and np.any(array <= 0):
        raise ValueError(f"{name} must be > 0 (allowed range: (0, inf)), got {array[array <= 0][:3].tolist()}")


def _trajectories(V, tau, params: dict, grid: str):
    """Flatten the inputs to one entry per trajectory; returns (V, tau, params, grid_shape)."""
    axes = {"V": _axis("V", V), "tau": _axis("tau", tau)}
    for name, values in params.items():
        if name not in engine.MODEL_PARAMETERS:
            raise ValueError(f"unknown model parameter {name!r}; sweepable: {', '.join(engine.MODEL_PARAMETERS)}")
        axes[name] = _axis(name, values)
    for name, array in axes.items():
        _check_parameter(name, array)
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


def _check_window(window) -> tuple[float, float]:
    try:
        w0, w1 = (float(w) for w in window)
    except (TypeError, ValueError):
        raise ValueError(f"window must be two numbers (w0, w1) with 0 <= w0 <= w1 <= 1, got {window!r}") from None
    if not (0.0 <= w0 <= w1 <= 1.0):
        raise ValueError(f"window must satisfy 0 <= w0 <= w1 <= 1 (fractions of t_final), got {window!r}")
    return w0, w1


def _memory_limit() -> float:
    try:
        return 0.5 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8e9


def _solver_settings(solver: AlphaMethod) -> dict:
    return {
        "rho": float(solver.rho),
        "newton_rtol": float(solver.newton_rtol),
        "newton_atol": float(solver.newton_atol),
        "max_newton_iterations": solver.max_newton_iterations,
        "max_subdivisions": solver.max_subdivisions,
        "log_components": list(solver.log_components),
        "log_discretization": solver.log_discretization,
        "max_log_change": float(solver.max_log_change),
    }


def _model_settings(model: PeelingModel) -> dict:
    adhesion = model.adhesion
    phi = adhesion.coefficients() if isinstance(adhesion, AdhesionLaw) else f"callable {type(adhesion).__qualname__}"
    return {name: float(getattr(model, name)) for name in ("R", "I", "k", "l")} | {
        "geometry": model.geometry,
        "phi": phi,
    }


def sweep_settings(model, solver, engine_run, V, tau, params, grid, t_final, window, chunk, truncation) -> dict:
    """The JSON-able settings that determine a sweep's results (compared when resuming)."""
    return {
        "V": [float(x) for x in V],
        "tau": [float(x) for x in tau],
        "params": {name: [float(x) for x in values] for name, values in params.items()},
        "grid": grid,
        **engine_run.settings(),
        "t_final": float(t_final),
        "window": list(window),
        "chunk": chunk,
        "truncation": truncation,
        "solver": _solver_settings(solver),
        "model": _model_settings(model),
    }


# ---------------------------------------------------------------------------- the two engines
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


def engine_for(dt, t_final, rtol, atol, save_dt, save_every, dtmin, max_steps) -> UniformMesh | ErrorControl:
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


def default_lane_batch(devices, chunk: int) -> int:
    """Lanes ``vmap``ped together by error control: 1 on CPUs, the whole chunk on accelerators.

    Measured (``benchmarks/sweep_throughput.py``): on a CPU a ``vmap``ped while loop runs every
    lane until the slowest is done and turns the kept-matrix ``cond`` into a select that
    computes the Jacobian at every step, so one lane at a time is fastest; a GPU's time is set
    by the number of loop iterations, not by the lanes, so it takes them all at once.
    """
    return 1 if devices[0].platform == "cpu" else max(1, chunk // len(devices))


# ---------------------------------------------------------------------------- devices
def batch_mesh(devices) -> jax.sharding.Mesh | None:
    """A 1-D mesh with axis ``"batch"`` over ``devices``; None for a single device."""
    if devices is None or len(devices) == 1:
        return None
    return jax.sharding.Mesh(np.asarray(devices), ("batch",))


def _put(arrays, devices):
    """Shard the batch axis over ``devices`` (a 1-D mesh), or leave on the default device."""
    mesh = batch_mesh(devices)
    if mesh is None:
        return jax.tree_util.tree_map(jnp.asarray, arrays)
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    # make_array_from_callback also works across hosts (jax.distributed): each process holds
    # the whole (small) input and supplies the shards of its own devices.
    return jax.tree_util.tree_map(
        lambda a: jax.make_array_from_callback(a.shape, sharding, lambda index, a=a: a[index]), arrays
    )


def _to_host(tree):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return jax.tree_util.tree_map(np.asarray, multihost_utils.process_allgather(tree, tiled=True))
    return jax.tree_util.tree_map(np.asarray, tree)


# ---------------------------------------------------------------------------- the sweep
def sweep(
    model: PeelingModel | None = None,
    V: ArrayLike = 1.1,
    tau: ArrayLike = 0.01,
    dt: float | None = None,
    t_final: float = 3.0,
    *,
    rtol: float | None = None,
    atol: float | None = None,
    save_dt: float | None = None,
    grid: str = "outer",
    params: dict[str, ArrayLike] | None = None,
    window: tuple[float, float] = (0.5, 1.0),
    save_every: int | None = None,
    chunk: int = 256,
    out: str | os.PathLike | None = None,
    progress: bool = True,
    solver: AlphaMethod | None = None,
    rho: float = 0.0,
    truncation: int | None = None,
    dtmin: float | None = None,
    max_steps: int = DEFAULT_MAX_STEPS,
    memory_limit: float | None = None,
    devices: Sequence | None = None,
    lane_batch: int | None = None,
) -> SweepResult:
    """Integrate eq. ``hv`` with (``av``)–(``str``) by the α-method for many (V, τ, …) at once.

    Each trajectory is the run :func:`peeljax.simulate` makes with the same settings: with
    ``dt=None`` (default) the error-controlled α-method, each trajectory with its own step
    sizes; with a number ``dt`` the uniform mesh, the same for every trajectory.

    Args:
        model: the base model (default: the paper's); ``params`` overrides its parameters.
        V, tau: pull velocities [m/s] and homogenization scales [s] (numbers or 1-D, all > 0).
        dt: None for error control; else the uniform mesh, N = round(t_final/dt) steps of
            t_final/N, as in :func:`peeljax.simulate`.
        t_final: end time [s], > 0.
        rtol, atol: error control only: the tolerances of :func:`peeljax.simulate`
            (default 1e-6 and 1e-9).
        save_dt: error control only: also keep the states at t = k·save_dt (and t_final), by
            the dense output; None keeps summaries only.
        grid: ``"outer"``: every combination of V × tau × params (in that order, C order);
            ``"pairs"``: the i-th entries together (equal lengths, or length 1 broadcast).
        params: other parameters to sweep, by name: R, I, k, l or a coefficient of φ
            (c1 … p9); traced like V and τ.
        window: (w0, w1), fractions of t_final: the window of the v statistics and events
            (with error control w0 < w1: its statistics are time integrals).
        save_every: uniform mesh only: also keep the states every ``save_every`` steps
            (t = 0 included).
        chunk: trajectories per compiled batch (the last chunk is padded to the same size, so
            one compilation serves the whole sweep). With several devices it is rounded up to
            a multiple of their number.
        out: a ``.npz`` path: chunks go to ``<out>.chunks/`` as they finish, the merged result
            to ``out``; a rerun with the same out and settings resumes (finished chunks are
            loaded, not recomputed) and different settings (tolerances included) are refused.
        progress: show a tqdm bar of trajectories and chunks (stderr).
        solver: an :class:`AlphaMethod` (default ``AlphaMethod(rho=rho)``).
        truncation: as in :func:`peeljax.simulate`.
        dtmin, max_steps: error control only, as in :func:`peeljax.simulate`.
        memory_limit: bytes the results may take in host memory (default: half the RAM).
        devices: the devices to shard each chunk over (default: ``jax.devices()``; on a CPU
            peeljax asks JAX for one device per core, see :mod:`peeljax`).
        lane_batch: error control only: lanes run together under ``vmap`` (groups run one
            after another); default 1 on CPUs and the whole chunk on GPUs
            (:func:`default_lane_batch`). It changes the speed, not the steps taken.

    Returns:
        A :class:`SweepResult` (see there for the summaries and :mod:`peeljax.sweeps.engine`
        for the statistics).

    Raises:
        ValueError: bad input, output that would not fit ``memory_limit``, or an ``out`` made
            with other settings; all before anything is compiled.
    """
    model = PeelingModel() if model is None else model
    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    check_choice("grid", grid, ("outer", "pairs"))
    engine_run = engine_for(dt, t_final, rtol, atol, save_dt, save_every, dtmin, max_steps)
    solver = checked_solver(solver, rho)
    check_truncation(truncation)
    params = dict(params or {})
    if not isinstance(model.adhesion, AdhesionLaw) and any(name not in ("R", "I", "k", "l") for name in params):
        raise ValueError("sweeping coefficients of φ needs model.adhesion to be an AdhesionLaw")
    window = _check_window(window)
    if isinstance(engine_run, ErrorControl) and window[0] == window[1]:
        raise ValueError(f"window must have w0 < w1 with error control (its statistics are time integrals), got {window!r}")
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if lane_batch is not None and (isinstance(lane_batch, bool) or not isinstance(lane_batch, int) or lane_batch < 1):
        raise ValueError(f"lane_batch must be a positive integer, got {lane_batch!r}")
    Vs, taus, param_values, grid_shape = _trajectories(V, tau, params, grid)
    n = Vs.size
    devices = list(jax.devices()) if devices is None else list(devices)
    devices = devices[: max(1, min(len(devices), n))]  # no device with only padding to run
    n_dev = len(devices)
    chunk = min(chunk, n)
    chunk = -(-chunk // n_dev) * n_dev  # a multiple of the device count
    lane_batch = default_lane_batch(devices, chunk) if lane_batch is None else lane_batch

    # Memory: every saved state of every trajectory is returned in host memory.
    save_ts = engine_run.save_times(t_final)
    n_save = 0 if save_ts is None else save_ts.size
    limit = _memory_limit() if memory_limit is None else float(memory_limit)
    total = n * (n_save * 4 * 8 + _BYTES_PER_TRAJECTORY)
    if total > limit:
        if isinstance(engine_run, UniformMesh):
            fewer = f"a larger save_every{'' if save_every is None else f', now {save_every}'}, or none"
        else:
            fewer = f"a larger save_dt{'' if save_dt is None else f', now {save_dt:g}'}, or none"
        raise ValueError(
            f"the sweep's output would take {total / 1e9:.3g} GB ({n} trajectories x {n_save} saved states x 4 x 8 bytes "
            f"+ summaries), more than the memory limit of {limit / 1e9:.3g} GB: save fewer states ({fewer}), sweep "
            "fewer V/tau values or a shorter t_final, or raise memory_limit"
        )

    settings = sweep_settings(
        model, solver, engine_run, _axis("V", V), _axis("tau", tau), {k: _axis(k, v) for k, v in params.items()},
        grid, t_final, window, chunk, truncation,
    )  # fmt: skip
    n_chunks = -(-n // chunk)
    sizes = [min(chunk, n - i * chunk) for i in range(n_chunks)]
    keys = tuple(_SUMMARY_FIELDS) + (("ys",) if save_ts is not None else ())
    store = None
    chunks: list[dict | None] = [None] * n_chunks
    if out is not None:
        store = ChunkStore(out, settings, n_chunks, sizes, keys)
        merged = store.finished_output()
        if merged is not None:
            return _result(merged, Vs, taus, param_values, save_ts, t_final, window, grid_shape, settings, ())
        store.open()
        chunks = [store.load(i) for i in range(n_chunks)]

    mesh = batch_mesh(devices)
    t_final_array = jnp.asarray(float(t_final))
    window_array = jnp.asarray(window, float)
    computed = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, unit="traj", desc="sweep", file=sys.stderr, dynamic_ncols=True)
        bar.update(sum(sizes[i] for i in range(n_chunks) if chunks[i] is not None))
    try:
        for i in range(n_chunks):
            if bar is not None:
                bar.set_postfix_str(f"chunk {i + 1}/{n_chunks}")
            if chunks[i] is not None:
                continue
            lanes = _device_order(np.arange(i * chunk, i * chunk + chunk).clip(max=n - 1), n_dev)  # padded
            inputs = _put((Vs[lanes], taus[lanes], {k: v[lanes] for k, v in param_values.items()}), devices)
            summary = engine_run.run(
                model, solver, *inputs, t_final_array, window_array, truncation, mesh, lane_batch
            )
            host = _to_host({key: getattr(summary, key) for key in keys})
            back = np.argsort(_device_order(np.arange(chunk), n_dev))
            arrays = {key: value[back][: sizes[i]] for key, value in host.items()}
            if store is not None and jax.process_index() == 0:
                store.save(i, arrays)
            chunks[i] = arrays
            computed.append(i)
            if bar is not None:
                bar.update(sizes[i])
    finally:
        if bar is not None:
            bar.close()
    merged = {key: np.concatenate([c[key] for c in chunks]) for key in keys}
    result = _result(
        merged, Vs, taus, param_values, save_ts, t_final, window, grid_shape, settings, tuple(computed)
    )
    if store is not None and jax.process_index() == 0:
        store.finish(result.arrays())
    return result


def _device_order(lanes: np.ndarray, n_devices: int) -> np.ndarray:
    """Deal the lanes to the devices like cards (lane i to device i mod n_devices).

    Sharding gives each device a contiguous block of the batch; dealing spreads neighbouring
    (V, τ), which cost alike, over all devices, so no device gets all the hard ones.
    """
    if n_devices == 1:
        return lanes
    return lanes.reshape(-1, n_devices).T.reshape(-1)


def _result(arrays, Vs, taus, params, save_ts, t_final, window, grid_shape, settings, computed) -> SweepResult:
    status = np.asarray(arrays["status"], dtype=np.int32)
    summaries = {key: np.asarray(arrays[key]) for key in _SUMMARY_FIELDS if key != "status"}
    w0, w1 = window[0] * float(t_final), window[1] * float(t_final)
    window_time = np.clip(np.minimum(summaries["t_stop"], w1) - w0, 0.0, None)
    return SweepResult(
        V=Vs,
        tau=taus,
        params=params,
        completed=status == StopReason.COMPLETED,
        status=status,
        window_time=window_time,
        ts=save_ts,
        ys=None if save_ts is None else np.asarray(arrays["ys"]),
        grid_shape=grid_shape,
        settings=settings,
        computed_chunks=computed,
        **{key: value for key, value in summaries.items() if key != "completed"},
    )
