"""Continuation of stick-slip orbits over a parameter: a branch of periodic orbits, its
stability, and the bifurcations that end or change it.

A branch is a curve of solutions X = (z, λ) of r(z; λ) = P^k(z; λ) − z = 0 (z the scaled
section coordinates, :mod:`peeljax.orbits.shooting`; λ the pull velocity V or a coefficient of
φ, scaled by its start value). It is followed by pseudo-arclength continuation (Keller), as
AUTO and COCO do: from a point X_i with unit tangent t_i (the null vector of the 2 × 3
Jacobian [∂r/∂z, ∂r/∂λ], the cross product of its rows), predict X_i + Δs·t_i and correct by
Newton's method on

    r(X) = 0,   t_i·(X − X_i − Δs·t_i) = 0,

each iteration one forward-mode pass through one period with three tangents (the two section
directions and λ). The step Δs grows after quick corrections and halves after failed ones;
folds are passed by the arclength, so the unstable side of a branch is followed as well.

Along the branch every point carries its Floquet multipliers (:mod:`peeljax.orbits.floquet`)
and the test functions are watched for sign changes between consecutive points, each then
located by the secant method on the branch (re-corrected points between the two):

* a **fold of cycles** — the tangent's λ-component changes sign (a multiplier through +1):
  a stable and an unstable orbit meet and vanish, the edge of a parameter range where an
  orbit exists (the ends of coexistence intervals);
* **period doubling** — det(M + I) changes sign (a multiplier through −1): the orbit with 2k
  slips branches off, shot from the orbit displaced along the −1 eigenvector (COCO's
  branch switching) and traced as a new branch;
* a **torus** (Neimark–Sacker) — det M − 1 changes sign while the multipliers are complex;
* a **change in the number of slips per period** — the orbit grazes φ's fold: a stick phase's
  G touches φ(v̂) without slipping (``approach`` → 0: a new slip appears past it), or a slip's
  crossing of the section becomes tangential (``crossing`` → 0: a slip vanishes). The branch
  with k ± 1 slips starts there, as a new branch;
* the **end of stick-slip** — the run from the section no longer comes back through k slips
  (the orbit shrank onto steady peeling or φ lost its fold): the branch ends, located by
  halving the step to its minimum.

Each step is one compiled call (the same program for every k and every point: k and λ are
traced); the loop over steps runs on the host, as AUTO's does.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import time
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..cycles import STATISTICS
from .._exported import compiled
from .api import PERIODS_PER_RUN, DEFAULT_ORBIT_RTOL, orbit_shooting
from .floquet import multipliers
from .orbit import PeriodicOrbit
from .period import OnePeriod, period_statistics
from .section import SlipSection
from .shooting import OrbitStatus, Shooting, linearised

__all__ = ["Bifurcation", "BifurcationKind", "BranchPoint", "OrbitBranch", "continue_orbit", "parameter_leaf"]

_CORRECTOR_ITERATIONS = 6  # from a predictor on the branch Newton needs 2–3
_MOST_MOVED = 0.5  # × the step: the farthest a correction may move off its prediction
_LEAST_ALIGNED = 0.95  # cos of the sharpest turn of the tangent over one step (18°)
_QUICK = 3  # a correction in at most this many iterations lets the step grow
_LOCATE_ITERATIONS = 30


class BifurcationKind(enum.Enum):
    FOLD = "fold of cycles"
    PERIOD_DOUBLING = "period doubling"
    TORUS = "torus"
    NEW_SLIP = "grazing: a slip appears"
    LOST_SLIP = "grazing: a slip vanishes"
    END = "end of the branch"


@dataclasses.dataclass(frozen=True)
class Bifurcation:
    """A bifurcation located on a branch: its kind, where (λ, and V), the orbit's slips per
    period there, and a note (for an end: why the branch ends)."""

    kind: BifurcationKind
    parameter: float
    V: float
    slips: int
    point: int  # the index of the branch point nearest to it (in its direction's list)
    note: str = ""
    direction: int = 1  # the direction the branch was followed in when it was met
    section: tuple[float, float] = (math.nan, math.nan)  # (α, ω) of the orbit there
    monodromy: tuple = ()  # M there (for branch switching), row-major
    period: float = math.nan  # T of the orbit there [s]
    def __str__(self) -> str:
        note = f" ({self.note})" if self.note else ""
        return f"{self.kind.value} at {self.parameter:.6g} with {self.slips} slips per period{note}"


def parameter_leaf(model, V, parameter: str) -> int:
    """The index of ``parameter`` ("V" or a coefficient of φ) among the leaves of (model, V)."""
    paths = jax.tree_util.tree_flatten_with_path((model, jnp.asarray(V, float)))[0]
    if parameter == "V":
        return len(paths) - 1
    for i, (path, _) in enumerate(paths):
        keys = [getattr(k, "name", getattr(k, "key", None)) for k in path]
        if keys[-2:] == ["adhesion", parameter]:
            return i
    names = [getattr(p[-1], "name", "") for p, _ in paths if len(p) >= 2 and getattr(p[-2], "name", "") == "adhesion"]
    raise ValueError(f"parameter must be 'V' or a coefficient of phi ({', '.join(names)}), got {parameter!r}")


class BranchPoint(eqx.Module):
    """A corrected point of a branch (all arrays; batched along a branch).

    Attributes:
        X: (z, λ/λ₀): the scaled section coordinates and the scaled parameter.
        tangent: the unit tangent of the branch there.
        orbit: the orbit there.
        converged: the corrector converged; iterations: its Newton iterations.
    """

    X: Float[Array, "3"]
    tangent: Float[Array, "3"]
    orbit: PeriodicOrbit
    converged: Bool[Array, ""]
    iterations: Int[Array, ""]


def _with_parameter(model, V, leaf: int, value):
    leaves, treedef = jax.tree_util.tree_flatten((model, jnp.asarray(V, float)))
    leaves[leaf] = jnp.asarray(value, float).reshape(jnp.shape(leaves[leaf]))
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _null_vector(A: Float[Array, "2 3"]) -> Float[Array, "3"]:
    t = jnp.cross(A[0], A[1])
    return t / jnp.linalg.norm(t)


def _point(shooting: Shooting, model, V, X, tangent, slips, t_max, scale, previous, *, leaf: int) -> BranchPoint:
    """Newton's method on the augmented system (module docstring) from the prediction X,
    ``previous`` the tangent whose orientation the new one keeps (and the arclength's)."""
    lin = linearised(shooting, model, V, slips, t_max, (leaf,))
    units = jnp.concatenate([jnp.ones(2), jnp.reshape(scale, (1,))])
    X_pred = X

    def evaluate(X):
        jac, r, period = lin.at(X * units)
        columns = [lin.unravel(jac[:, j])[0] for j in range(3)]
        A = jnp.stack(columns, axis=1) * units[None, :]  # ∂r/∂X
        return A, r, period

    def body(c):
        X, _, it, _ = c
        A, r, period = evaluate(X)
        F = jnp.concatenate([r, jnp.reshape(jnp.dot(tangent, X - X_pred), (1,))])
        J = jnp.concatenate([A, tangent[None, :]], axis=0)
        step = -jnp.linalg.solve(J, F)
        step = jnp.where(jnp.all(jnp.isfinite(step)), step, 0.0)
        converged = (jnp.max(jnp.abs(r)) <= shooting.tolerance) & period.reached
        failed = ~period.reached | ~jnp.all(jnp.isfinite(r))
        X_next = jnp.where(converged | failed, X, X + step)
        return X_next, converged, it + 1, failed

    def more(c):
        _, converged, it, failed = c
        return ~converged & ~failed & (it < _CORRECTOR_ITERATIONS)

    X, converged, iterations, _ = jax.lax.while_loop(more, body, (X_pred, jnp.asarray(False), jnp.asarray(0), jnp.asarray(False)))
    A, r, period = evaluate(X)
    new_tangent = _null_vector(A)
    new_tangent = jnp.where(jnp.dot(new_tangent, previous) < 0, -new_tangent, new_tangent)
    m, v = _with_parameter(model, V, leaf, X[2] * scale)
    orbit = _orbit_at(m, v, X[:2], slips, A, r, period, converged, iterations)
    return BranchPoint(X=X, tangent=new_tangent, orbit=orbit, converged=converged, iterations=iterations)


def _orbit_at(model, V, z, slips, A, r, period: OnePeriod, converged, iterations) -> PeriodicOrbit:
    section = SlipSection.at(model, V)
    scale = section.scale
    monodromy = (A[:, :2] + jnp.eye(2)) * scale[:, None] / scale[None, :]
    s = z * scale
    status = jnp.select(
        [~section.folds.exist, ~period.reached, converged],
        [OrbitStatus.NO_FOLD, OrbitStatus.EVENTS_CHANGED, OrbitStatus.CONVERGED],
        OrbitStatus.NOT_CONVERGED,
    ).astype(jnp.int32)
    return PeriodicOrbit(
        model=model, V=jnp.asarray(V, float), slips=jnp.asarray(slips, jnp.int32), section=s, state=section.state(s),
        period=period.time, force_integral=period.force_integral, approach=period.approach, crossing=period.crossing,
        monodromy=monodromy, multipliers=multipliers(monodromy), status=status, run_status=period.status,
        iterations=jnp.asarray(iterations, jnp.int32), residual=jnp.max(jnp.abs(r)), steps=period.steps,
        statistics=period_statistics(period),
    )  # fmt: skip


@functools.lru_cache(maxsize=None)
def _corrector(leaf: int):
    """The compiled corrector for the parameter at ``leaf`` (static: it picks the tangent)."""
    return compiled(functools.partial(_point, leaf=leaf), f"continuation_point[{leaf}]")


@dataclasses.dataclass
class OrbitBranch:
    """A branch of periodic orbits over a parameter (host arrays, one entry per point).

    Attributes:
        parameter: ``"V"`` or the coefficient of φ continued in.
        values: the parameter at each point; V: the pull velocity there.
        slips: k at each point; period: T [s].
        statistics: the five statistics of one period at each point (``F_mean``, …).
        multipliers: the Floquet multipliers (n × 2, complex); stable: max |λ| < 1.
        test_functions: ``fold``, ``period_doubling``, ``torus`` at each point.
        approach, crossing: the grazing monitors (:class:`~peeljax.orbits.PeriodicOrbit`).
        section: (α, ω) on the section at each point.
        bifurcations: what was located on the branch, in the order met.
        ends: why the branch ended, one line per direction followed.
        wall_time: seconds spent.
    """

    parameter: str
    values: np.ndarray
    V: np.ndarray
    slips: np.ndarray
    period: np.ndarray
    statistics: dict[str, np.ndarray]
    multipliers: np.ndarray
    stable: np.ndarray
    test_functions: dict[str, np.ndarray]
    approach: np.ndarray
    crossing: np.ndarray
    section: np.ndarray
    bifurcations: list[Bifurcation]
    ends: list[str]
    wall_time: float = math.nan

    def __len__(self) -> int:
        return len(self.values)

    def __str__(self) -> str:
        lo, hi = (float(np.min(self.values)), float(np.max(self.values))) if len(self) else (math.nan, math.nan)
        ks = sorted({int(k) for k in self.slips})
        lines = [
            f"branch of {len(self)} orbits over {self.parameter} in [{lo:.6g}, {hi:.6g}], "
            f"{', '.join(map(str, ks))} slips per period; {int(np.sum(self.stable))} stable"
        ]
        lines += [f"  {b}" for b in self.bifurcations]
        lines += [f"  end: {e}" for e in self.ends]
        return "\n".join(lines)


def _host(point: BranchPoint) -> dict:
    o = point.orbit
    M = np.asarray(o.monodromy)
    M = np.where(np.isfinite(M), M, 0.0)  # (a failed correction's; its point is refused)
    return {
        "X": np.asarray(point.X), "tangent": np.asarray(point.tangent), "converged": bool(point.converged),
        "iterations": int(point.iterations), "V": float(o.V), "slips": int(o.slips), "period": float(o.period),
        "statistics": {k: float(v) for k, v in o.statistics.items()}, "multipliers": np.asarray(o.multipliers),
        "monodromy": M, "approach": float(o.approach), "crossing": float(o.crossing), "section": np.asarray(o.section),
        "status": int(o.status),
        "fold": float(np.linalg.det(M - np.eye(2))), "period_doubling": float(np.linalg.det(M + np.eye(2))),
        "torus": float(np.linalg.det(M) - 1.0), "complex": bool(np.trace(M) ** 2 < 4 * np.linalg.det(M)),
    }  # fmt: skip


def continue_orbit(
    orbit: PeriodicOrbit,
    *,
    parameter: str = "V",
    bounds: tuple[float, float] | None = None,
    ds: float = 0.02,
    ds_min: float = 1e-4,
    ds_max: float = 0.05,
    max_points: int = 400,
    directions: tuple[int, ...] = (1, -1),
    rtol: float = DEFAULT_ORBIT_RTOL,
    progress: Callable[[str], None] | None = None,
) -> OrbitBranch:
    """The branch of periodic orbits through ``orbit`` over ``parameter`` (module docstring).

    Args:
        orbit: a converged :class:`~peeljax.PeriodicOrbit` (from :func:`peeljax.periodic_orbit`).
        parameter: ``"V"`` (default) or a coefficient of φ (``"c1"``, …).
        bounds: the parameter's range to stay in (default: V in (0, 10) m/s; a coefficient
            within ±50 % of its value).
        ds, ds_min, ds_max: the first, smallest and largest arclength step, in the scaled
            coordinates (radians, units of V/R, the parameter over its start value).
        max_points: most points per direction.
        directions: +1 (increasing parameter) and/or −1.
        rtol: the tolerance of each period's runs.
        progress: called with a line per event (None: quiet).

    Returns:
        An :class:`OrbitBranch`: the points in parameter order along the arclength (the −1
        direction reversed before the +1 one), every bifurcation located, why it ended.
    """
    if int(orbit.status) != OrbitStatus.CONVERGED:
        raise ValueError(f"orbit must be converged to continue it, its status is {orbit.status_name}: {orbit.reason}")
    for d in directions:
        if d not in (1, -1):
            raise ValueError(f"directions must hold +1 and/or -1, got {directions!r}")
    if not 0 < ds_min <= ds <= ds_max:
        raise ValueError(f"the steps must satisfy 0 < ds_min <= ds <= ds_max, got {ds_min!r}, {ds!r}, {ds_max!r}")
    start_time = time.perf_counter()
    model, V0 = orbit.model, float(orbit.V)
    leaf = parameter_leaf(model, V0, parameter)
    leaves = jax.tree_util.tree_leaves((model, jnp.asarray(V0)))
    value0 = float(np.asarray(leaves[leaf]))
    scale = abs(value0) if value0 != 0 else 1.0
    if bounds is None:
        bounds = (0.0, 10.0) if parameter == "V" else (value0 - 0.5 * abs(value0), value0 + 0.5 * abs(value0))
    lo, hi = (b / scale for b in bounds)
    shooting = orbit_shooting(rtol=rtol)
    correct = _corrector(leaf)
    say = progress or (lambda line: None)
    slips = int(orbit.slips)
    section_scale = np.asarray(SlipSection.at(model, V0).scale)
    z0 = np.asarray(orbit.section) / section_scale
    X0 = np.concatenate([z0, [value0 / scale]])

    def point(X, tangent, previous, k, period=float(orbit.period)):
        # One period's runs are bounded by 3 periods of the last point's (T changes along a branch).
        t_max = jnp.asarray(PERIODS_PER_RUN * period)
        p = correct(shooting, model, jnp.asarray(V0), jnp.asarray(X), jnp.asarray(tangent), jnp.asarray(k, jnp.int32),
                    t_max, jnp.asarray(scale), jnp.asarray(previous))  # fmt: skip
        return _host(p)

    # The tangent at the start: a correction at fixed λ, oriented to increasing λ.
    first = point(X0, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), slips)
    bifurcations: list[Bifurcation] = []
    ends: list[str] = []
    sides = {}
    for direction in directions:
        here = dict(first)
        here["tangent"] = direction * first["tangent"]
        points = [here]
        step = ds
        k = slips
        while len(points) < max_points:
            last = points[-1]
            new = point(last["X"] + step * last["tangent"], last["tangent"], last["tangent"], k, last["period"])
            # A correction that moved far off the prediction, or a tangent that turned sharply, may
            # have landed on another part of the curve: refused like a failed one.
            moved = float(np.linalg.norm(new["X"] - last["X"] - step * last["tangent"]))
            turned = float(np.dot(new["tangent"], last["tangent"]))
            if not new["converged"] or moved > _MOST_MOVED * step or turned < _LEAST_ALIGNED:
                step /= 2
                if step < ds_min:
                    kind, why = _end_of(points, new)
                    where = _extrapolated_end(points, kind) * scale
                    ends.append(f"{'+' if direction > 0 else '-'}{parameter}: {kind.value} at {where:.6g} ({why})")
                    bifurcations.append(
                        Bifurcation(kind, where, where if parameter == "V" else last["V"], k, len(points) - 1, why,
                                    direction, tuple(last["section"]),
                                    tuple(last["monodromy"].ravel()), last["period"])  # fmt: skip
                    )
                    say(f"  {kind.value} at {parameter} = {where:.6g}")
                    break
                continue
            for kind, located in _events(last, new, point, k, scale):
                bifurcations.append(
                    Bifurcation(kind, located["X"][2] * scale, located["V"], k, len(points), "", direction,
                                tuple(located["section"]), tuple(located["monodromy"].ravel()), located["period"])  # fmt: skip
                )
                say(f"  {kind.value} at {parameter} = {located['X'][2] * scale:.6g}")
            points.append(new)
            if not lo <= new["X"][2] <= hi:
                ends.append(f"{'+' if direction > 0 else '-'}{parameter}: left the bounds at {new['X'][2] * scale:.6g}")
                break
            if len(points) > 3 and np.linalg.norm(new["X"] - X0) < 0.5 * step:
                ends.append(f"{'+' if direction > 0 else '-'}{parameter}: the branch closed on its start")
                break
            step = min(step * 1.5, ds_max) if new["iterations"] <= _QUICK else step
        else:
            ends.append(f"{'+' if direction > 0 else '-'}{parameter}: max_points reached")
        sides[direction] = points
    backward = list(reversed(sides[-1])) if -1 in sides else []
    forward = sides[1] if 1 in sides else []
    ordered = backward[:-1] + forward if backward and forward else backward + forward
    return _branch(parameter, scale, ordered, bifurcations, ends, time.perf_counter() - start_time)


_GRAZING_APPROACH = 1e-3  # × (φ(v̂) − φ(v̌)): a stick phase this close to φ's maximum grazes it
_GRAZING_CROSSING = 1e-2  # × the branch's fastest crossing: a slip this slow is vanishing


def _extrapolated_end(points: list[dict], kind: BifurcationKind) -> float:
    """The scaled parameter of a grazing from the branch's last two points: the monitor that
    vanishes there is linear in the arclength near it (the approach; the square of the crossing
    rate, which vanishes like a square root), so its secant's zero places the grazing to second
    order in the last step, finer than the smallest step finds it. The last point's parameter
    otherwise."""
    last = points[-1]["X"][2]
    if kind not in (BifurcationKind.NEW_SLIP, BifurcationKind.LOST_SLIP) or len(points) < 2:
        return last
    a, b = points[-2], points[-1]
    f = (lambda p: p["approach"]) if kind == BifurcationKind.NEW_SLIP else (lambda p: p["crossing"] ** 2)
    fa, fb = f(a), f(b)
    if not (np.isfinite(fa) and np.isfinite(fb)) or fa == fb:
        return last
    w = fb / (fa - fb)  # the zero at b + w·(b − a)
    if not 0 <= w <= 1:
        return last
    return float(b["X"][2] + w * (b["X"][2] - a["X"][2]))


def _end_of(points: list[dict], failed: dict) -> tuple[BifurcationKind, str]:
    """Why a branch ends where the corrector fails at the smallest step: a grazing (the
    monitors at the last point), or the failure's own reason."""
    last = points[-1]
    drop = max(p["statistics"]["F_slip"] - p["statistics"]["F_stick"] for p in points)
    fastest = max(p["crossing"] for p in points)
    if last["approach"] > -_GRAZING_APPROACH * max(drop, 1e-300):
        return BifurcationKind.NEW_SLIP, f"a stick phase touches phi's maximum: {last['slips'] + 1} slips per period past it"
    if last["crossing"] < _GRAZING_CROSSING * fastest:
        return BifurcationKind.LOST_SLIP, f"a slip crosses phi's maximum tangentially: {last['slips'] - 1} slips per period past it"
    status = OrbitStatus(failed["status"])
    if status == OrbitStatus.CONVERGED:
        return BifurcationKind.END, "the corrector did not converge at the smallest step"
    return BifurcationKind.END, status.message


def _events(a: dict, b: dict, point, k: int, scale: float):
    """The bifurcations between consecutive points a and b, each located (module docstring)."""
    found = []
    tests = [
        (BifurcationKind.FOLD, lambda p: p["tangent"][2]),
        (BifurcationKind.PERIOD_DOUBLING, lambda p: p["period_doubling"]),
    ]
    if a["complex"] and b["complex"]:
        tests.append((BifurcationKind.TORUS, lambda p: p["torus"]))
    for kind, f in tests:
        fa, fb = f(a), f(b)
        if np.sign(fa) != np.sign(fb) and fa != 0:
            found.append((kind, _locate(a, b, f, fa, fb, point, k)))
    return found


def _locate(a: dict, b: dict, f, fa: float, fb: float, point, k: int) -> dict:
    """The point between a and b where f = 0: regula falsi (Illinois) on the arclength σ from
    a, each trial a point corrected on the hyperplane through a + σ·t_a; to σ within 1e-8."""
    sa, sb = 0.0, float(np.dot(b["X"] - a["X"], a["tangent"]))
    best = b
    for _ in range(_LOCATE_ITERATIONS):
        sigma = sb - fb * (sb - sa) / (fb - fa)
        if not min(sa, sb) < sigma < max(sa, sb):
            sigma = 0.5 * (sa + sb)
        p = point(a["X"] + sigma * a["tangent"], a["tangent"], a["tangent"], k, a["period"])
        if not p["converged"]:
            break
        fp = f(p)
        best = p
        if fp == 0 or abs(sb - sa) < 1e-8:
            break
        if np.sign(fp) == np.sign(fa):
            sa, fa = sigma, fp
            fb *= 0.5
        else:
            sb, fb = sigma, fp
            fa *= 0.5
    return best


def _branch(parameter, scale, points, bifurcations, ends, wall) -> OrbitBranch:
    def column(key):
        return np.array([p[key] for p in points])

    return OrbitBranch(
        parameter=parameter, values=column("X")[:, 2] * scale, V=column("V"), slips=column("slips"),
        period=column("period"), statistics={k: np.array([p["statistics"][k] for p in points]) for k in STATISTICS},
        multipliers=np.stack([p["multipliers"] for p in points]),
        stable=np.array([np.max(np.abs(p["multipliers"])) < 1 for p in points]),
        test_functions={k: column(k) for k in ("fold", "period_doubling", "torus")},
        approach=column("approach"), crossing=column("crossing"), section=np.stack([p["section"] for p in points]),
        bifurcations=bifurcations, ends=ends, wall_time=wall,
    )  # fmt: skip
