"""A periodic stick-slip orbit (:func:`peeljax.periodic_orbit`) over one period, in four panels.

matplotlib only; the one computation is the orbit's trajectory over one period
(:meth:`~peeljax.PeriodicOrbit.trajectory`, a run of T seconds from the section), which a
caller that has it already passes in.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .._panels import panels
from ..solution import Solution

__all__ = ["plot_orbit"]

_UP_COLOR, _DOWN_COLOR = "C3", "C0"  # stick → slip, slip → stick (as in plot_stick_slip)
_UP_LABEL, _DOWN_LABEL = "stick → slip (v jumps up)", "slip → stick (v jumps down)"


def _series(orbit, trajectory: Solution) -> dict[str, np.ndarray]:
    """One period on the host: t, v, F, G and the mask of the rows just after a jump; the
    jumps (the slip at the section, t = 0, first): t, up, v before and after, F, G."""
    model, V = orbit.model, float(orbit.V)
    valid = np.asarray(trajectory.valid, bool)
    t = np.asarray(trajectory.ts, float)[valid]
    ys = np.asarray(trajectory.ys, float)[valid]
    after = np.zeros(t.size, bool) if trajectory.after_jump is None else np.asarray(trajectory.after_jump, bool)[valid]
    # The run ends with the slip at T that closes the period: the one at t = 0 again. Kept:
    # the rows up to the state just before it (the first row at its time).
    end = float(orbit.period) * (1 - 1e-6)
    closing = np.flatnonzero(t >= end)
    if closing.size > 1:
        t, ys, after = t[: closing[0] + 1], ys[: closing[0] + 1], after[: closing[0] + 1]
    F = np.asarray(model.tension(ys[:, 2], ys[:, 0]), float)
    G = np.asarray(model.shear_force(ys[:, :3].T), float)
    # The slip at the section (t = 0) is the orbit's own: the run starts just after it.
    from ..branches import phi_folds

    folds = phi_folds(model, V)
    state = np.asarray(orbit.state, float)
    first = {
        "jump_t": np.array([0.0]), "jump_up": np.array([True]), "jump_v_before": np.array([float(folds.v_max)]),
        "jump_v_after": ys[:1, 3], "jump_F": np.asarray(model.tension(state[2], state[0]), float).reshape(1),
        "jump_G": np.array([float(folds.phi_max)]),
    }  # fmt: skip
    run = trajectory.jumps.as_numpy() if trajectory.jumps is not None else {key: np.zeros(0) for key in first}
    inside = run["jump_t"] < end
    jumps = {key: np.concatenate([first[key], np.asarray(run[key])[inside]]) for key in first}
    return {"t": t, "v": ys[:, 3], "F": F, "G": G, "after": after, "jumps": jumps, "folds": folds}


def _broken(t: np.ndarray, after: np.ndarray, *series: np.ndarray) -> list[np.ndarray]:
    """NaN before each row just after a jump: the lines are not drawn across the jumps (they
    are drawn on their own)."""
    at = np.flatnonzero(after)
    return [np.insert(np.asarray(a, float), at, np.nan) for a in (t, *series)]


def plot_orbit(
    orbit,
    *,
    trajectory: Solution | None = None,
    title: str | None = None,
    path: str | Path | None = None,
    axes=None,
) -> Figure:
    """One period of a periodic stick-slip orbit, its G–v loop and its Floquet multipliers.

    Four panels:

    1. v(t) over one period [0, T] on a log axis, each jump a vertical segment (red: stick →
       slip at φ's maximum v̂, the first at t = 0 where the orbit crosses the section; blue:
       slip → stick), the pull velocity V dashed;
    2. F(t), the tape tension (what a load cell reads), the slips ▲ and re-sticks ▼ marked
       and the period's statistics drawn: F_mean (the time average over the period, dashed),
       F_slip and F_stick (the means at the slips and re-sticks, dotted);
    3. the G–v loop over φ(v, V) (dashed): G = (1 + l·sinα/L)·F against v, the jumps as
       horizontal segments at constant G between the branches, the folds (v̂, φ(v̂, V)) and
       (v̌, φ(v̌, V)) marked;
    4. the multipliers λ₁, λ₂ (eigenvalues of the return map's Jacobian on the section) in the
       complex plane against the unit circle: the orbit is stable when both lie inside.

    Args:
        orbit: a single :class:`~peeljax.PeriodicOrbit` (or one read by :func:`peeljax.load`).
        trajectory: its :meth:`~peeljax.PeriodicOrbit.trajectory` (default: computed here; a
            run of one period, compiled on first use).
        title: figure title (default on a figure of its own: V, T, k and the stability).
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        axes: four matplotlib Axes for v(t), F(t), the loop and the multipliers (a figure of
            the user's); None: a new figure.

    Returns:
        The figure (the axes' figure when they are given).

    Raises:
        ValueError: a batch of orbits, or one that did not converge (its status and reason
            say why; there is no orbit to draw).
    """
    if np.ndim(orbit.V) != 0:
        raise ValueError("plot_orbit: one orbit, not a batch (index it first)")
    if not bool(orbit.converged):
        raise ValueError(
            f"plot_orbit: the orbit did not converge ({orbit.status_name}: {orbit.reason}); nothing to draw"
        )

    def mosaic(fig):
        found = fig.subplot_mosaic([["v", "loop"], ["F", "mult"]], width_ratios=(1.4, 1.0))
        found["F"].sharex(found["v"])
        return [found[key] for key in ("v", "F", "loop", "mult")]

    drawn = panels(axes, 4, mosaic, figsize=(12.5, 8.0), what="v(t), F(t), the G–v loop and the multipliers")
    ax_v, ax_F, ax_loop, ax_mult = drawn.axes
    trajectory = orbit.trajectory() if trajectory is None else trajectory
    s = _series(orbit, trajectory)
    t, v, F, G, after, jumps, folds = (s[key] for key in ("t", "v", "F", "G", "after", "jumps", "folds"))
    jt, up = jumps["jump_t"], jumps["jump_up"].astype(bool)
    V, T, k = float(orbit.V), float(orbit.period), int(np.asarray(orbit.slips))
    stats = {key: float(value) for key, value in orbit.statistics.items()}
    tb, vb, Fb, Gb = _broken(t, after, v, F, G)
    ms = 1e3  # time axis in ms: a period is tens to hundreds of ms

    # 1. v(t) with the jumps
    ax_v.plot(tb * ms, vb, color="0.2", lw=1.0, label="peeling velocity v(t)")
    for mask, color, label in ((up, _UP_COLOR, _UP_LABEL), (~up, _DOWN_COLOR, _DOWN_LABEL)):
        if mask.any():
            ax_v.vlines(jt[mask] * ms, jumps["jump_v_before"][mask], jumps["jump_v_after"][mask], colors=color, lw=1.4,
                        label=label)  # fmt: skip
    ax_v.axhline(V, color="k", ls="--", lw=0.9, label=f"pull velocity V = {V:g} m/s")
    ax_v.set_yscale("log")
    ax_v.set_ylabel("peeling velocity v [m/s]")
    ax_v.set_title(f"one period, T = {T * ms:.5g} ms, {k} slip{'' if k == 1 else 's'}", fontsize=10)
    ax_v.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7, framealpha=0.9, borderaxespad=0.3)

    # 2. F(t) with the slips, the re-sticks and the period's statistics
    ax_F.plot(tb * ms, Fb, color="0.2", lw=1.0, label="tension F(t)")
    ax_F.plot(
        jt[up] * ms, jumps["jump_F"][up], "^", color=_UP_COLOR, ms=6, ls="none", label="slips (F at stick → slip)"
    )
    ax_F.plot(
        jt[~up] * ms,
        jumps["jump_F"][~up],
        "v",
        color=_DOWN_COLOR,
        ms=6,
        ls="none",
        label="re-sticks (F at slip → stick)",
    )
    ax_F.axhline(stats["F_mean"], color="C2", ls="--", lw=1.0, label=f"F_mean = {stats['F_mean']:.5g} N")
    # where F meets G: the force φ balances is G = (1 + l·sinα/L)·F, above the tension F
    G_slip, G_stick = (float(np.mean(jumps["jump_G"][side])) if np.any(side) else np.nan for side in (up, ~up))
    ax_F.axhline(stats["F_slip"], color=_UP_COLOR, ls=":", lw=1.0,
                 label=f"F_slip = {stats['F_slip']:.5g} N (there G = {G_slip:.5g} N: φ's maximum)")  # fmt: skip
    ax_F.axhline(stats["F_stick"], color=_DOWN_COLOR, ls=":", lw=1.0,
                 label=f"F_stick = {stats['F_stick']:.5g} N (there G = {G_stick:.5g} N: φ's minimum)")  # fmt: skip
    ax_F.set_xlabel("time from the slip at the section t [ms]")
    ax_F.set_ylabel("tension F [N]")
    ax_F.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7, framealpha=0.9, borderaxespad=0.3)
    for ax in (ax_v, ax_F):
        ax.set_xlim(-0.01 * T * ms, 1.01 * T * ms)  # the jumps at t = 0 clear of the axis
        ax.grid(True, alpha=0.3)

    # 3. the G–v loop over φ(v, V)
    import jax.numpy as jnp

    v_hat, phi_hat, v_check, phi_check = (float(x) for x in (folds.v_max, folds.phi_max, folds.v_min, folds.phi_min))
    span = np.concatenate(
        [v[np.isfinite(v) & (v > 0)], jumps["jump_v_before"], jumps["jump_v_after"], [v_hat, v_check]]
    )
    span = span[span > 0]
    grid = np.geomspace(span.min() / 2.0, span.max() * 1.5, 400)
    ax_loop.plot(grid, np.asarray(orbit.model.phi(jnp.asarray(grid), V), float), "k--", lw=1.0,
                 label=f"φ(v, V = {V:g} m/s)", zorder=3)  # fmt: skip
    _, vl, Gl = _broken(t, after, v, G)
    ax_loop.plot(vl, Gl, color="C2", lw=3.0, alpha=0.55, label="the orbit: G against v")
    for mask, color, label in ((up, _UP_COLOR, _UP_LABEL), (~up, _DOWN_COLOR, _DOWN_LABEL)):
        if mask.any():
            ax_loop.hlines(jumps["jump_G"][mask], jumps["jump_v_before"][mask], jumps["jump_v_after"][mask],
                           colors=color, lw=1.4, label=label, zorder=4)  # fmt: skip
    ax_loop.plot([v_hat, v_check], [phi_hat, phi_check], "o", ms=7, mfc="white", mec="k", mew=1.4, zorder=5,
                 label=f"folds v̂ = {v_hat:.3g}, v̌ = {v_check:.3g} m/s")  # fmt: skip
    forces = np.concatenate([G[np.isfinite(G)], [phi_hat, phi_check]])
    pad = max(float(np.ptp(forces)), 1e-3 * max(abs(float(forces.max())), 1.0))
    ax_loop.set_ylim(float(forces.min()) - 0.3 * pad, float(forces.max()) + 0.45 * pad)
    ax_loop.set_xlim(grid[0], grid[-1])
    ax_loop.set_xscale("log")
    ax_loop.set_xlabel("peeling velocity v [m/s]")
    ax_loop.set_ylabel("shear force G = (1 + l·sinα/L)·F [N]")
    ax_loop.set_title("G–v loop over φ(v, V)", fontsize=10)
    ax_loop.grid(True, alpha=0.3)
    ax_loop.legend(loc="upper left", fontsize=7, framealpha=0.9)

    # 4. the multipliers against the unit circle
    lam = np.asarray(orbit.multipliers, complex)
    moduli = np.abs(lam)
    stable = bool(np.max(moduli) < 1.0)
    theta = np.linspace(0.0, 2 * np.pi, 361)
    ax_mult.plot(np.cos(theta), np.sin(theta), color="0.4", lw=1.0, label="unit circle |λ| = 1")
    ax_mult.axhline(0.0, color="0.8", lw=0.8, zorder=0)
    ax_mult.axvline(0.0, color="0.8", lw=0.8, zorder=0)
    color = "C2" if stable else "C3"
    ax_mult.plot(lam.real, lam.imag, "x", color=color, ms=10, mew=2.2, ls="none",
                 label="multipliers λ₁, λ₂ (" + ("stable: inside" if stable else "unstable: one outside") + ")")  # fmt: skip
    for i, (z, m) in enumerate(zip(lam, moduli)):
        ax_mult.annotate(f"λ{'₁₂'[i]} = {_complex(z)}\n|λ{'₁₂'[i]}| = {m:.3g}", xy=(z.real, z.imag),
                         xytext=(8, 10 - 34 * i), textcoords="offset points", fontsize=8, color=color)  # fmt: skip
    reach = max(1.25, 1.15 * float(np.max(moduli)))
    ax_mult.set_xlim(-reach, reach)
    ax_mult.set_ylim(-reach, reach)
    ax_mult.set_aspect("equal", adjustable="box")
    ax_mult.set_xlabel("Re λ")
    ax_mult.set_ylabel("Im λ")
    ax_mult.set_title("Floquet multipliers on the section", fontsize=10)
    ax_mult.legend(loc="lower left", fontsize=7, framealpha=0.9)
    ax_mult.grid(True, alpha=0.3)

    default = (
        f"periodic orbit at V = {V:g} m/s: T = {T:.7g} s, {k} stick → slip events per period, "
        f"{'stable' if stable else 'unstable'} (max |λ| = {np.max(moduli):.3g})"
    )
    return drawn.finish(title, path, default_title=default, fontsize=11)


def _complex(z: complex) -> str:
    if abs(z.imag) < 1e-12 * max(abs(z), 1e-300):
        return f"{z.real:.4g}"
    return f"{z.real:.3g} {'+' if z.imag >= 0 else '−'} {abs(z.imag):.3g}i"
