"""The bifurcation diagram of stick-slip orbits over V: seeds from runs, branches by continuation.

A run from a start (the tape at rest, the paper's; or steady peeling) settles on an attractor;
where it repeats, its orbit is shot (:func:`peeljax.periodic_orbit`) — a *seed*. Every seed not
already on a traced branch is continued over V both ways (:func:`continue_orbit`), and every
branch end that is a bifurcation seeds the branch beyond it:

* a grazing where a slip appears (or vanishes): the orbit with k + 1 (k − 1) slips per
  period, shot just past the grazing point from the same section point;
* a period doubling: the orbit with 2k slips, shot from the orbit displaced along the
  multiplier −1's eigenvector on the side where it exists.

The diagram holds the branches (stable and unstable parts), every bifurcation located on them,
the seeds with the branch each lies on, and the runs' own statistics (what a brute-force map
shows) for comparison.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._validation import check_positive
from ..model import PAPER_ALPHA0, PeelingModel
from ..simulate import simulate
from .api import DEFAULT_ORBIT_RTOL, OrbitNotFound, phi_has_folds, compiled_orbit, least_period, orbit_shooting, start_from_run
from ..saved import register_reader
from .continuation import Bifurcation, BifurcationKind, OrbitBranch, continue_orbit
from .files import DIAGRAM_KIND, diagram_parts, write_diagram
from .section import SlipSection
from .shooting import OrbitStatus

__all__ = ["OrbitDiagram", "Seed", "orbit_diagram", "read_diagram"]

STARTS = ("paper", "steady")
_SWITCH_STEP = 2e-4  # [m/s]: a branch beyond a bifurcation is shot this far past it
_ON_BRANCH = 1e-3  # an orbit within this of a branch lies on it (in :func:`_invariants`' units)


@dataclasses.dataclass(frozen=True)
class Seed:
    """A run's attractor at one V and start, and what became of it.

    Attributes:
        V: pull velocity [m/s]; start: ``"paper"`` or ``"steady"``.
        slips: k of its repeat (0: none found); period: the repeat's T [s] (NaN: none).
        F_slip, F_stick: the run's mean tension at its slips and re-sticks over its second half [N]
            (what a brute-force map shows).
        interval: the run's mean time between slips over its second half [s].
        orbit: the orbit's status name where one was shot, else why not.
        branch: the index of the branch it lies on (-1: none).
    """

    V: float
    start: str
    slips: int
    period: float
    F_slip: float
    F_stick: float
    interval: float
    orbit: str
    branch: int = -1


@dataclasses.dataclass
class OrbitDiagram:
    """Stick-slip orbits over V (module docstring).

    Attributes:
        V_range: the range of V covered [m/s].
        branches: the traced branches (:class:`OrbitBranch`).
        seeds: the runs' attractors (:class:`Seed`).
        wall_time: seconds in all; seed_time: of which the seeds' runs and orbits.
        complete: False for the part of a diagram finished before it was interrupted (what
            :func:`orbit_diagram`'s ``on_progress`` receives, and a file written from it).
    """

    V_range: tuple[float, float]
    branches: list[OrbitBranch]
    seeds: list[Seed]
    wall_time: float = math.nan
    seed_time: float = math.nan
    complete: bool = True

    @property
    def bifurcations(self) -> list[tuple[int, Bifurcation]]:
        """(branch index, bifurcation) for every bifurcation located, in V order."""
        found = [(i, b) for i, branch in enumerate(self.branches) for b in branch.bifurcations]
        return sorted(found, key=lambda ib: ib[1].V)

    def covered(self) -> tuple[int, int]:
        """(periodic seeds on a traced branch, periodic seeds)."""
        periodic = [s for s in self.seeds if s.slips > 0 and s.orbit == "converged"]
        return sum(s.branch >= 0 for s in periodic), len(periodic)

    def save(self, path) -> None:
        """Write the diagram to ``path`` (``.npz``, :mod:`peeljax.orbits.files`);
        :func:`peeljax.load` reads it back."""
        write_diagram(path, self)

    def as_dict(self) -> dict:
        """The diagram as JSON-able numbers: ``V_range``; per branch its k (slips per period), V range,
        orbits, stable orbits and how it ends; each bifurcation (branch index, kind, V, k, note); the
        seed runs (``runs``, ``periodic``, ``on_a_branch``); ``wall_time_s``."""
        on, periodic = self.covered()
        return {
            "V_range": list(self.V_range),
            "branches": [
                {"slips": sorted({int(k) for k in b.slips}), "V_min": float(b.V.min()), "V_max": float(b.V.max()),
                 "points": len(b), "stable_points": int(b.stable.sum()), "ends": b.ends}
                for b in self.branches
            ],
            "bifurcations": [
                {"branch": i, "kind": b.kind.value, "V": b.V, "slips": b.slips, "note": b.note} for i, b in self.bifurcations
            ],
            "seeds": {"runs": len(self.seeds), "periodic": periodic, "on_a_branch": on},
            "wall_time_s": self.wall_time,
        }  # fmt: skip

    def summary(self) -> str:
        """:meth:`__str__`'s table, then each branch (k, V range, orbits, stable ones) with its bifurcations."""
        lines = [str(self)]
        for i, branch in enumerate(self.branches):
            ks = ", ".join(str(k) for k in sorted({int(k) for k in branch.slips}))
            lines.append(
                f"branch {i}: {ks} slips per period, V in [{branch.V.min():.6g}, {branch.V.max():.6g}] m/s, "
                f"{len(branch)} orbits ({int(branch.stable.sum())} stable)"
            )
            lines += [f"  {b}" for b in branch.bifurcations]
        return "\n".join(lines)

    def __str__(self) -> str:
        on, periodic = self.covered()
        kinds = {}
        for _, b in self.bifurcations:
            kinds[b.kind.value] = kinds.get(b.kind.value, 0) + 1
        lines = [
            f"orbit diagram over V in [{self.V_range[0]:g}, {self.V_range[1]:g}] m/s: {len(self.branches)} branches, "
            f"{sum(len(b) for b in self.branches)} orbits, {self.wall_time:.1f} s"
            + ("" if self.complete else " (incomplete: interrupted, what was finished before)"),
            f"  seeds: {len(self.seeds)} runs, {periodic} periodic, {on} of them on a traced branch",
            "  bifurcations: " + (", ".join(f"{n} {k}" for k, n in kinds.items()) or "none"),
        ]
        return "\n".join(lines)


def _steady_state(model: PeelingModel, V: float):
    return model.consistent_state(V, PAPER_ALPHA0, V / model.R, V)


def _run_statistics(sol) -> tuple[float, float, float]:
    """(mean F at slips, at re-sticks, mean time between slips) over the run's second half."""
    jumps = sol.jumps.as_numpy()
    t_end = float(sol.t_stop)
    inside = jumps["jump_t"] >= 0.5 * t_end
    up = jumps["jump_up"] & inside
    down = ~jumps["jump_up"] & inside
    F = jumps.get("jump_F", np.full_like(jumps["jump_t"], np.nan))
    slip_times = jumps["jump_t"][up]
    interval = float(np.mean(np.diff(slip_times))) if len(slip_times) > 1 else math.nan
    F_slip = float(np.mean(F[up])) if np.any(up) else math.nan
    F_stick = float(np.mean(F[down])) if np.any(down) else math.nan
    return F_slip, F_stick, interval


def _invariants(V, period, F_mean) -> np.ndarray:
    """What identifies an orbit whichever of its k section crossings it was shot from: V, T and
    the mean force, in units of about 1 (m/s, 0.2 s, 200 N)."""
    return np.column_stack([np.atleast_1d(V), np.atleast_1d(period) / 0.2, np.atleast_1d(F_mean) / 200.0])


def _distance_to_branch(branch: OrbitBranch, orbit) -> float:
    """The distance of an orbit to the branch's polyline of orbits with its k, in invariants."""
    slips = int(orbit.slips)
    same = branch.slips == slips
    if not np.any(same):
        return math.inf
    pts = _invariants(branch.V, branch.period, branch.statistics["F_mean"])
    q = _invariants(float(orbit.V), float(orbit.period), float(orbit.statistics["F_mean"]))[0]
    best = math.inf
    for i in range(len(pts)):
        if not same[i]:
            continue
        best = min(best, float(np.linalg.norm(pts[i] - q)))
        if i + 1 < len(pts) and same[i + 1]:
            a, b = pts[i], pts[i + 1]
            u = b - a
            t = float(np.clip(np.dot(q - a, u) / max(np.dot(u, u), 1e-300), 0.0, 1.0))
            best = min(best, float(np.linalg.norm(a + t * u - q)))
    return best


def orbit_diagram(
    model: PeelingModel | None = None,
    V: ArrayLike = (0.3, 5.4),
    *,
    seeds: int | Sequence[float] = 52,
    starts: Sequence[str] = STARTS,
    t_final: float = 6.0,
    rtol: float = DEFAULT_ORBIT_RTOL,
    max_branches: int = 200,
    ds_max: float = 0.05,
    progress: bool = True,
    on_progress: Callable[[OrbitDiagram], None] | None = None,
) -> OrbitDiagram:
    """The stick-slip orbits over V: seeds from runs, branches by continuation (module docstring).

    Args:
        model: the model (default: the paper's).
        V: (V_min, V_max) [m/s], 0 < V_min < V_max: the range the branches are followed in.
        seeds: the number of equally spaced V of the seed runs, or the V themselves.
        starts: the runs' starts, ``"paper"`` (the tape at rest) and/or ``"steady"``.
        t_final: the seed runs' length [s] (their repeat is looked for in the second half).
        rtol: the tolerance of the orbits' runs.
        max_branches: at most this many branches are traced.
        ds_max: the largest continuation step (scaled coordinates).
        progress: a line on stderr per branch.
        on_progress: called with the diagram finished so far (``complete=False``: the seeds run
            so far, then every branch traced so far) after each seed's V and each branch, e.g.
            to save it, so that an interruption (Ctrl-C) keeps what was finished.
    """
    import sys

    model = PeelingModel() if model is None else model
    V_lo, V_hi = (float(v) for v in np.asarray(V, float).ravel()[[0, -1]])
    check_positive("V", V_lo)
    if not V_lo < V_hi:
        raise ValueError(f"V must be (V_min, V_max) with 0 < V_min < V_max, got {V!r}")
    for start in starts:
        if start not in STARTS:
            raise ValueError(f"starts must be among {STARTS}, got {start!r}")
    check_positive("t_final", t_final)
    seed_V = np.linspace(V_lo, V_hi, seeds) if isinstance(seeds, int) else np.asarray(seeds, float)
    say = (lambda line: print(line, file=sys.stderr, flush=True)) if progress else (lambda line: None)
    began = time.perf_counter()
    shooting = orbit_shooting(rtol=rtol)

    # 1. Seeds: each run's attractor, and its orbit where it repeats.
    found: list[tuple[Seed, object]] = []

    def so_far(branches, complete=False, seed_time=math.nan) -> OrbitDiagram:
        return OrbitDiagram((V_lo, V_hi), list(branches), _on_branches(found, branches), time.perf_counter() - began,
                            seed_time, complete)  # fmt: skip

    def report(branches, seed_time=math.nan) -> None:
        if on_progress is not None:
            on_progress(so_far(branches, seed_time=seed_time))

    for v in seed_V:
        folds = bool(phi_has_folds(model, jnp.asarray(v)))
        for start in starts:
            y0 = None if start == "paper" else _steady_state(model, float(v))
            sol = simulate(model, V=float(v), tau=0, t_final=t_final, y0=y0)
            F_slip, F_stick, interval = _run_statistics(sol)
            orbit, why = None, "no fold of phi" if not folds else ""
            slips, period = 0, math.nan
            if folds:
                try:
                    s0, slips, period = start_from_run(sol)
                    orbit = compiled_orbit(shooting, model, jnp.asarray(v), jnp.asarray(s0), jnp.asarray(slips, jnp.int32),
                                   jnp.asarray(3.0 * period))  # fmt: skip
                    orbit = least_period(shooting, orbit)
                    why = orbit.status_name
                except OrbitNotFound as error:
                    why = str(error).removeprefix("start: ")
            found.append((Seed(float(v), start, slips, period, F_slip, F_stick, interval, why), orbit))
        report([])
    seed_time = time.perf_counter() - began
    say(f"seeds: {len(found)} runs in {seed_time:.1f} s, {sum(o is not None and o.converged for _, o in found)} orbits")

    # 2. Branches from every seed not on one yet, and from the bifurcations that end them.
    branches: list[OrbitBranch] = []
    queue = [orbit for _, orbit in found if orbit is not None and bool(orbit.converged)]
    while queue and len(branches) < max_branches:
        orbit = queue.pop(0)
        k = int(orbit.slips)
        if any(_distance_to_branch(b, orbit) < _ON_BRANCH for b in branches):
            continue
        branch = continue_orbit(orbit, bounds=(V_lo, V_hi), ds_max=ds_max, rtol=rtol)
        branches.append(branch)
        say(f"branch {len(branches) - 1}: {k} slips per period, V in [{branch.V.min():.5g}, {branch.V.max():.5g}], "  # (0-based: diagram.branches[i])
            f"{len(branch)} orbits, {len(branch.bifurcations)} bifurcations")  # fmt: skip
        report(branches, seed_time)
        for b in branch.bifurcations:
            queue.extend(_beyond(b, model, shooting))
    return so_far(branches, complete=True, seed_time=seed_time)


def _on_branches(found: list, branches: list[OrbitBranch]) -> list[Seed]:
    """The seeds, each with the index of the branch its orbit lies on (-1: none)."""
    seeds_out = []
    for seed, orbit in found:
        index = -1
        if orbit is not None and bool(orbit.converged):
            distances = [_distance_to_branch(b, orbit) for b in branches]
            if distances and min(distances) < _ON_BRANCH:
                index = int(np.argmin(distances))
        seeds_out.append(dataclasses.replace(seed, branch=index))
    return seeds_out


def _beyond(b: Bifurcation, model: PeelingModel, shooting) -> list:
    """The orbits just past a bifurcation that start new branches (module docstring)."""
    V = b.V
    section = np.asarray(b.section)
    sc = np.asarray(SlipSection.at(model, V).scale)
    t_max = 3.0 * b.period * 2  # (a doubled orbit takes twice as long)
    shots = []
    if b.kind in (BifurcationKind.NEW_SLIP, BifurcationKind.LOST_SLIP):
        k = b.slips + (1 if b.kind == BifurcationKind.NEW_SLIP else -1)
        if k >= 1:
            shots.append((V + b.direction * _SWITCH_STEP, section, k))
    elif b.kind == BifurcationKind.PERIOD_DOUBLING and len(b.monodromy) == 4:
        M = np.asarray(b.monodromy).reshape(2, 2)
        values, vectors = np.linalg.eig(M)
        v = np.real(vectors[:, int(np.argmin(np.abs(values + 1)))])
        for side in (1, -1):
            for sign in (1, -1):
                shots.append((V + side * _SWITCH_STEP, section + sign * 1e-3 * sc * v / np.linalg.norm(v), 2 * b.slips))
    out = []
    for v, s, k in shots:
        if not bool(phi_has_folds(model, jnp.asarray(v))):
            continue
        orbit = compiled_orbit(shooting, model, jnp.asarray(v), jnp.asarray(s), jnp.asarray(k, jnp.int32), jnp.asarray(t_max))
        if int(orbit.status) != OrbitStatus.CONVERGED:
            continue
        # Past a period doubling Newton may return to the k-orbit run twice: not a new orbit.
        if b.kind == BifurcationKind.PERIOD_DOUBLING and np.max(np.abs(np.asarray(orbit.section) - section) / sc) < 1e-5:
            continue
        out.append(orbit)
    return out


def read_diagram(arrays: dict, name: str) -> OrbitDiagram:
    """The :class:`OrbitDiagram` of a diagram file's arrays (:func:`peeljax.load`)."""
    V_range, branches, seeds, wall, seed_time, complete = diagram_parts(arrays, name)
    try:
        branches = [
            OrbitBranch(**{**fields, "bifurcations": [Bifurcation(BifurcationKind[kind], *rest) for kind, *rest in fields["bifurcations"]]})
            for fields in branches
        ]  # fmt: skip
    except KeyError as error:
        raise ValueError(f"{name!r} is malformed: not an orbit diagram's arrays (no bifurcation kind {error})") from None
    return OrbitDiagram(V_range, branches, [Seed(*fields) for fields in seeds], wall, seed_time, complete)


register_reader(DIAGRAM_KIND, npz=read_diagram)
