"""``peeljax.sweep``: many (V, τ[, model parameter]) trajectories, batched, chunked, resumable.

The flow: the inputs become one entry per trajectory (:mod:`.grid`); the integrator is chosen
(:mod:`.integrators`); each chunk of lanes is placed on the devices (:mod:`.devices`), run by
the compiled engine (:mod:`.engine`), gathered and written (:mod:`.storage`); the chunks are
merged into a :class:`SweepResult`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import sys
from collections.abc import Sequence

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Int

from .._files import read_meta
from .._memory import check_output_memory
from .._validation import check_choice, check_truncation
from ..adhesion import AdhesionLaw, law_settings
from ..integrators.alpha import AlphaMethod

from ..model import PeelingModel
from ..saved import register_reader
from ..solution import StopReason
from .devices import batch_mesh, deal, default_lane_batch, put_lanes, to_host
from .distributed import check_same_settings, is_multiprocess, open_shared_store
from .grid import axis, check_window, trajectories
from .engine import GIVEN_START
from .integrators import sweep_plan
from .lane_cycles import CYCLE_BYTES, CYCLE_KEYS, cycle_arrays, sweep_cycle_statistics
from .storage import FORMAT, VERSION, ChunkStore, check_writable_format

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
# Each lane's jump record (runs carried through the folds of φ): a count and 5 arrays of max_jumps slots.
JUMP_KEYS: tuple[str, ...] = ("jump_count", "jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G")
_JUMP_FIELDS = {"jump_count": "count", "jump_t": "t", "jump_up": "up", "jump_v_before": "v_before",
                "jump_v_after": "v_after", "jump_G": "G"}  # fmt: skip
# SweepResult.as_dict's per-trajectory fields
_RECORD_KEYS = ("V", "tau", "completed", "status", "t_stop", "v_mean", "v_std", "v_min", "v_max", "events",
                "accepted_steps", "rejected_steps", "window_time")  # fmt: skip


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
        jumps: where the runs go through the folds of φ, each lane's jump record: ``jump_count``
            (n,) and ``jump_t``, ``jump_up``, ``jump_v_before``, ``jump_v_after``, ``jump_G``
            (n, max_jumps), NaN-padded (see :class:`~peeljax.JumpRecord`); else None.
            :meth:`cycle_statistics` summarizes a lane.
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
    jumps: dict[str, np.ndarray] | None = None
    cycles: dict[str, np.ndarray] | None = None  # the window's cycle statistics per lane (keys CYCLE_KEYS)
    peeljax_version: str | None = None  # of the peeljax that wrote the file it was loaded from

    def __len__(self) -> int:
        return int(self.V.shape[0])

    def cycle_statistics(self, index: int, transient: float | None = None, **kwargs):
        """The :class:`~peeljax.cycles.CycleStatistics` of lane ``index``: over the window
        (``transient`` None) from the sums its loop kept, what :func:`peeljax.cycle_statistics`
        gives for the run's whole record; another ``transient`` from its kept jumps, where they
        hold all after it (:func:`peeljax.sweeps.lane_cycles.sweep_cycle_statistics`)."""
        return sweep_cycle_statistics(self, index, transient, **kwargs)

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
        if self.jumps is not None:
            out.update(self.jumps)
        if self.cycles is not None:
            out.update(self.cycles)
        return out

    def as_dict(self) -> dict:
        """The trajectories as JSON-able lists: ``trajectories`` (V, tau, completed, status, t_stop, v's window
        statistics, events, step counts, window_time; one entry per trajectory) and ``jumps`` (None where none were
        recorded): ``jump_count``, then per trajectory its recorded jumps in time order, for each of jump_t,
        jump_up, jump_v_before, jump_v_after and jump_G."""
        record = {"trajectories": {key: np.asarray(getattr(self, key)).tolist() for key in _RECORD_KEYS}, "jumps": None}
        if self.jumps is not None:
            counts = np.asarray(self.jumps["jump_count"]).astype(int)
            record["jumps"] = {"jump_count": counts.tolist()} | {
                key: [np.asarray(self.jumps[key])[i, :n].astype(bool if key == "jump_up" else float).tolist()
                      for i, n in enumerate(counts)]
                for key in JUMP_KEYS[1:]
            }  # fmt: skip
        return record

    def table(self) -> str:
        """One row per trajectory under a header: V, tau, how it ended, t_stop, v's mean and standard deviation over
        the window, events, accepted and rejected steps, and the jumps where they were recorded."""
        jumps = None if self.jumps is None else np.asarray(self.jumps["jump_count"])
        lines = [f"{'V':>8} {'tau':>10} {'status':>14} {'t_stop':>8} {'v_mean':>10} {'v_std':>10} {'events':>6} "
                 f"{'steps':>8} {'rejected':>8}{'' if jumps is None else '   jumps'}"]  # fmt: skip
        for i in range(len(self)):
            lines.append(
                f"{self.V[i]:8.4g} {self.tau[i]:10.4g} {self.reasons[i]:>14} {self.t_stop[i]:8.4g} "
                f"{self.v_mean[i]:10.4g} {self.v_std[i]:10.4g} {self.events[i]:6d} "
                f"{self.accepted_steps[i]:8d} {self.rejected_steps[i]:8d}"
                + ("" if jumps is None else f" {jumps[i]:7d}")
            )
        return "\n".join(lines)

    # ------------------------------------------------------------------ labelled data and files
    def to_xarray(self):
        """The sweep as an ``xarray.Dataset`` with labelled dimensions and units.

        Dimensions: ``("V", "tau", <swept parameters>…)`` for ``grid="outer"`` (coordinates:
        the values swept), ``("trajectory",)`` for ``grid="pairs"`` (V, τ and the parameters as
        coordinates along it); ``t`` for saved states (variables ``alpha``, ``omega``, ``u``,
        ``v``) and ``jump`` for the jump records' slots. Each variable has a ``units`` attribute;
        the dataset's attributes hold ``kind`` ("sweep"), ``peeljax_version``, the scalar
        settings and ``settings_json`` (all of them). Needs ``pip install "peeljax[xarray]"``.
        """
        from .labelled import sweep_dataset

        return sweep_dataset(self)

    def save(self, path: str | os.PathLike) -> None:
        """Write the sweep to ``path``: netCDF-4 for a ``.nc`` suffix (:meth:`to_xarray`; needs
        ``pip install "peeljax[xarray]"``), else an ``.npz`` (:meth:`arrays` and ``meta_json``:
        the settings, the units and the peeljax version). :func:`peeljax.load` reads either back.
        The file is replaced only once it is complete (a failed write keeps the previous one)."""
        from .storage import write_result

        write_result(path, self, {"format": FORMAT, "version": VERSION, "settings": self.settings})

    @classmethod
    def from_arrays(cls, arrays: dict, settings: dict, peeljax_version: str | None = None) -> SweepResult:
        """The sweep from the arrays of its ``.npz`` (:meth:`arrays`) and its ``settings``."""
        names = list(settings.get("params", {}))
        missing = [key for key in (*PER_TRAJECTORY_KEYS, *(f"param_{name}" for name in names)) if key not in arrays]
        if missing:
            raise ValueError(f"not a sweep's arrays: missing {missing}")
        if settings.get("grid", "outer") == "outer":
            grid_shape = (len(settings["V"]), len(settings["tau"]), *(len(settings["params"][n]) for n in names))
        else:
            grid_shape = None
        n = int(np.asarray(arrays["V"]).shape[0])
        if grid_shape is not None and int(np.prod(grid_shape)) != n:
            raise ValueError(f"the settings' grid {grid_shape} does not hold the {n} trajectories of the arrays")
        result = _result(
            arrays, np.asarray(arrays["V"], float), np.asarray(arrays["tau"], float),
            {name: np.asarray(arrays[f"param_{name}"], float) for name in names},
            None if "ts" not in arrays else np.asarray(arrays["ts"], float), settings["t_final"], settings["window"],
            grid_shape, settings, (),
        )  # fmt: skip
        return dataclasses.replace(result, peeljax_version=peeljax_version)

    @classmethod
    def from_xarray(cls, dataset) -> SweepResult:
        """The sweep from its dataset (:meth:`to_xarray`, or a netCDF file it was written to)."""
        from .labelled import sweep_arrays

        arrays, settings = sweep_arrays(dataset)
        return cls.from_arrays(arrays, settings, dataset.attrs.get("peeljax_version"))


# ---------------------------------------------------------------------------- inputs
def _model_settings(model: PeelingModel) -> dict:
    adhesion = model.adhesion
    phi = law_settings(adhesion)
    return {name: float(getattr(model, name)) for name in ("R", "I", "k", "l")} | {
        "geometry": model.geometry,
        "phi": phi,
    }


def sweep_settings(model, plan, V, tau, params, grid, t_final, window, chunk, truncation) -> dict:
    """The JSON-able settings that determine a sweep's results (compared when resuming)."""
    return {
        "V": [float(x) for x in V],
        "tau": [float(x) for x in tau],
        "params": {name: [float(x) for x in values] for name, values in params.items()},
        "grid": grid,
        **plan.settings(),
        "t_final": float(t_final),
        "window": list(window),
        "chunk": chunk,
        "truncation": truncation,
        "model": _model_settings(model),
    }


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
    solver: str | AlphaMethod | diffrax.AbstractSolver | None = None,
    rho: float = 0.0,
    truncation: int | None = None,
    dtmin: float | None = None,
    max_steps: int | None = None,
    memory_limit: float | None = None,
    devices: Sequence | None = None,
    lane_batch: int | None = None,
    fold: str | None = None,
    max_jumps: int | None = None,
    start: str | ArrayLike = "paper",
) -> SweepResult:
    """Integrate eq. ``hv`` with (``av``)–(``str``) (or the DAE at τ = 0) for many (V, τ, …) at once.

    Each trajectory is the run :func:`peeljax.simulate` makes with the same settings: with
    ``dt=None`` (default) error control with :func:`peeljax.simulate`'s default stepper (τ > 0:
    Tsit5, switching to the α-method where the ODE turns stiff), each trajectory with its own
    step sizes; with a number ``dt`` the α-method's uniform mesh, the same for every trajectory.

    Args:
        model: the base model (default: the paper's); ``params`` overrides its parameters.
        V, tau: pull velocities [m/s] (> 0) and homogenization scales [s] (numbers or 1-D):
            all τ > 0 (the homogenized ODE) or all τ = 0 (the DAE itself, with jumps).
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
        out: a ``.npz`` path (or ``.nc``: netCDF-4, labelled as :meth:`SweepResult.to_xarray`,
            with ``pip install "peeljax[xarray]"``): chunks go to ``<out>.chunks/`` as they
            finish, the merged result to ``out`` (read back by :func:`peeljax.load`); a rerun
            with the same out and settings resumes (finished chunks are loaded, not recomputed;
            with ``progress`` a line on stderr says how many) and different settings
            (tolerances included) are refused.
        progress: show a tqdm bar of trajectories and chunks (stderr).
        rho: the α-method's ρ ∈ [0, 1) (default 0, the paper's choice for the best-conditioned
            Newton matrix). A speed lever under error control: the local error constant falls
            from 1/3 (ρ = 0) to 1/9 (ρ = 0.5), and at equal error on the 1024-lane batch of
            ``benchmarks/studies/lane_levers.py`` (retired: ``benchmarks/studies/README.md``) ρ = 0.5 took about 0.6× the step attempts and
            the time, with the τ = 0 jump times no less accurate
            (``benchmarks/studies/results/lane_levers.md``).
        solver: an :class:`AlphaMethod` (default ``AlphaMethod(rho=rho)``), or any
            ``diffrax.AbstractSolver`` (error control: each lane through diffrax with its PID
            controller, the same summaries; a reference, far slower than the α-method).
        truncation: as in :func:`peeljax.simulate`.
        dtmin, max_steps: error control only, as in :func:`peeljax.simulate`.
        memory_limit: bytes the results may take in host memory (default: half the RAM).
        devices: the devices to shard each chunk over (default: ``jax.devices()``; on a CPU
            peeljax asks JAX for one device per core, see :mod:`peeljax`). After
            ``jax.distributed.initialize`` that is every process's devices: call ``sweep`` with
            the same arguments in every process; only process 0 writes ``out``, which must be on
            a file system they share (:mod:`peeljax.sweeps.distributed`, ``docs/sweeps.md``).
        lane_batch: error control only: lanes run together under ``vmap`` (groups run one
            after another); default 1 on CPUs and the whole chunk on GPUs
            (:func:`default_lane_batch`). It changes the speed, not the steps taken.
        fold: what happens at a fold of φ, as in :func:`peeljax.simulate` (default: ``"jump"``
            under error control); each lane's jumps are kept (``result.jumps``).
        max_jumps: each lane keeps its last ``max_jumps`` jumps (a ring buffer, default 64;
            ``result.jumps``); the cycle statistics of the window are accumulated in the loop
            over all of its jumps (``result.cycles``), and no lane stops for a full record.
        start: each lane's initial state: ``"paper"`` (the paper's, the tape at rest),
            ``"steady"`` (steady peeling, v = V): stick-slip and steady peeling coexist for
            some V, so the start decides which one a lane shows; or the states (α, ω, u, v)
            themselves, shape (4,) for every lane or (n, 4), one per trajectory in the grid's
            order (consistent at τ = 0: :meth:`PeelingModel.consistent_state`).

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
    taus_given = axis("tau", tau)
    dae = bool(np.all(taus_given == 0))
    given_states = None
    if not isinstance(start, str):
        given_states, start = start, GIVEN_START
    plan = sweep_plan(
        solver, rho, dt, t_final, rtol, atol, save_dt, save_every, dtmin, max_steps, fold, max_jumps, dae, start
    )
    if dae and truncation is not None:
        raise ValueError("truncation applies to tau > 0 (the homogenized ODE); tau=0 is the DAE itself")
    check_truncation(truncation)
    params = dict(params or {})
    if not isinstance(model.adhesion, AdhesionLaw) and any(name not in ("R", "I", "k", "l") for name in params):
        raise ValueError("sweeping coefficients of φ needs model.adhesion to be an AdhesionLaw")
    window = check_window(window)
    if not plan.uniform and window[0] == window[1]:
        raise ValueError(f"window must have w0 < w1 with error control (its statistics are time integrals), got {window!r}")
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if lane_batch is not None and (isinstance(lane_batch, bool) or not isinstance(lane_batch, int) or lane_batch < 1):
        raise ValueError(f"lane_batch must be a positive integer, got {lane_batch!r}")
    Vs, taus, param_values, grid_shape = trajectories(V, tau, params, grid)
    n = Vs.size
    states = None if given_states is None else _start_states(given_states, n)
    devices = list(jax.devices()) if devices is None else list(devices)
    multiprocess = is_multiprocess()  # jax.distributed: every process's devices, one program
    if not multiprocess:  # (there every process must keep its devices, even with padding only)
        devices = devices[: max(1, min(len(devices), n))]  # no device with only padding to run
    n_dev = len(devices)
    chunk = min(chunk, n)
    chunk = -(-chunk // n_dev) * n_dev  # a multiple of the device count
    lane_batch = default_lane_batch(devices, chunk) if lane_batch is None else lane_batch

    # Memory: every saved state of every trajectory is returned in host memory.
    n_save = plan.save_count()  # counted, not made: the check comes before the arrays
    jump_bytes = 0 if plan.max_jumps is None else plan.max_jumps * 5 * 8 + CYCLE_BYTES
    total = n * (n_save * 4 * 8 + jump_bytes + _BYTES_PER_TRAJECTORY)
    if plan.uniform:
        fewer = f"a larger save_every{'' if save_every is None else f', now {save_every}'}, or none"
    else:
        fewer = f"a larger save_dt{'' if save_dt is None else f', now {save_dt:g}'}, or none"
    check_output_memory(
        "the sweep's output", total, f"{n} trajectories x {n_save} saved states x 4 x 8 bytes + summaries",
        f"save fewer states ({fewer}), sweep fewer V/tau values or a shorter t_final, or raise memory_limit",
        memory_limit,
    )  # fmt: skip
    save_ts = plan.save_times()

    settings = sweep_settings(
        model, plan, axis("V", V), axis("tau", tau), {k: axis(k, v) for k, v in params.items()},
        grid, t_final, window, chunk, truncation,
    )  # fmt: skip
    if states is not None:  # (a resumed sweep must have started from the same states)
        settings["start_states_sha256"] = hashlib.sha256(states.tobytes()).hexdigest()
    n_chunks = -(-n // chunk)
    sizes = [min(chunk, n - i * chunk) for i in range(n_chunks)]
    keys = tuple(_SUMMARY_FIELDS) + (("ys",) if save_ts is not None else ())
    keys += JUMP_KEYS + CYCLE_KEYS if plan.max_jumps is not None else ()
    store = None
    chunks: list[dict | None] = [None] * n_chunks
    if multiprocess:
        check_same_settings(settings)
        progress = progress and jax.process_index() == 0  # one bar, not one a process
    if out is not None:
        check_writable_format(out)
        store = ChunkStore(out, settings, n_chunks, sizes, keys)
        if multiprocess:  # process 0 opens the folder; all skip the chunks it found
            merged, chunks = open_shared_store(store, n_chunks)
        else:
            merged = store.finished_output()
        if merged is not None:
            if progress:
                print(f"resumed: the finished sweep loaded from {str(store.out)!r}", file=sys.stderr)
            return _result(merged, Vs, taus, param_values, save_ts, t_final, window, grid_shape, settings, ())
        if not multiprocess:
            store.open()
            chunks = [store.load(i) for i in range(n_chunks)]
        loaded = sum(c is not None for c in chunks)
        if loaded and progress:
            print(f"resumed: {loaded} of {n_chunks} chunks loaded from {str(store.folder)!r}", file=sys.stderr)

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
            lanes = deal(np.arange(i * chunk, i * chunk + chunk).clip(max=n - 1), n_dev)  # padded
            given = {} if states is None else {"y0": states[lanes]}
            inputs = put_lanes((Vs[lanes], taus[lanes], {k: v[lanes] for k, v in param_values.items()}, given), devices)
            summary = plan.run(model, *inputs[:3], t_final_array, window_array, truncation, mesh, lane_batch, inputs[3])
            host = to_host({key: _summary_field(summary, key) for key in keys})
            back = np.argsort(deal(np.arange(chunk), n_dev))
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
        store.finish(result)
    return result


def _start_states(states, n: int) -> np.ndarray:
    """A sweep's given starts as (n, 4) float64: one state (α, ω, u, v) for all, or one each."""
    try:
        array = np.asarray(states, float)
    except (TypeError, ValueError):
        raise ValueError(f"start must be 'paper', 'steady' or states (alpha, omega, u, v), got {states!r}") from None
    if array.shape == (4,):
        array = np.broadcast_to(array, (n, 4))
    if array.shape != (n, 4):
        raise ValueError(
            f"start states must have shape (4,) or (n, 4) with n = {n}, the sweep's trajectories, got shape {array.shape}"
        )
    if not np.all(np.isfinite(array)):
        raise ValueError("start states must be finite")
    return np.ascontiguousarray(array)


def _summary_field(summary, key: str):
    if key in _JUMP_FIELDS:
        return getattr(summary.jumps, _JUMP_FIELDS[key])
    if key in CYCLE_KEYS:
        return cycle_arrays(summary.cycles)[key]
    return getattr(summary, key)


def _result(arrays, Vs, taus, params, save_ts, t_final, window, grid_shape, settings, computed) -> SweepResult:
    status = np.asarray(arrays["status"], dtype=np.int32)
    jumps = {key: np.asarray(arrays[key]) for key in JUMP_KEYS} if "jump_count" in arrays else None
    cycles = None
    if CYCLE_KEYS[0] in arrays:  # (files written before the slip states were kept: NaN)
        missing = {"cycle_slip_state": np.full((status.size, 4), np.nan)}
        cycles = {key: np.asarray(arrays[key]) if key in arrays else missing[key] for key in CYCLE_KEYS}
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
        jumps=jumps,
        cycles=cycles,
        **{key: value for key, value in summaries.items() if key != "completed"},
    )


# ---------------------------------------------------------------------------- peeljax.load
def _read_npz(arrays: dict, name: str) -> SweepResult:
    meta = read_meta(arrays, name) or {}
    if not isinstance(meta.get("settings"), dict):
        raise ValueError(f"{name!r} is malformed: its meta_json has no settings object")
    try:
        return SweepResult.from_arrays(arrays, meta["settings"], meta.get("peeljax_version"))
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{name!r} is malformed: not a sweep's arrays ({error})") from None


register_reader("sweep", npz=_read_npz, netcdf=lambda dataset, name: SweepResult.from_xarray(dataset))
