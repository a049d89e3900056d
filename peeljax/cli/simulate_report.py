"""What ``peeljax simulate`` says about a run (:mod:`.simulate`): the line before it, the summary,
the figure's title, the cycle statistics and the remedies. ``config`` is the run's
:class:`~peeljax.cli.simulate.RunConfig` (not imported: that module imports this one)."""

from __future__ import annotations

import math
import sys

import numpy as np

from ..cycles import cycle_statistics
from ..solution import Solution, StopReason
from ._common import PROG, max_steps_remedy, option_names, stats_text

__all__ = ["announce", "cycles", "method_title", "plot_title", "remedy_notes", "regime_note", "summary_lines"]

# The stepper that ran (the Solution's ``method``), in words; other names are shown as they are.
_METHOD_TITLES = {
    "alpha": "alpha-method", "alpha-adaptive": "alpha-method", "diffrax": "diffrax Kvaerno5 reference",
    "switching-tsit5-alpha": "Tsit5 <-> alpha-method"}  # fmt: skip


def method_title(method: str, option: str | None = None) -> str:
    """The stepper that ran (the Solution's ``method``) in words; "(the default stepper)" when
    --method left the choice to the library."""
    title = _METHOD_TITLES.get(method, method)
    return f"{title} (the default stepper)" if option == "default" else title


def plot_title(config, record: dict) -> str:
    """The figure's title: the run's settings, and its outcome on a line of its own."""
    tau = "τ = 0 (the DAE)" if config.dae else f"τ = {config.tau:g} s"
    rho = record.get("rho")
    parts = [f"V = {config.V:g} m/s", tau, method_title(record["method"], config.method).replace("alpha-method", "α-method")]
    if config.adaptive:
        parts += [f"rtol = {config.rtol:g}", f"atol = {config.atol:g}"] + ([] if rho is None else [f"ρ = {rho:g}"])
    elif config.uniform:
        parts += [f"dt = {record['dt']:.4g} s", f"ρ = {config.rho:g}"]
    else:
        parts += [f"rtol = {config.rtol:g}", f"output every {record['dt']:.4g} s"]
    if config.model.geometry != "paper":
        parts.append(f"{config.model.geometry} geometry")
    outcome = "completed" if record["status"] == "completed" else f"stopped at t = {record['t_stop']:.4g} s"
    if record.get("jumps") is not None:
        outcome += f", {record['jumps']} jump{'' if record['jumps'] == 1 else 's'} at the folds of φ"
    return f"{', '.join(parts)}\n{outcome}"


def regime_note(config) -> str | None:
    """A plain word when φ(·, V) has no maximum: then there is no stick-slip to resolve (the
    paper's φ loses its maximum between V = 4 and 8 m/s) and large V makes the run stiff."""
    from ..analysis import phi_extrema

    if math.isfinite(phi_extrema(config.model, config.V)[0]):
        return None
    return (f"phi(v, V = {config.V:g}) has no maximum for v in [1e-3, 50] m/s: no stick-slip regime at this V (the "
            "paper's law has one up to V of about 7 m/s)")  # fmt: skip


def summary_lines(record: dict, config, found=None) -> list[str]:
    """A few human-readable lines (:func:`report` makes them ASCII)."""
    settings = [] if record.get("rho") is None else [f"rho = {record['rho']:g}"]
    if config.rtol is not None:
        settings.append(f"rtol = {config.rtol:g}, atol = {config.atol:g}")
    if config.adaptive:
        settings.append(f"fold {config.fold} (--max-jumps {config.max_jumps}, --max-steps {config.budget})")
    mesh = _mesh(config, f" ({record['accepted_steps']} accepted, {record['rejected_steps']} rejected steps)",
                 f"dt = {record['dt']:.6g} s ({config.n_steps} steps)")  # fmt: skip
    tau = "tau = 0 (the DAE)" if config.dae else f"tau = {config.tau:g} s"
    stopped = f"stopped at t = {record['t_stop']:.6g} s"
    if record["status"] == "completed":
        ended = f"completed: reached t = {record['t_stop']:.6g} s"
    elif record["status_code"] == int(StopReason.MAX_STEPS):
        ended = (f"{stopped}: the step budget ({config.budget} step attempts, --max-steps) was used up before "
                 "t_final: raise --max-steps or loosen --rtol")  # fmt: skip
    elif record["status_code"] == int(StopReason.MAX_JUMPS):  # the reason names the parameter max_jumps
        ended = f"{stopped}: the jump record is full (--max-jumps {config.max_jumps}): raise --max-jumps to go on"
    else:
        ended = f"{stopped}: {option_names(record['reason'])}"
    lines = [
        f"peeljax simulate: {method_title(record['method'], config.method)}, V = {config.V:g} m/s, {tau}, "
        f"{mesh}, t_final = {config.t_final:g} s, {', '.join(settings)}, geometry {config.model.geometry}",
        ended,
        f"v [m/s]: final {record['v_final']:.6g}, min {record['v_min']:.6g}, max {record['v_max']:.6g}"]
    if record.get("jumps") is not None:
        up = record["jumps_up"]
        lines.append(f"jumps at the folds of phi: {record['jumps']} ({up} stick -> slip, {record['jumps'] - up} slip -> stick)")
        lines.append(str(found) if found is not None else f"cycles: {record['cycles_note']}")
    if record.get("note"):
        lines.append(f"note: {record['note']}")
    lines.append("stats: " + stats_text(record["stats"], jumps_said=record.get("jumps") is not None))
    lines.append(f"wall time {record['wall_time_s']:.3g} s (including compilation)")
    return lines + [f"wrote {record[key]}" for key in ("out", "plot") if record.get(key)]


def cycles(solution: Solution, config, record: dict):
    """With a jump record: its count (``record["jumps"]``, ``"jumps_up"``) and the cycle statistics over [transient,
    t_stop] (``record["cycles"]``, returned too; None with a note when the run stopped before the transient ended)."""
    if solution.jumps is None:
        return None
    jumps = solution.jumps.as_numpy()
    record["jumps"] = int(jumps["jump_t"].size)
    record["jumps_up"] = int(np.count_nonzero(jumps["jump_up"]))
    t_stop = float(solution.t_stop)
    if not config.transient < t_stop:
        record["cycles"], record["cycles_note"] = None, (f"the run stopped at t = {t_stop:.6g} s, before its transient "
                                                         f"ended (--transient {config.transient:g} s): no cycle statistics")  # fmt: skip
        return None
    found = cycle_statistics(jumps, t_stop, transient=config.transient)
    record["cycles"] = found.as_dict()
    return found


def _mesh(config, steps: str, uniform: str) -> str:
    """How the run's output is laid out: error control's steps (``steps`` said after), output times, or ``uniform``."""
    if config.adaptive:
        return f"error control{steps}"
    return f"output at {len(config.save_ts)} times" if config.n_steps is None else uniform


def announce(config) -> None:
    """What runs, on stderr, before it compiles."""
    mesh = _mesh(config, "", f"{config.n_steps} step{'' if config.n_steps == 1 else 's'}")
    method = "default stepper" if config.method == "default" else config.method
    budget = "" if config.budget is None else f", at most {config.budget} step attempts (--max-steps)"
    print(f"{PROG}: {method} run with {mesh} to t = {config.t_final:g} s{budget} (compiling first: a few seconds) ...",
          file=sys.stderr)  # fmt: skip


def remedy_notes(solution: Solution, config) -> list[str]:
    """After a run that ran out of its step budget or its jump record: the option to raise (stderr)."""
    status = int(np.asarray(solution.status))
    if status == StopReason.MAX_STEPS:
        return [max_steps_remedy(config.budget)]
    if status == StopReason.MAX_JUMPS:
        return [f"{PROG}: the jump record is full: raise --max-jumps (now {config.max_jumps})"]
    return []
