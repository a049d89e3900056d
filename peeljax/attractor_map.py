"""The attractor map over V: every attractor the DAE (τ = 0) settles on, labelled, with its basin
share and the boundaries in V where the set of attractors changes.

:func:`attractor_map` works in batched rounds of :func:`peeljax.sweep` runs (every lane one
trajectory, all lanes of a round one compiled program over every device):

1. **Starts.** At every V: the tape at rest (the paper's start), steady peeling (v = V), and
   ``random_starts`` states on the stick branch, the same draws at every V (α ∈ [−0.3, 0.4] rad,
   ω ∈ [0, 2V/R], v = s·v̂(V) with s ∈ [0.05, 0.95], u from the constraint (sac)).
2. **Features** of each run over its window [transient, t_final] (:mod:`peeljax.sweeps.stick_slip_map`):
   stick-slip or not, the repeat of its stick → slip events, the five statistics, the stick
   fraction, and the state at its last slip (on the section of :mod:`peeljax.orbits`).
3. **Labels.** *steady*: no jump in the window. *periodic (k slips per period)*: the repeat found
   (strictly, or to 3 % on the later part of the window) and the orbit found from the last slip
   by :func:`peeljax.periodic_orbits` (batched Newton on the return map; converged with
   |μ₁| < 1; a solve held at Newton's floor by the runs' rounding is shot again at a tighter
   ``rtol``), with its exact period and Floquet multipliers. *Near an unstable orbit (k)*:
   Newton converges from the run to an orbit with |μ₁| ≥ 1 whose period is the run's repeat
   (to 3 %): the run has not yet left it. Not an attractor: kept as a row with this label
   (where runs linger, and how often: ``hits``, its basin share), never a seed or a bisected
   branch. (From steady peeling at 2.3–4.8 m/s the runs shadow a k = 1 orbit whose complex
   pair of multipliers lies just outside the unit circle, |μ₁| = 1.0001–1.0012: at 3.09 m/s
   the slip intervals spread by e in ~9 s and the run leaves after 20–40 s.) Otherwise the
   largest two Lyapunov exponents through the jumps (:func:`peeljax.lyapunov_spectra`, all
   such runs in one batch, from their last slips): *chaotic* where λ₁ > 0 beyond three standard errors and
   ``chaos_threshold``; *periodic (k=?)* where λ₂ < 0 beyond them (a bounded attractor of a
   flow has a zero exponent along the flow; λ₂ < 0 makes it λ₁, and an attractor with no other
   exponent ≥ 0 is a limit cycle: its orbit not found, k not known); *quasi-periodic* where λ₁
   and λ₂ are both 0 within them; *irregular* where none can be said (a run the exponents'
   check stopped, or exponents too uncertain); *unresolved*: a run that stopped before t_final.
4. **Attractors per V**: runs whose labels agree and whose orbits (periodic: the period to 1e-5)
   or statistics (others: the mean time between slips and the stick fraction to 5 %) agree are
   one attractor; its basin share is the fraction of the random starts that end on it, with the
   binomial standard error. (At τ = 0 every slip starts at φ's maximum and every stick at its
   minimum: the forces at the jumps are V's alone, the same for every attractor; the time
   between slips is the attractor's own.)
5. **Neighbours' seeds** (``seed_rounds``): an attractor found at a neighbouring V but not at V is
   looked for from its last slip moved to V (α, ω kept, v at the same fraction of v̂); repeated
   until no round finds a new one. Attractors of neighbouring V are linked into branches (same
   label and k, the mean time between slips within ``branch_tol``).
6. **Boundaries** where a branch of steady peeling or of refined periodic orbits (what a run
   tells apart without exponents) ends between two V of the grid, to ``boundary_tol``. A
   periodic branch: its orbit continued by Newton (:func:`peeljax.periodic_orbits`, every end
   of a round in one batch) from the inside towards the neighbouring grid value, the step halved
   after each failure (a failure from more than 2e-3 m/s away is tried again from the next
   orbit); the bracket's inside end has the branch's orbit, stable, and Newton from there finds
   none at the outside end. Then one run from the orbit at each outside end names the change:
   *loses stability* (Newton converged there with |μ₁| ≥ 1), *stick-slip ends* (the run peels
   steadily), *period doubling* (2k slips, the period doubled to 5 %), *grazing* (another k,
   the period continuous to 5 %) or *lost* (to another attractor); where that run finds the
   branch's orbit after all, the continuation goes on from it. A branch of steady peeling ends
   where its linearisation says (:func:`peeljax.steady_peeling_ends`: at a fold of φ,
   ∂φ/∂v(V, V) = 0, or a Hopf bifurcation), to 1e-8 m/s, without a run: close to a fold runs
   cannot bracket it (the damping of steady peeling vanishes there and its stiffness grows
   without bound); bisected by runs only where the linearisation does not put the end between
   the two grid values.

Steady peeling's stability, its ends and a periodic orbit are exact; the other labels rest on
finite runs: the tolerances above say how far. :func:`peeljax.plots.plot_attractor_map` draws
the result.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time

import jax
import numpy as np
from jaxtyping import ArrayLike

from ._files import META_KEY, json_safe, meta_array, read_meta
from ._validation import check_positive
from .cycles import repeat_pattern
from .model import PAPER_ALPHA0, PeelingModel
from .orbits.shooting import FLOOR_RESIDUAL, FLOOR_RTOL, at_floor, keep_converged
from .saved import register_reader
from .solution import StopReason
from .steady import FOLD, HOPF, steady_peeling_ends
from .sweeps.stick_slip_map import fold_table, map_lanes

__all__ = ["ATTRACTOR_KINDS", "AttractorMap", "attractor_label", "attractor_map", "check_attractor_map_options"]

DEFAULT_V = np.linspace(0.3, 5.4, 200)  # [m/s]: the stick-slip range of the paper's φ and its ends
DEFAULT_V.setflags(write=False)
ATTRACTOR_KINDS: tuple[str, ...] = (
    "steady", "periodic", "quasi-periodic", "chaotic", "irregular", "unresolved", "near an unstable orbit",
)  # fmt: skip
STEADY, PERIODIC, QUASI_PERIODIC, CHAOTIC, IRREGULAR, UNRESOLVED, UNSTABLE = range(len(ATTRACTOR_KINDS))

_LOOSE_REPEAT = 3e-2  # the repeat looked for on the later part of a window that shows none strictly
_SAME_PERIOD = 1e-5  # two refined orbits with these relative periods are one
_SAME_STATISTICS = 5e-2  # two undecided runs with these relative slip intervals and stick fractions are one
_GRAZING_JUMP = 5e-2  # a change of k with the period continuous to this: a grazing
_KEPT_JUMPS = 512  # each lane's last jumps (ring buffer): the repeat of up to 127 slips per period is looked for
_MAX_SLIPS = 127
# A run's step budget per second run: stick-slip at 5.4 m/s takes about 2·10⁴ a second; a run
# near a grazing can take without end (it stops, unresolved, rather than hold up its round).
_MAX_STEPS_PER_SECOND = 60_000
_CHUNK = 16  # lanes per compiled batch: every round's sweep is padded to it (one program)
_IDLE_PERIOD = 1e-9  # s: the period guess of a padding lane of orbits (its runs end at once)
# Newton's floor (docs/attractors.md): solves that end there are shot again at the tighter tolerance
_FLOOR_RESIDUAL, _FLOOR_RTOL = FLOOR_RESIDUAL, FLOOR_RTOL
_TWIN_RTOL = 1e-4  # runs of one V and k whose repeat periods agree to this refine one orbit

# Per attractor: the fields of AttractorMap (float unless named in _INT_FIELDS).
ATTRACTOR_FIELDS: tuple[str, ...] = (
    "V_index", "V", "kind", "slips", "period", "multiplier", "lyapunov", "lyapunov_2", "lyapunov_se",
    "G_slip_max", "G_stick_min", "slip_interval", "stick_fraction", "v_mean", "hits", "basin", "basin_se",
    "branch",
)  # fmt: skip
_ORBIT_FIELDS = ("status", "multipliers", "period", "state", "residual")
_STEADY_END = {FOLD: "fold of phi: dphi/dv(V, V) = 0", HOPF: "Hopf bifurcation"}
_INT_FIELDS = ("V_index", "kind", "slips", "hits", "branch")
_KIND = "attractor-map"  # the files' kind (peeljax.load)
_UNITS = {"V": "m/s", "period": "s", "lyapunov": "1/s", "lyapunov_2": "1/s", "lyapunov_se": "1/s", "G_slip_max": "N",
          "G_stick_min": "N", "slip_interval": "s", "v_mean": "m/s", "boundary_V_inside": "m/s", "boundary_V_outside": "m/s"}  # fmt: skip
BOUNDARY_FIELDS: tuple[str, ...] = ("branch", "V_inside", "V_outside", "change", "becomes_kind", "becomes_slips")


def attractor_label(kind: int, slips: int) -> str:
    """An attractor's label: its kind, with k for a periodic one (``"periodic (k=2)"``;
    ``"periodic (k=?)"``: a limit cycle by its exponents, its orbit not found) and for the
    unstable orbit a run has not yet left (``"near an unstable orbit (k=1)"``)."""
    if kind not in (PERIODIC, UNSTABLE):
        return ATTRACTOR_KINDS[kind]
    return f"{ATTRACTOR_KINDS[kind]} (k={slips})" if slips else f"{ATTRACTOR_KINDS[kind]} (k=?)"


@dataclasses.dataclass(frozen=True, eq=False)
class AttractorMap:
    """The attractors over V (definitions: :mod:`peeljax.attractor_map`).

    Attributes:
        V: the pull velocities of the grid [m/s], shape (m,).
        V_index, V, kind, …: per attractor (shape (n,), in order of V): the grid index and V,
            the label (an index into :data:`ATTRACTOR_KINDS`), k = slips per period (0 where not
            periodic, or a limit cycle known by its exponents alone), the period [s] and |μ₁| of
            a periodic orbit (NaN otherwise), λ₁, λ₂ and λ₁'s standard error [1/s] (NaN where
            not computed), the statistics of a run on it
            (largest slip force and smallest re-stick force G [N], mean time between slips [s],
            stick fraction, mean v [m/s]), how many runs ended on it (``hits``), its basin share
            among the random starts with its binomial standard error, and its branch.
        state: (n, 4) a state on it (the last slip, before the jump; steady: the steady state).
        boundaries: per boundary of a branch (shape (b,) each): ``branch``, the bracket's ends
            ``V_inside`` (the attractor found) and ``V_outside`` (not found from its seed),
            ``change`` (the kind of change, text), and what the seed became beyond it
            (``becomes_kind``, ``becomes_slips``).
        random_starts, t_final, transient: what was run; settings: every option (JSON-able).
        rounds: lanes run per round (starts, seeds, bisection); wall_time: seconds in all.
    """

    grid_V: np.ndarray
    fields: dict[str, np.ndarray]
    state: np.ndarray
    boundaries: dict[str, np.ndarray]
    random_starts: int
    t_final: float
    transient: float
    settings: dict = dataclasses.field(default_factory=dict)
    rounds: tuple = ()
    wall_time: float = math.nan

    def __getattr__(self, name):
        fields = self.__dict__.get("fields", {})
        if name in fields:
            return fields[name]
        raise AttributeError(name)

    @property
    def labels(self) -> list[str]:
        """Each attractor's label (:func:`attractor_label`)."""
        return [attractor_label(kind, k) for kind, k in zip(self.fields["kind"], self.fields["slips"])]

    def at(self, V: float) -> list[int]:
        """The attractors at the grid's V nearest to ``V`` (indices into the per-attractor fields)."""
        j = int(np.argmin(np.abs(self.grid_V - float(V))))
        return [int(i) for i in np.flatnonzero(self.fields["V_index"] == j)]

    def orbit(self, i: int, model: PeelingModel | None = None, **options):
        """The periodic orbit of attractor ``i`` (:func:`peeljax.periodic_orbit` from its state,
        with its k and period; ``model``: the map's, default the paper's), e.g. to continue it
        over V with :func:`peeljax.continue_orbit`.

        Raises:
            ValueError: attractor ``i`` is not a periodic orbit found by Newton (k known).
        """
        from .orbits.api import periodic_orbit

        if self.fields["kind"][i] != PERIODIC or not self.fields["slips"][i]:
            raise ValueError(f"attractor {i} is {self.labels[i]!r}: only a periodic orbit with k known has an orbit")
        return periodic_orbit(
            model, V=float(self.fields["V"][i]), start=self.state[i], slips=int(self.fields["slips"][i]),
            period=float(self.fields["period"][i]), **options,
        )  # fmt: skip

    def as_dict(self) -> dict:
        """The map as JSON-able lists: ``V`` (the grid), ``attractors`` (every field of
        :data:`ATTRACTOR_FIELDS` and ``label``, per attractor), ``boundaries``, ``rounds`` and ``settings``."""
        return {
            "V": self.grid_V.tolist(),
            "attractors": {name: np.asarray(self.fields[name]).tolist() for name in ATTRACTOR_FIELDS} | {"label": self.labels},
            "boundaries": {name: np.asarray(value).tolist() for name, value in self.boundaries.items()},
            "rounds": list(self.rounds),
            "settings": self.settings,
        }

    def summary(self) -> str:
        """A few lines: the attractors by label, the branches and the boundaries."""
        labels = self.labels
        counts = {label: labels.count(label) for label in dict.fromkeys(labels)}
        lines = [
            f"attractor map: {self.grid_V.size} values of V in [{self.grid_V[0]:g}, {self.grid_V[-1]:g}] m/s, "
            f"{self.random_starts} random starts each",
            "attractors: " + ", ".join(f"{n} {label}" for label, n in counts.items()),
            f"branches: {len(set(self.fields['branch'].tolist()))}",
        ]
        b = self.boundaries
        for i in range(b["branch"].size):
            lo, hi = sorted((b["V_inside"][i], b["V_outside"][i]))
            lines.append(f"  boundary of branch {b['branch'][i]} in [{lo:.5f}, {hi:.5f}] m/s: {b['change'][i]}")
        return "\n".join(lines)

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write the map as .npz (arrays, no pickles; its settings as JSON in ``meta_json``);
        :func:`peeljax.load` reads it."""
        extra = {
            "random_starts": self.random_starts, "t_final": self.t_final, "transient": self.transient,
            "settings": json_safe(self.settings), "rounds": list(self.rounds), "wall_time": self.wall_time,
        }  # fmt: skip
        arrays = {f"attractor_{k}": v for k, v in self.fields.items()}
        arrays |= {f"boundary_{k}": np.asarray(v, str if k == "change" else None) for k, v in self.boundaries.items()}
        arrays[META_KEY] = meta_array(_KIND, _UNITS, **extra)
        np.savez(path, grid_V=self.grid_V, state=self.state, **arrays)

    def to_xarray(self):
        """The attractors as an ``xarray.Dataset`` over the dimension ``attractor``."""
        import xarray as xr

        data = {name: ("attractor", value) for name, value in self.fields.items()}
        data["label"] = ("attractor", np.asarray(self.labels, str))
        data["state"] = (("attractor", "component"), self.state)
        attrs = {"t_final": self.t_final, "transient": self.transient, "random_starts": self.random_starts}
        return xr.Dataset(data, coords={"component": ["alpha", "omega", "u", "v"]}, attrs=attrs)


def _read_npz(arrays: dict, name: str) -> AttractorMap:
    try:
        meta = read_meta(arrays, name) or {}
        fields = {k: np.asarray(arrays[f"attractor_{k}"]) for k in ATTRACTOR_FIELDS}
        boundaries = {k: np.asarray(arrays[f"boundary_{k}"]) for k in BOUNDARY_FIELDS}
        return AttractorMap(
            grid_V=np.asarray(arrays["grid_V"], float), fields=fields, state=np.asarray(arrays["state"], float),
            boundaries=boundaries, random_starts=int(meta["random_starts"]), t_final=float(meta["t_final"]),
            transient=float(meta["transient"]), settings=meta["settings"], rounds=tuple(meta["rounds"]),
            wall_time=float(meta["wall_time"]),
        )  # fmt: skip
    except (KeyError, ValueError, TypeError) as error:
        raise ValueError(f"{name!r} is not an attractor map written by AttractorMap.save ({error})") from None


register_reader(_KIND, _read_npz)


# ---------------------------------------------------------------------------- starts
def _random_draws(n: int, seed: int) -> np.ndarray:
    """(n, 3) draws (α, ω·R/V, s) of the random starts, the same at every V."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.3, 0.4, n), rng.uniform(0.0, 2.0, n), rng.uniform(0.05, 0.95, n)])


def _top_of_stick_branch(v_max: np.ndarray, V: np.ndarray) -> np.ndarray:
    """v̂(V), or V where φ has no fold (no stick branch to speak of)."""
    return np.where(np.isfinite(v_max), v_max, V)


def _consistent(model: PeelingModel, V, alpha, omega, v) -> np.ndarray:
    """(n, 4) consistent states (u from the constraint) at the lanes' V."""
    states = jax.jit(jax.vmap(model.consistent_state))(*(np.asarray(a, float) for a in (V, alpha, omega, v)))
    return np.asarray(states)


# ---------------------------------------------------------------------------- one round of runs
def _run(model, V: np.ndarray, y0: np.ndarray, t_final: float, transient: float, sweep_kwargs: dict) -> dict:
    """Sweep the lanes (V, y0) at τ = 0 (padded to whole chunks: one compiled program for every
    round) and return each lane's map fields, plus ``slip_state``."""
    from .sweeps.api import sweep

    n = V.size
    pad = -n % _CHUNK
    V_all = np.concatenate([V, np.repeat(V[-1:], pad)])
    y_all = np.concatenate([y0, np.repeat(y0[-1:], pad, axis=0)])
    kwargs = {"max_jumps": _KEPT_JUMPS, "max_steps": _MAX_STEPS_PER_SECOND * math.ceil(t_final)} | sweep_kwargs
    result = sweep(
        model, V=V_all, tau=0.0, t_final=t_final, grid="pairs", start=y_all, window=(transient / t_final, 1.0),
        chunk=_CHUNK, progress=False, **kwargs,
    )  # fmt: skip
    fields = map_lanes(result, transient, 1e-3, settle=True)
    fields = {k: np.asarray(v)[:n] for k, v in fields.items() if k not in ("G", "up")}
    fields["slip_state"] = np.asarray(result.cycles["cycle_slip_state"])[:n]
    # The stick → slip times in the window, from the lane's last jumps (its ring buffer).
    t, up = np.asarray(result.jumps["jump_t"], float), np.asarray(result.jumps["jump_up"], bool)
    kept = np.minimum(np.asarray(result.jumps["jump_count"]), t.shape[1])
    fields["kept_slips"] = [t[i, : kept[i]][up[i, : kept[i]] & (t[i, : kept[i]] >= transient)] for i in range(n)]
    return fields


def _candidates(lanes: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per lane: the first label (steady / periodic candidate / irregular / unresolved), k and T."""
    n = lanes["status"].size
    kind = np.full(n, IRREGULAR)
    slips = np.asarray(lanes["events"], int).copy()
    period = np.asarray(lanes["period"], float).copy()
    completed = lanes["status"] == StopReason.COMPLETED
    kind[~completed] = UNRESOLVED
    steady = completed & (lanes["jumps"] == 0) & (lanes["crossings"] == 0)
    kind[steady] = STEADY
    for i in np.flatnonzero(completed & ~steady):
        if slips[i] == 0:  # no strict repeat: a looser one on the later part of the window
            times = lanes["kept_slips"][i]
            tail = times[times.size // 2 :]
            repeat = repeat_pattern(tail, rtol=_LOOSE_REPEAT) if tail.size >= 5 else None
            if repeat is not None and repeat.events <= _MAX_SLIPS:
                slips[i], period[i] = repeat.events, repeat.period
        if slips[i] > 0 and np.all(np.isfinite(lanes["slip_state"][i])):
            kind[i] = PERIODIC  # a candidate until its orbit is found
    slips[kind != PERIODIC] = 0
    period[kind != PERIODIC] = np.nan
    return kind, slips, period


def _refine(model, V, state, slips, period, orbit_rtol) -> tuple[np.ndarray, ...]:
    """The periodic candidates' orbits, batched: (converged and stable, converged and unstable,
    k, period, |μ₁|), k the orbit's own (at most the candidate's). An unstable orbit counts
    where its period is the run's repeat (to the loose repeat's 3 %): the run shadows it."""
    slips = np.array(slips, np.int64)
    if V.size == 0:
        return np.zeros(0, bool), np.zeros(0, bool), slips, np.zeros(0), np.zeros(0)
    orbits = _padded_orbits(model, V, state, slips, period, orbit_rtol)
    status = orbits["status"]
    mu = np.abs(orbits["multipliers"])
    mu1 = mu.max(axis=1) if mu.ndim == 2 else mu
    ok = (status == 0) & (mu1 < 1.0)
    T = np.asarray(orbits["period"], float)
    unstable = (status == 0) & (mu1 >= 1.0) & (np.abs(T - period) <= _LOOSE_REPEAT * period)
    # An orbit of k slips may repeat after k/p of them (p a prime factor of k): Newton on P^k
    # finds it too. Each such orbit shoots again with k/p; kept where it closes in T·(k/p)/k.
    while True:
        lanes = [(i, k // p) for i, k in enumerate(slips) if ok[i] for p in _prime_factors(int(k))]
        if not lanes:
            break
        idx = np.asarray([i for i, _ in lanes])
        fewer = np.asarray([k for _, k in lanes], np.int64)
        short = _padded_orbits(model, V[idx], orbits["state"][idx], fewer, T[idx] * fewer / slips[idx], orbit_rtol)
        T_short = np.asarray(short["period"], float)
        closes = (short["status"] == 0) & (np.abs(T_short * slips[idx] / fewer - T[idx]) <= 1e-6 * T[idx])
        changed = False
        for lane, i in enumerate(idx):
            if closes[lane] and fewer[lane] < slips[i]:
                slips[i], T[i], mu1[i], changed = fewer[lane], T_short[lane], np.abs(short["multipliers"][lane]).max(), True
        if not changed:
            break
    return ok, unstable, slips, T, mu1


def _padded_orbits(model, V, state, slips, period, orbit_rtol, max_iterations: int = 20):
    """:func:`peeljax.periodic_orbits` in chunks of ``_CHUNK`` lanes (:func:`_chunked_orbits`);
    the solves that stop at Newton's floor (NOT_CONVERGED, residual below ``_FLOOR_RESIDUAL``)
    shot again from their last iterate at ``_FLOOR_RTOL``, kept where they converge."""

    slips = np.asarray(slips, np.int64)
    orbits = _chunked_orbits(model, V, state, slips, period, orbit_rtol, max_iterations)
    floor = at_floor(orbits["status"], orbits["residual"], orbits["state"], orbits["period"])
    if floor.size == 0 or orbit_rtol <= _FLOOR_RTOL:
        return orbits
    again = _chunked_orbits(
        model, V[floor], orbits["state"][floor], slips[floor], orbits["period"][floor], _FLOOR_RTOL, max_iterations,
    )  # fmt: skip
    keep_converged(orbits, again, floor)
    return orbits


def _chunked_orbits(model, V, state, slips, period, orbit_rtol, max_iterations):
    """:func:`peeljax.periodic_orbits` in chunks of ``_CHUNK`` lanes, the last one padded (one
    compiled program for any number of lanes), the padding dropped. A padding lane's runs are
    bounded by ``_IDLE_PERIOD``: its first run ends at once, where a copy of a real lane would
    shoot that lane's orbit again (a round of 9 lanes did 16 lanes' work). The lanes go in
    order of slips and period: a chunk runs as long as its longest lane's passes."""
    from .orbits.batch import periodic_orbits

    n = V.size
    pad = -n % _CHUNK
    period = np.broadcast_to(np.asarray(period, float), V.shape)
    order = np.lexsort((period, np.asarray(slips)))
    V, state, slips, period = (np.asarray(a)[order] for a in (V, state, slips, period))

    def padded(a, fill=None):
        a = np.asarray(a)
        tail = np.repeat(a[-1:], pad, axis=0) if fill is None else np.full(pad, fill, a.dtype)
        return np.concatenate([a, tail])

    lanes = [padded(V), padded(state), padded(np.asarray(slips, np.int64)), padded(period, _IDLE_PERIOD)]
    blocks = []
    for i in range(0, n + pad, _CHUNK):
        V_i, state_i, slips_i, period_i = (a[i : i + _CHUNK] for a in lanes)
        orbits = periodic_orbits(
            model, V=V_i, start=state_i, slips=slips_i, period=period_i, rtol=orbit_rtol, max_iterations=max_iterations
        )
        blocks.append({name: np.asarray(getattr(orbits, name)) for name in _ORBIT_FIELDS})
    back = np.argsort(order)
    return {name: np.concatenate([b[name] for b in blocks])[:n][back] for name in blocks[0]}


def _prime_factors(k: int) -> list[int]:
    factors, p = [], 2
    while p * p <= k:
        if k % p == 0:
            factors.append(p)
            while k % p == 0:
                k //= p
        p += 1
    return factors + ([k] if k > 1 else [])


def _exponents(model, V: np.ndarray, states: np.ndarray, lyapunov_time: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """λ₁, λ₂ and their standard errors per lane, all lanes in one batch (:func:`peeljax.lyapunov_spectra`)."""
    from .lyapunov import lyapunov_spectra

    results = lyapunov_spectra(model, V, states, n=2, t_total=lyapunov_time, t_transient=0.5)
    return [(np.asarray(r.exponents, float), np.asarray(r.standard_error, float)) for r in results]


def _label_irregular(lam, se, chaos_threshold: float) -> int:
    """Chaotic, periodic (a limit cycle whose orbit was not found: k unknown), quasi-periodic or
    (none can be said) irregular, from λ₁, λ₂ and their standard errors: each exponent is 0 or
    not to within 3 SE + ``chaos_threshold``; a λ₁ known only to worse than ``chaos_threshold``
    decides nothing but chaos and the limit cycle."""
    if not np.all(np.isfinite(lam)):
        return IRREGULAR
    if not np.all(np.isfinite(se)):
        return IRREGULAR  # (fewer segments than batches: no standard error)
    margin = 3.0 * se + chaos_threshold
    if lam[0] > margin[0]:
        return CHAOTIC
    if lam[1] < -margin[1]:
        # A bounded attractor of a flow has a zero exponent (along the flow): λ₂ < 0 makes it
        # λ₁, and an attractor with no other exponent ≥ 0 is a limit cycle (k not known).
        return PERIODIC
    precise = se[0] <= chaos_threshold
    if precise and abs(lam[0]) <= margin[0] and abs(lam[1]) <= margin[1]:
        return QUASI_PERIODIC
    return IRREGULAR


# ---------------------------------------------------------------------------- attractors
@dataclasses.dataclass
class _Attractor:
    j: int
    kind: int
    slips: int
    period: float
    multiplier: float
    lanes: dict  # the lane fields of its first run
    state: np.ndarray
    hits: int = 0
    random_hits: int = 0
    lyapunov: tuple = (math.nan, math.nan, math.nan)
    branch: int = -1

    def same(self, other: "_Attractor") -> bool:
        if (self.kind, self.slips) != (other.kind, other.slips):
            return False
        if self.kind in (PERIODIC, UNSTABLE) and self.slips:
            return abs(self.period - other.period) <= _SAME_PERIOD * self.period
        if self.kind in (STEADY, UNRESOLVED):
            return True
        return all(
            abs(self.lanes[key] - other.lanes[key]) <= _SAME_STATISTICS * max(abs(self.lanes[key]), 1e-12)
            for key in ("slip_interval", "stick_fraction")
        )

    @property
    def slip_interval(self) -> float:
        """The mean time between slips [s]: T/k on a periodic orbit, the run's mean elsewhere. At
        τ = 0 every slip starts at φ's maximum and every stick at its minimum: the forces at the
        jumps are those of V, the same for every attractor; the time between slips is its own."""
        if self.kind in (PERIODIC, UNSTABLE) and self.slips:
            return self.period / self.slips
        return float(self.lanes.get("slip_interval", math.nan))

    def near(self, other: "_Attractor", tol: float) -> bool:
        """Same label and k, and the slip intervals within ``tol`` (relative): one branch across V."""
        if _family(self) != _family(other):
            return False
        return self.kind == STEADY or abs(self.slip_interval - other.slip_interval) <= tol * other.slip_interval


def _lane_dict(lanes: dict, i: int) -> dict:
    return {k: v[i] for k, v in lanes.items() if k != "kept_slips"}


def _steady_states(model, V: np.ndarray) -> np.ndarray:
    """(n, 4) steady peeling at each V: v = V, ω = V/R, at the paper's α0 (u consistent)."""
    return _consistent(model, V, np.full(V.size, PAPER_ALPHA0), V / float(model.R), V)


def _labels(model, V: np.ndarray, lanes: dict, options) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per lane: label, k, period and |μ₁| from the run and the orbits refined from it."""
    kind, slips, period = _candidates(lanes)
    cand = np.flatnonzero(kind == PERIODIC)
    multiplier = np.full(kind.size, np.nan)
    if cand.size:
        # Twins (the same V, k and repeat period to _TWIN_RTOL: one orbit reached from two
        # starts) take the orbit refined from the first of them.
        first = _first_twins(V[cand], slips[cand], period[cand])
        lead = np.unique(first)
        refined = _refine(model, V[cand[lead]], lanes["slip_state"][cand[lead]], slips[cand[lead]],
                          period[cand[lead]], options["orbit_rtol"])  # fmt: skip
        ok, unstable, k, T, mu1 = (np.asarray(a)[np.searchsorted(lead, first)] for a in refined)
        found = ok | unstable
        slips[cand[found]], period[cand[found]], multiplier[cand[found]] = k[found], T[found], mu1[found]
        kind[cand[unstable]] = UNSTABLE
        kind[cand[~found]], slips[cand[~found]], period[cand[~found]] = IRREGULAR, 0, np.nan
    return kind, slips, period, multiplier


def _first_twins(V: np.ndarray, slips: np.ndarray, period: np.ndarray) -> np.ndarray:
    """Per candidate, the index of the first candidate with its V and k and a repeat period
    within ``_TWIN_RTOL`` (relative) of its own (itself where none is earlier)."""
    first = np.arange(V.size)
    for i in range(V.size):
        same = (V[:i] == V[i]) & (slips[:i] == slips[i]) & (np.abs(period[:i] - period[i]) <= _TWIN_RTOL * period[i])
        same &= first[:i] == np.arange(i)  # a twin of the first of a group, not of another twin
        if same.any():
            first[i] = int(np.argmax(same))
    return first


def _classify(model, V_grid, js, y_start, lanes, options) -> list[_Attractor]:
    """One attractor candidate per lane (refined orbits; lanes without one run again, longer, from
    their last slip; exponents of those still without, one per V and statistics), in lane order."""
    V = V_grid[js]
    say = options["say"]
    kind, slips, period, multiplier = _labels(model, V, lanes, options)
    say(f"{np.sum(kind == PERIODIC)} periodic orbits refined, {np.sum(kind == STEADY)} steady, "
        f"{np.sum(kind == UNSTABLE)} near an unstable orbit, {np.sum(kind == IRREGULAR)} undecided")
    # Run again, longer, where a longer window could show the repeat: runs with few slips in
    # theirs (a run with many shows any repeat of up to _MAX_SLIPS slips already: running all
    # 440 undecided runs of the 200-V map again took 230 s and found no orbit more).
    few = np.asarray([times.size for times in lanes["kept_slips"]]) < 2 * _MAX_SLIPS + 1
    longer = np.flatnonzero((kind == IRREGULAR) & few & np.all(np.isfinite(lanes["slip_state"]), axis=1))
    if longer.size and options["extend"] > 1:
        t_long = options["extend"] * options["t_final"]
        say(f"{longer.size} undecided runs again, {t_long:g} s each")
        again = _run(model, V[longer], lanes["slip_state"][longer], t_long, t_long / 2, options["sweep_kwargs"])
        k2, s2, p2, m2 = _labels(model, V[longer], again, options)
        kind[longer], slips[longer], period[longer], multiplier[longer] = k2, s2, p2, m2
        for key in lanes:
            if key != "kept_slips":
                lanes[key][longer] = again[key]
    steady = np.flatnonzero(kind == STEADY)
    steady_states = _steady_states(model, V_grid[js[steady]])
    found = []
    for i in range(kind.size):
        state = steady_states[np.searchsorted(steady, i)] if kind[i] == STEADY else lanes["slip_state"][i]
        found.append(_Attractor(int(js[i]), int(kind[i]), int(slips[i]), float(period[i]), float(multiplier[i]),
                                _lane_dict(lanes, i), np.asarray(state, float)))  # fmt: skip
    if options["lyapunov"]:
        # One run per V and attractor (the twins take its exponents), all in one batch.
        first: list[_Attractor] = []
        twins: list[tuple[_Attractor, _Attractor]] = []
        for a in found:
            if a.kind != IRREGULAR or not np.all(np.isfinite(a.state)):
                continue
            twin = next((b for b in first if b.j == a.j and b.same(a)), None)
            if twin is None:
                first.append(a)
            else:
                twins.append((a, twin))
        if first:
            say(f"Lyapunov exponents of the {len(first)} attractors still undecided, in one batch")
            V_first = np.asarray([V_grid[a.j] for a in first])
            exponents = _exponents(model, V_first, np.stack([a.state for a in first]), options["lyapunov_time"])
            for a, (lam, se) in zip(first, exponents):
                a.lyapunov = (float(lam[0]), float(lam[1]), float(se[0]))
                a.kind = _label_irregular(lam, se, options["chaos_threshold"])
        for a, twin in twins:
            a.lyapunov, a.kind = twin.lyapunov, twin.kind
    return found


def _merge(attractors: dict[int, list[_Attractor]], found: list[_Attractor], random: np.ndarray) -> list[_Attractor]:
    """Add each run's attractor at its V (a known one gets a hit); returns the new ones. A run
    that stopped early is kept (as *unresolved*) only where it was a random start: its share."""
    new = []
    for a, is_random in zip(found, random):
        if a.kind == UNRESOLVED and not is_random:
            continue
        known = next((b for b in attractors.setdefault(a.j, []) if b.same(a)), None)
        if known is None:
            attractors[a.j].append(a)
            new.append(a)
            known = a
        known.hits += 1
        known.random_hits += int(is_random)
    return new


def _moved(model, state: np.ndarray, v_top_from: float, V_to: float, v_top_to: float) -> np.ndarray:
    """A state of V_from moved to V_to: α, ω kept, v at the same fraction of v̂ (at most 0.99), u consistent."""
    fraction = min(state[3] / v_top_from, 0.99) if v_top_from > 0 else 0.5
    return np.asarray(model.consistent_state(V_to, state[0], state[1], fraction * v_top_to), float)


def _link(attractors: dict[int, list[_Attractor]], m: int, branch_tol: float) -> int:
    """Branch ids: an attractor continues the nearest one of the previous V with its label and k
    (slip interval within branch_tol, relative); returns the number of branches."""
    n_branches = 0
    for j in range(m):
        previous = attractors.get(j - 1, [])
        taken = set()
        for a in attractors.get(j, []):
            best, best_d = None, math.inf
            for b in previous:
                if (b.kind, b.slips) != (a.kind, a.slips) or id(b) in taken:
                    continue
                d = 0.0 if a.kind == STEADY else abs(a.slip_interval - b.slip_interval) / max(b.slip_interval, 1e-12)
                if d <= branch_tol and d < best_d:
                    best, best_d = b, d
            if best is None:
                a.branch, n_branches = n_branches, n_branches + 1
            else:
                a.branch = best.branch
                taken.add(id(best))
    return n_branches


def _change(branch: _Attractor, became) -> str:
    if became == "stopped":
        return "not located (a run in the bracket stopped early)"
    if became is None:
        return "lost"
    if branch.kind != STEADY and became.kind == STEADY:
        return "stick-slip ends"
    if branch.kind == STEADY:
        return "steady peeling ends"
    if branch.kind == PERIODIC and became.kind == UNSTABLE and became.slips == branch.slips:
        if abs(became.period - branch.period) <= _GRAZING_JUMP * branch.period:
            return f"loses stability (|mu1| = {became.multiplier:.6f})"
    if branch.kind == PERIODIC and became.kind == PERIODIC:
        if became.slips == 2 * branch.slips and abs(became.period - 2 * branch.period) <= _GRAZING_JUMP * 2 * branch.period:
            return "period doubling"
        if abs(became.period - branch.period) <= _GRAZING_JUMP * branch.period:
            return f"grazing (k {branch.slips} -> {became.slips})"
    return f"lost to {attractor_label(became.kind, became.slips)}"


# ---------------------------------------------------------------------------- the map
def attractor_map(
    model: PeelingModel | None = None,
    V: ArrayLike = DEFAULT_V,
    *,
    random_starts: int = 4,
    seed: int = 0,
    t_final: float = 4.0,
    transient: float | None = None,
    seed_rounds: int = 3,
    extend: float = 3.0,
    boundary_tol: float | None = 1e-4,
    branch_tol: float = 0.1,
    lyapunov: bool = True,
    lyapunov_time: float = 10.0,
    chaos_threshold: float = 0.05,
    orbit_rtol: float = 1e-8,
    progress: bool = True,
    **sweep_kwargs,
) -> AttractorMap:
    """Every attractor of the peeling (τ = 0) over V, labelled, with basins and boundaries.

    The rounds, the labels and their tolerances: :mod:`peeljax.attractor_map`.

    Args:
        model: the model (default: the paper's).
        V: the grid of pull velocities [m/s], increasing, > 0 (default 200 in [0.3, 5.4]).
        random_starts: random states on the stick branch per V (≥ 0; the basin shares are
            fractions of them).
        seed: the random starts' seed.
        t_final, transient: each run's length and the start of its window [s] (default
            transient: t_final/2).
        seed_rounds: rounds of runs from the neighbours' attractors (0: none).
        extend: a run without a periodic orbit is run again from its last slip, ``extend`` times
            as long (1: not), before its exponents are computed.
        boundary_tol: the width to which each boundary is bracketed [m/s] (None: not located).
        branch_tol: how far (relative slip force) an attractor may move between neighbouring V
            and still continue a branch.
        lyapunov: label runs without a periodic orbit by their Lyapunov exponents (else *irregular*).
        lyapunov_time, chaos_threshold: the exponents' averaging time [s] and the smallest λ₁
            [1/s] called chaotic (beyond three standard errors).
        orbit_rtol: the tolerance of the periodic orbits' runs.
        progress: a line on stderr per round.
        **sweep_kwargs: options of :func:`peeljax.sweep` (``rtol``, ``atol``, ``max_steps``,
            ``devices``, ``lane_batch``, ``max_jumps``, …).

    Returns:
        An :class:`AttractorMap`.

    Raises:
        ValueError: bad input, named with its allowed range, before anything is compiled.
    """
    begin = time.perf_counter()
    model, grid, t_final, transient, boundary_tol = check_attractor_map_options(
        model, V, random_starts, seed, t_final, transient, seed_rounds, extend, boundary_tol, branch_tol,
        lyapunov_time, chaos_threshold, orbit_rtol, sweep_kwargs,
    )  # fmt: skip
    options = {"orbit_rtol": float(orbit_rtol), "branch_tol": float(branch_tol), "t_final": t_final,
               "extend": float(extend), "sweep_kwargs": sweep_kwargs, "lyapunov": bool(lyapunov),
               "lyapunov_time": float(lyapunov_time), "chaos_threshold": float(chaos_threshold)}  # fmt: skip
    say = _progress(progress, begin)
    options["say"] = say

    m = grid.size
    v_top = _top_of_stick_branch(fold_table(model, grid)["v_max"], grid)
    R = float(model.R)
    draws = _random_draws(random_starts, seed)
    # Round 1: rest, steady and the random starts at every V.
    js = np.tile(np.arange(m), 2 + random_starts)
    rest = np.stack([np.asarray(model.initial_state(V)) for V in grid])
    steady = _steady_states(model, grid)
    randoms = [_consistent(model, grid, np.full(m, a), w * grid / R, s * v_top) for a, w, s in draws]
    y0 = np.concatenate([rest, steady, *randoms])
    random = np.arange(js.size) >= 2 * m
    say(f"{js.size} runs from rest, steady peeling and {random_starts} random starts at {m} values of V")
    rounds = [int(js.size)]
    attractors: dict[int, list[_Attractor]] = {}
    lanes = _run(model, grid[js], y0, t_final, transient, sweep_kwargs)
    _merge(attractors, _classify(model, grid, js, y0, lanes, options), random)

    # Seeds from the neighbours, until a round finds nothing new.
    fresh = {id(a) for found in attractors.values() for a in found}
    for _ in range(seed_rounds):
        seeds_j, seeds_y = [], []
        for j in range(m):
            for a in [a for k in (j - 1, j + 1) for a in attractors.get(k, []) if id(a) in fresh]:
                if a.kind in (STEADY, UNRESOLVED, UNSTABLE) or not np.all(np.isfinite(a.state)):
                    continue
                if any((b.kind, b.slips) == (a.kind, a.slips) for b in attractors.get(j, [])):
                    continue
                seeds_j.append(j)
                seeds_y.append(_moved(model, a.state, v_top[a.j], grid[j], v_top[j]))
        if not seeds_j:
            break
        js = np.asarray(seeds_j)
        say(f"{js.size} runs from the neighbours' attractors")
        rounds.append(int(js.size))
        y0 = np.stack(seeds_y)
        lanes = _run(model, grid[js], y0, t_final, transient, sweep_kwargs)
        new = _merge(attractors, _classify(model, grid, js, y0, lanes, options), np.zeros(js.size, bool))
        fresh = {id(a) for a in new}
        if not new:
            break

    _link(attractors, m, branch_tol)
    boundaries = _boundaries(model, grid, v_top, attractors, boundary_tol, t_final, transient, sweep_kwargs,
                             options, say, rounds) if boundary_tol is not None else None  # fmt: skip
    return _result(grid, attractors, boundaries, random_starts, t_final, transient, rounds, begin, {
        "random_starts": random_starts, "seed": seed, "t_final": t_final, "transient": transient,
        "seed_rounds": seed_rounds, "boundary_tol": boundary_tol,
        **{k: v for k, v in options.items() if k not in ("sweep_kwargs", "say")},
        "sweep": {k: v for k, v in sweep_kwargs.items() if k != "devices"},
    })  # fmt: skip


def check_attractor_map_options(
    model, V, random_starts, seed, t_final, transient, seed_rounds, extend, boundary_tol, branch_tol, lyapunov_time,
    chaos_threshold, orbit_rtol, sweep_kwargs,
) -> tuple:  # fmt: skip
    """:func:`attractor_map`'s own checks, nothing compiled: (model, V, t_final, transient, boundary_tol)."""
    model = PeelingModel() if model is None else model
    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    grid = _check_grid(V)
    for name, value in (("random_starts", random_starts), ("seed_rounds", seed_rounds), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
    t_final = _positive("t_final", t_final)
    transient = t_final / 2 if transient is None else float(transient)
    if not 0 <= transient < t_final:
        raise ValueError(f"transient must lie in [0, t_final) = [0, {t_final:g}), got {transient!r}")
    if boundary_tol is not None:
        boundary_tol = _positive("boundary_tol", boundary_tol)
    if not float(extend) >= 1:
        raise ValueError(f"extend must be >= 1, got {extend!r}")
    for name, value in (("branch_tol", branch_tol), ("lyapunov_time", lyapunov_time), ("orbit_rtol", orbit_rtol)):
        _positive(name, value)
    if not float(chaos_threshold) >= 0:
        raise ValueError(f"chaos_threshold must be >= 0, got {chaos_threshold!r}")
    own = sorted(set(sweep_kwargs) & {"V", "tau", "t_final", "grid", "start", "window", "chunk", "progress", "out"})
    if own:
        raise ValueError(f"attractor_map sets {', '.join(own)} itself")
    return model, grid, t_final, transient, boundary_tol


def _boundaries(model, grid, v_top, attractors, tol, t_final, transient, sweep_kwargs, options, say, rounds) -> dict:
    """Locate every branch end inside the grid, all in the same rounds (module docstring, 6)."""
    ends = []  # [branch attractor (inside), V_inside, V_outside, seed state, v_top of the seed's V, became]
    by_branch: dict[int, list[_Attractor]] = {}
    for j in sorted(attractors):
        for a in attractors[j]:
            by_branch.setdefault(a.branch, []).append(a)
    exact = []  # [branch attractor, V_stable, V_unstable, kind]: steady ends from the linearisation
    for members in by_branch.values():
        if not (members[0].kind == STEADY or (members[0].kind == PERIODIC and members[0].slips)):
            continue  # a bisection's runs get no exponents: only what a run alone tells apart is bisected
        first, last = members[0], members[-1]
        for a, outside in ((first, first.j - 1), (last, last.j + 1)):
            if not 0 <= outside < grid.size:
                continue
            if a.kind == STEADY:
                end = _steady_end(model, grid[min(a.j, outside)], grid[max(a.j, outside)], a.j < outside, tol)
                if end is not None:
                    exact.append([a, *end])
                    continue
            ends.append([a, float(grid[a.j]), float(grid[outside]), a.state, float(v_top[a.j]), None])
    orbit_ends = [e for e in ends if e[0].kind == PERIODIC]
    _bisect_orbits(model, orbit_ends, tol, t_final, transient, sweep_kwargs, options, say, rounds)
    # Steady ends the linearisation does not place (none on the paper's φ): bisected by runs from
    # steady peeling, the first round at the outside end itself (the confirming run there).
    ends = [e for e in ends if e[0].kind == STEADY]
    first_round, frozen = True, set()
    while ends:
        todo = [e for e in ends if id(e) not in frozen and (first_round or abs(e[2] - e[1]) > tol)]
        if not todo:
            break
        Vs = np.asarray([e[2] if first_round else 0.5 * (e[1] + e[2]) for e in todo])
        say(f"{len(todo)} runs bisecting the ends of steady peeling")
        rounds.append(len(todo))
        y0 = _steady_states(model, Vs)
        lanes = _run(model, Vs, y0, t_final, transient, sweep_kwargs)
        found = _classify_free(model, Vs, y0, lanes, options | {"lyapunov": False, "extend": 1.0})
        for e, a, V in zip(todo, found, Vs):
            if a.kind == UNRESOLVED:  # a run that stopped says nothing: the bracket stays where it is
                e[5] = e[5] if e[5] is not None else "stopped"
                frozen.add(id(e))
            elif a.near(e[0], options["branch_tol"]):
                e[1], e[2], e[5] = (e[1], e[1], "kept") if first_round else (float(V), e[2], e[5])
            else:
                e[2], e[5] = float(V), a
        first_round = False
    ends = ends + orbit_ends
    out = {k: [] for k in BOUNDARY_FIELDS}
    for branch, V_in, V_out, kind in exact:
        out["branch"].append(branch.branch)
        out["V_inside"].append(V_in)
        out["V_outside"].append(V_out)
        out["change"].append(f"steady peeling ends ({_STEADY_END[kind]})")
        out["becomes_kind"].append(-1)
        out["becomes_slips"].append(0)
    for branch, V_in, V_out, _, _, became in ends:
        if became == "kept":  # the seed kept its attractor at the neighbour: no boundary
            continue
        out["branch"].append(branch.branch)
        out["V_inside"].append(V_in)
        out["V_outside"].append(V_out)
        out["change"].append(_change(branch, became))
        known = isinstance(became, _Attractor)
        out["becomes_kind"].append(became.kind if known else -1)
        out["becomes_slips"].append(became.slips if known else 0)
    return {k: np.asarray(v, str if k == "change" else (int if k in ("branch", "becomes_kind", "becomes_slips") else float))
            for k, v in out.items()}  # fmt: skip


def _bisect_orbits(model, ends, tol, t_final, transient, sweep_kwargs, options, say, rounds) -> None:
    """Locate the ends of periodic branches by Newton on the branch's orbit, continued from the
    inside towards the neighbouring grid value with step halving (no runs): a step lands where the
    orbit of the branch's k converges, stable, its period continuous to ``branch_tol``; a failure
    halves the step, and one from farther than ``_TRUSTED_STEP`` is tried again from the next
    orbit. Then a run from the last orbit at each outside end names what it becomes; where that
    run finds the branch's orbit after all (Newton lost it, the orbit goes on), the continuation
    goes on from there."""
    work = [{"end": e, "V": e[1], "state": e[3], "T": e[0].period, "step": e[2] - e[1], "fail": None} for e in ends]
    for _ in range(1 + _RESTARTS):
        _continue_orbits(model, [w for w in work if "became" not in w], tol, options, say, rounds)
        named = [w for w in work if "became" not in w and w["fail"] is not None]
        if not named:
            break
        Vs = np.asarray([w["fail"] for w in named])
        both = np.concatenate([Vs, [w["V"] for w in named]])  # the outside ends, then the inside ones
        tops, tops_in = np.split(_top_of_stick_branch(fold_table(model, both)["v_max"], both), 2)
        y0 = np.stack([_moved(model, w["state"], t_in, V, top) for w, t_in, V, top in zip(named, tops_in, Vs, tops)])
        say(f"{len(named)} runs beyond the boundaries")
        rounds.append(len(named))
        lanes = _run(model, Vs, y0, t_final, transient, sweep_kwargs)
        found = _classify_free(model, Vs, y0, lanes, options | {"lyapunov": False, "extend": 1.0})
        for w, a in zip(named, found):
            branch = w["end"][0]
            if a.kind == PERIODIC and a.slips == branch.slips and _continuous(a.period, w["T"], options):
                # The branch's orbit, stable, where Newton lost it: on from the run's orbit.
                w.update(V=w["fail"], state=a.state, T=a.period, fail=None, step=w["end"][2] - w["fail"])
                continue
            status, mu1, T = w["newton"]
            if status == 0 and mu1 >= 1.0 and a.kind != UNRESOLVED:
                a.kind, a.slips, a.period, a.multiplier = UNSTABLE, branch.slips, T, mu1
            w["became"] = "stopped" if a.kind == UNRESOLVED else a
    for w in work:
        e = w["end"]
        if w["fail"] is None:
            e[1], e[5] = e[2], "kept"  # the orbit continued to the neighbouring grid value
        else:  # the change is named against the orbit at the bracket's inside end
            e[0] = dataclasses.replace(e[0], period=w["T"])
            e[1], e[2], e[3], e[5] = w["V"], w["fail"], w["state"], w.get("became", "stopped")


def _continue_orbits(model, work: list[dict], tol, options, say, rounds) -> None:
    """:func:`_bisect_orbits`' rounds of Newton, every unfinished end in one batch per round."""
    while True:
        todo = [w for w in work if (w["fail"] is None and abs(w["V"] - w["end"][2]) > 1e-12)
                or (w["fail"] is not None and abs(w["fail"] - w["V"]) > tol)]  # fmt: skip
        if not todo:
            return
        Vs = np.asarray([_next_try(w) for w in todo])
        say(f"{len(todo)} orbits continued towards the boundaries")
        rounds.append(len(todo))
        orbits = _padded_orbits(
            model, Vs, np.stack([w["state"] for w in todo]), np.asarray([w["end"][0].slips for w in todo], np.int64),
            np.asarray([w["T"] for w in todo]), options["orbit_rtol"], max_iterations=_BISECTION_ITERATIONS,
        )  # fmt: skip
        mu1 = np.abs(orbits["multipliers"]).max(axis=1)
        T = np.asarray(orbits["period"], float)
        for i, w in enumerate(todo):
            if orbits["status"][i] == 0 and mu1[i] < 1.0 and _continuous(T[i], w["T"], options):
                w.update(V=float(Vs[i]), state=orbits["state"][i], T=float(T[i]))
                if w["fail"] is not None:
                    left = w["fail"] - w["V"]
                    if abs(left) <= 1e-12 or np.sign(left) != np.sign(w["step"]):
                        w["fail"] = None  # the failure was the start's, not the orbit's: on to the grid value
                    else:  # a failure from close by stands (bisect); one from far away is tried again
                        w["step"] = 0.5 * left if w["trusted"] else left
            else:
                w.update(fail=float(Vs[i]), step=0.5 * w["step"], trusted=abs(w["step"]) <= _TRUSTED_STEP)
                w["newton"] = (int(orbits["status"][i]), float(mu1[i]), float(T[i]))


def _continuous(T: float, T_branch: float, options) -> bool:
    """A period that continues the branch's (to ``branch_tol``, relative)."""
    return abs(T - T_branch) <= options["branch_tol"] * T_branch


def _next_try(w: dict) -> float:
    """The next V of a continued end: a step from its last orbit, never past the grid value."""
    V_grid = w["end"][2]
    if w["fail"] is None and abs(w["step"]) >= abs(V_grid - w["V"]) - 1e-12:
        return V_grid
    return w["V"] + w["step"]


_BISECTION_ITERATIONS = 8
_RESTARTS = 2  # continuations resumed where a run found the orbit Newton had lost
_TRUSTED_STEP = 2e-3  # m/s: Newton from an orbit this close converges where the orbit goes on (measured)


def _steady_end(model, V_lo: float, V_hi: float, stable_below: bool, tol: float) -> tuple[float, float, str] | None:
    """The end of a steady branch between two grid values from the linearisation
    (:func:`peeljax.steady.steady_peeling_ends`): (V_stable, V_unstable, kind), bracketed to
    ``min(tol, 1e-8)``; None where the linearisation does not put it there (then it is bisected
    by runs)."""
    stable, V_stable, V_unstable, kinds = steady_peeling_ends(model, np.array([V_lo, V_hi]), xtol=min(tol, 1e-8))
    if kinds and bool(stable[0]) == stable_below:
        return float(V_stable[0]), float(V_unstable[0]), kinds[0]
    return None


def _family(a: _Attractor) -> tuple[int, int]:
    """What a bisection compares: steady, periodic with k, or stick-slip without an orbit."""
    return (a.kind, a.slips) if a.kind in (STEADY, PERIODIC, UNRESOLVED, UNSTABLE) else (IRREGULAR, 0)


def _classify_free(model, Vs, y0, lanes, options) -> list[_Attractor]:
    """:func:`_classify` for lanes at V off the grid (each lane its own V)."""
    return _classify(model, Vs, np.arange(Vs.size), y0, lanes, options)


def _result(grid, attractors, boundaries, random_starts, t_final, transient, rounds, begin, settings) -> AttractorMap:
    rows = [a for j in sorted(attractors) for a in attractors[j]]
    n = len(rows)
    fields = {name: np.zeros(n, int if name in _INT_FIELDS else float) for name in ATTRACTOR_FIELDS}
    for i, a in enumerate(rows):
        p = a.random_hits / random_starts if random_starts else math.nan
        values = {
            "V_index": a.j, "V": grid[a.j], "kind": a.kind, "slips": a.slips, "period": a.period,
            "multiplier": a.multiplier, "lyapunov": a.lyapunov[0], "lyapunov_2": a.lyapunov[1],
            "lyapunov_se": a.lyapunov[2], "G_slip_max": a.lanes.get("G_slip_max", math.nan),
            "G_stick_min": a.lanes.get("G_stick_min", math.nan), "slip_interval": a.lanes.get("slip_interval", math.nan),
            "stick_fraction": a.lanes.get("stick_fraction", math.nan), "v_mean": a.lanes.get("v_mean", math.nan),
            "hits": a.hits, "basin": p, "basin_se": math.sqrt(p * (1 - p) / random_starts) if random_starts else math.nan,
            "branch": a.branch,
        }  # fmt: skip
        for name, value in values.items():
            fields[name][i] = value
    state = np.stack([a.state for a in rows]) if rows else np.zeros((0, 4))
    if boundaries is None:
        boundaries = {k: np.zeros(0, int if k in ("branch", "becomes_kind", "becomes_slips") else float) for k in BOUNDARY_FIELDS}
        boundaries["change"] = np.zeros(0, str)
    return AttractorMap(
        grid_V=grid, fields=fields, state=state, boundaries=boundaries, random_starts=random_starts,
        t_final=t_final, transient=transient, settings=settings, rounds=tuple(rounds),
        wall_time=time.perf_counter() - begin,
    )  # fmt: skip


def _progress(on: bool, begin: float):
    """A line on stderr with the elapsed time (nothing when not ``on``)."""
    if not on:
        return lambda text: None
    return lambda text: print(f"attractor map [{time.perf_counter() - begin:6.1f} s]: {text}", file=sys.stderr)


def _positive(name: str, value) -> float:
    if isinstance(value, bool) or np.ndim(value) != 0:
        raise TypeError(f"{name} must be one real number, got {value!r}")
    check_positive(name, value)
    return float(value)


def _check_grid(V) -> np.ndarray:
    grid = np.atleast_1d(np.asarray(V, float))
    if grid.ndim != 1 or grid.size == 0:
        raise ValueError(f"V must be a number or a 1-d array of pull velocities, got shape {grid.shape}")
    check_positive("V", grid)
    if np.any(np.diff(grid) <= 0):
        raise ValueError("V must be increasing")
    return grid
