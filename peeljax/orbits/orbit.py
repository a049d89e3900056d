"""The result of shooting: a stick-slip periodic orbit, its stability and its statistics."""

from __future__ import annotations

import json
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Complex, Float, Int

from ..model import PeelingModel
from ..simulate import simulate
from ..solution import Solution, StopReason
from ..saved import register_reader
from .files import KIND, orbit_fields, write_orbit
from .floquet import test_functions
from .section import state_after_slip
from .shooting import OrbitStatus

__all__ = ["PeriodicOrbit", "SavedOrbit", "read_orbit"]

_UNITS = {"F_mean": "N", "F_slip": "N", "F_stick": "N", "period": "s", "slip_duration": "s"}
# PeriodicOrbit.summary's statistics: key, name, unit, scale
_STATISTICS_WORDS = (
    ("F_mean", "F_mean", "N", 1.0), ("F_slip", "F_slip", "N", 1.0), ("F_stick", "F_stick", "N", 1.0),
    ("period", "time between slips", "ms", 1e3), ("slip_duration", "slip duration", "ms", 1e3),
)  # fmt: skip


class PeriodicOrbit(eqx.Module):
    """A periodic stick-slip orbit of the DAE (τ = 0) with k stick → slip events per period.

    Every float field carries derivatives with respect to V, the model and φ's coefficients
    by the implicit function theorem on the fixed point (:mod:`peeljax.orbits.shooting`),
    except ``monodromy`` and ``multipliers``, which are held constant. Under ``vmap`` every
    field gains a leading batch axis.

    Attributes:
        model: spool, tape and adhesion law.
        V: pull velocity [m/s].
        slips: k, the stick → slip events per period.
        section: s = (α, ω) [rad, rad/s] where the orbit crosses the stick → slip section
            (G(x) = φ(v̂, V), just before the slip).
        state: (α, ω, u, v̂) there, before the slip.
        period: T [s].
        force_integral: ∫₀ᵀ F dt over the period [N·s].
        approach: the closest approach to a grazing over the period [N] (negative; 0 where
            a stick phase's G touches φ's maximum without slipping, or a slip phase's G its
            minimum without re-sticking: there k changes; :mod:`peeljax.orbits.period`); −inf
            where nothing comes close.
        crossing: the slowest crossing of the section over the period, min Ġ at the slips
            [N/s] (positive; 0 where a slip is about to vanish: a grazing).
        monodromy: M = ∂P^k/∂s, the return map's Jacobian on the section.
        multipliers: its eigenvalues λ₁, λ₂ (larger modulus first): the orbit's nontrivial
            Floquet multipliers.
        status: an :class:`~peeljax.orbits.OrbitStatus` code (0: converged).
        run_status: the :class:`~peeljax.StopReason` of the last period's run (``MAX_JUMPS``:
            it reached its k-th slip).
        iterations: Newton's iterations.
        residual: |P^k(s) − s| in the scaled coordinates (radians, units of V/R).
        steps: step attempts of one period's run.
        statistics: the five statistics of a stick-slip table over exactly one period
            (:func:`peeljax.orbits.period.period_statistics`): ``F_mean`` (the time average of
            F), ``F_slip`` and ``F_stick`` (F at the slips and re-sticks) [N], ``period`` (T/k,
            the mean time between slips) and ``slip_duration`` [s].
    """

    model: PeelingModel
    V: Float[Array, ""]
    slips: Int[Array, ""]
    section: Float[Array, "2"]
    state: Float[Array, "4"]
    period: Float[Array, ""]
    force_integral: Float[Array, ""]
    approach: Float[Array, ""]
    crossing: Float[Array, ""]
    monodromy: Float[Array, "2 2"]
    multipliers: Complex[Array, "2"]
    status: Int[Array, ""]
    run_status: Int[Array, ""]
    iterations: Int[Array, ""]
    residual: Float[Array, ""]
    steps: Int[Array, ""]
    statistics: dict[str, Array]

    # -- verdicts ---------------------------------------------------------------------------
    @property
    def converged(self) -> Bool[Array, ""]:
        return self.status == OrbitStatus.CONVERGED

    @property
    def stable(self) -> Bool[Array, ""]:
        """Asymptotically stable: every multiplier inside the unit circle."""
        return _stable(self.multipliers)

    @property
    def status_name(self) -> str:
        """``"converged"``, ``"not_converged"``, … (single orbits only)."""
        return OrbitStatus(int(self.status)).name.lower()

    @property
    def reason(self) -> str:
        """Why shooting ended, in words (single orbits only)."""
        status = OrbitStatus(int(self.status))
        text = status.message
        if status == OrbitStatus.EVENTS_CHANGED:
            text += f" (the run ended: {StopReason(int(self.run_status)).message})"
        return text

    # -- what a measurement sees ------------------------------------------------------------
    @property
    def test_functions(self) -> dict[str, Array]:
        """The fold, period-doubling and torus test functions of the monodromy
        (:func:`peeljax.orbits.floquet.test_functions`)."""
        return _test_functions(self.monodromy)

    # -- one period in time -----------------------------------------------------------------
    def trajectory(self, ts: ArrayLike | None = None, *, rtol: float = 1e-8, atol: float | None = None) -> Solution:
        """One period of the orbit as a run: :func:`peeljax.simulate` (τ = 0) from the state
        just after the slip at the section, over [0, T], output at ``ts`` (default: 2001
        equally spaced times) with both sides of every jump; its ``jumps`` are the period's
        (the slip at t = 0 is the orbit's section: the record starts with the re-stick after
        it, and ends with the slip at T that closes the period). Single orbits only."""
        period = float(self.period)
        ts = np.linspace(0.0, period, 2001) if ts is None else np.asarray(ts, float)
        y0 = state_after_slip(self.model, self.V, self.section)
        return simulate(self.model, V=float(self.V), tau=0, y0=y0, t_final=period, ts=ts, rtol=rtol, atol=atol)

    # -- output -----------------------------------------------------------------------------
    def as_dict(self) -> dict:
        """The orbit as JSON-able numbers (single orbits only)."""
        stats = {k: float(v) for k, v in self.statistics.items()}
        mult = np.asarray(self.multipliers)
        return {
            "V": float(self.V),
            "status": self.status_name,
            "reason": self.reason,
            "slips_per_period": int(self.slips),
            "period": float(self.period),
            "stable": bool(self.stable),
            "multipliers": [{"re": float(m.real), "im": float(m.imag), "abs": float(abs(m))} for m in mult],
            "statistics": stats,
            "units": dict(_UNITS),
            "section": {"alpha": float(self.section[0]), "omega": float(self.section[1])},
            "newton_iterations": int(self.iterations),
            "residual": float(self.residual),
        }

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), indent=2)

    def summary(self) -> str:
        """A report in plain words (single orbits only): the status and why, the period and the events per period, the
        Floquet multipliers and the stability, the five statistics over one period, and the section point."""
        d = self.as_dict()
        status, reason, k = d["status"], d["reason"], d["slips_per_period"]
        at = "" if status == "converged" else " (at Newton's last point: not an orbit)"
        shown = ", ".join(_complex(complex(m["re"], m["im"]), modulus=False) for m in d["multipliers"])
        moduli = ", ".join(f"{m['abs']:.4g}" for m in d["multipliers"])
        words = ", ".join(f"{name} {scale * d['statistics'][key]:.6g} {unit}" for key, name, unit, scale in _STATISTICS_WORDS)
        return "\n".join([
            f"{reason if reason.startswith(status) else f'{status}: {reason}'} ({d['newton_iterations']} Newton "
            f"iterations, residual {d['residual']:.2e})",
            f"period T = {d['period']:.7g} s with {k} stick -> slip event{'' if k == 1 else 's'} per period{at}",
            f"{'stable' if d['stable'] else 'unstable'}: Floquet multipliers {shown} (|lambda| {moduli}; stable when "
            "every |lambda| < 1)",
            f"over one period: {words}",
            f"section: alpha = {d['section']['alpha']:.7g} rad, omega = {d['section']['omega']:.7g} rad/s (just before "
            "the slip)",
        ])  # fmt: skip

    def save(self, path, settings: dict | None = None) -> None:
        """Write the orbit to an ``.npz`` that :func:`peeljax.load` reads back as a
        :class:`~peeljax.orbits.SavedOrbit` (:mod:`peeljax.orbits.files`; single orbits
        only); ``settings``: JSON-able notes on how it was found (rtol, …). Written atomically."""
        write_orbit(path, self, settings)

    def __str__(self) -> str:
        if jnp.ndim(self.V) != 0:
            return f"PeriodicOrbit(batch of {jnp.shape(self.V)[0]})"
        d = self.as_dict()
        mult = ", ".join(_complex(m) for m in np.asarray(self.multipliers))
        s = d["statistics"]
        lines = [
            f"periodic orbit at V = {d['V']:.6g} m/s: {d['status']} ({d['newton_iterations']} Newton iterations, "
            f"residual {d['residual']:.1e})",
            f"  T = {d['period']:.7g} s with {d['slips_per_period']} stick → slip events per period; "
            f"{'stable' if d['stable'] else 'unstable'}, multipliers {mult}",
            f"  F_mean {s['F_mean']:.6g} N, F_slip {s['F_slip']:.6g} N, F_stick {s['F_stick']:.6g} N, "
            f"time between slips {1e3 * s['period']:.6g} ms, slip duration {1e3 * s['slip_duration']:.6g} ms",
        ]
        if d["status"] != "converged":
            lines.append(f"  {self.reason}")
        return "\n".join(lines)


_test_functions = eqx.filter_jit(test_functions)


@eqx.filter_jit
def _stable(multipliers):
    return jnp.max(jnp.abs(multipliers), axis=-1) < 1.0


def _complex(m: complex, modulus: bool = True) -> str:
    """A multiplier in words: real where its imaginary part is negligible; else a+bi, with its modulus (``modulus``)."""
    if abs(m.imag) < 1e-12 * max(abs(m), 1e-300):
        return f"{m.real:.4g}"
    if not modulus:
        return f"{m.real:.4g}{'+' if m.imag >= 0 else '-'}{abs(m.imag):.4g}i"
    return f"{m.real:.4g}{'+' if m.imag >= 0 else '−'}{abs(m.imag):.4g}i (|λ| {abs(m):.4g})"


class SavedOrbit(PeriodicOrbit):
    """A :class:`PeriodicOrbit` read from a file (:func:`peeljax.load`), with what the file says
    about how it was found.

    Attributes (besides the orbit's):
        settings: how the orbit was found (``rtol``, ``atol``, ``transient``, … as saved; empty
            where the writer gave none).
        path: the file it was read from.
        units: the units of the file's arrays.
        peeljax_version: the version of the peeljax that wrote the file.
    """

    settings: dict = eqx.field(default_factory=dict)
    path: str = eqx.field(static=True, default="")
    units: dict = eqx.field(default_factory=dict)
    peeljax_version: str = eqx.field(static=True, default="")

    def save(self, path: str | os.PathLike, settings: dict | None = None) -> None:
        """Write the orbit to ``path`` as it was read (its settings kept unless ``settings``)."""
        write_orbit(path, self, self.settings if settings is None else settings)

    def __repr__(self) -> str:
        return (
            f"SavedOrbit({self.path!r}: V = {float(self.V):g} m/s, {int(self.slips)} slips per period, "
            f"T = {float(self.period):.7g} s, {self.status_name})"
        )


def read_orbit(arrays: dict, name: str) -> SavedOrbit:
    """The :class:`SavedOrbit` of an orbit's ``.npz`` arrays (``name``: the file, for messages);
    a ValueError naming the file where they are malformed."""
    try:
        return SavedOrbit(**orbit_fields(arrays, name), path=name)
    except (KeyError, TypeError) as error:
        raise ValueError(f"{name!r} is malformed: not an orbit's arrays ({error})") from None


# peeljax.load reads an orbit's file.
register_reader(KIND, npz=read_orbit)
