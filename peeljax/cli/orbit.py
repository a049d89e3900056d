"""``peeljax orbit``: the periodic stick-slip orbit at one pull velocity, its stability and its
statistics over one period (:func:`peeljax.periodic_orbit`), a figure and a file.

Exit status: 0 the orbit converged; 1 it did not (its status and reason are printed, and the
``--out`` file records them), or an output could not be written; 2 bad input, or no orbit to
shoot for (φ has no fold at V, or the run shows no repeat), before any shooting; 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

from ..model import PeelingModel
from ..orbits.api import ATOL_PER_RTOL, DEFAULT_TRANSIENT_RUN, MAX_ITERATIONS, MAX_SLIPS, check_periodic_orbit
from ..orbits.api import orbit_shooting, periodic_orbit
from ..orbits.diagram import orbit_diagram
from . import _interrupt, options
from ._common import PROG, Elapsed, checked, fail, library_default, library_defaults, plotter, report, subcommand
from ._common import write_failed, write_files, wrote

__all__ = ["EXIT_NOT_CONVERGED", "OrbitConfig", "add_command", "validate_orbit"]

EXIT_NOT_CONVERGED = 1
MAX_SEEDS = 2000  # seed runs of a diagram: a typo must not run for days


# V, the tolerance, Newton's iteration cap and a diagram's seed runs: the library's defaults
_ORBIT, _SEEDS = library_defaults(periodic_orbit), library_default(orbit_diagram, "seeds")
_V, _RTOL, _MAX_ITERATIONS = _ORBIT["V"], _ORBIT["rtol"], _ORBIT["max_iterations"]


def _one_V(token: str) -> float | tuple:
    """--V: one pull velocity [m/s], or START:STOP[:SEEDS] for the diagram over that range."""
    if ":" not in token:
        return options.number("--V")(token)
    parts = token.split(":")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"{token!r}: give one V, or START:STOP or START:STOP:SEEDS")
    lo, hi = (options.number("--V")(part) for part in parts[:2])
    try:
        return (lo, hi, int(parts[2]) if len(parts) == 3 else _SEEDS)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{token!r}: SEEDS must be an integer in [2, {MAX_SEEDS}]") from None


def add_command(subparsers) -> None:
    max_iterations, seeds = _MAX_ITERATIONS, _SEEDS
    parser = subcommand(
        subparsers, "orbit", checked(validate_orbit, _orbit_command), "find the periodic stick-slip orbit at one V: period, "
        "stability, statistics", "Find the periodic stick-slip orbit of the DAE (tau = 0) at one V by shooting: Newton's "
        "method on the return map after k stick -> slip events, from the repeat of a run from the paper's start (--transient). "
        "Prints the period, the Floquet multipliers and the stability, and the statistics over one period. Exit status: 0 "
        "the orbit converged; 1 it did not, or an output could not be written; 2 bad input, or no orbit to shoot for (phi "
        "has no fold at V, or the run shows no repeat); 130 interrupted (Ctrl-C).", out_formats=(".npz",))  # fmt: skip
    problem = parser.add_argument_group("problem")
    problem.add_argument("--V", type=_one_V, default=_V, metavar="V|START:STOP[:SEEDS]",
                         help=f"pull velocity [m/s], > 0 (default {_V:g}); or a range START:STOP: the bifurcation "
                         f"diagram over it — seed runs at SEEDS equally spaced V (default {seeds}) from the tape at "
                         "rest and from steady peeling, each repeat's orbit continued over V, every bifurcation "
                         "located and the branch beyond it traced")  # fmt: skip
    options.add_geometry_and_phi(problem)
    shooting = parser.add_argument_group("shooting")
    shooting.add_argument("--slips", type=int, default=None, metavar="K",
                          help=f"k, the stick -> slip events per period, an integer in [1, {MAX_SLIPS}] (default: the "
                          "repeat's; twice it shoots for the period-doubled orbit)")  # fmt: skip
    shooting.add_argument("--transient", type=float, default=DEFAULT_TRANSIENT_RUN, metavar="T",
                          help="the approach to the attractor: a run of T seconds from the paper's start, > 0, whose "
                          "second half shows the repeat (k, T and the state at its last slip) that Newton starts from "
                          f"(default {DEFAULT_TRANSIENT_RUN:g})")  # fmt: skip
    shooting.add_argument("--max-iterations", dest="max_iterations", type=int, default=max_iterations, metavar="N",
                          help=f"Newton's iteration cap, an integer in [1, {MAX_ITERATIONS}] (default {max_iterations})")
    options.add_tolerances(shooting, rtol_default=f"{_RTOL:g}", atol_default=f"{ATOL_PER_RTOL:g}*rtol", note="each period's run")
    options.add_output(parser, "progress (the elapsed wall time while it compiles and shoots)", out=("FILE.npz", (
        "write the orbit (section point, period, multipliers, statistics, model, settings; also when Newton did not "
        "converge, with its status); peeljax.load reads it back")), plot=("FILE.png", "write v(t), F(t) over one period, "
        "the G-v loop over phi(v, V) and the multipliers against the unit circle (a converged orbit only)"))  # fmt: skip


# ---------------------------------------------------------------------------- validation
@dataclass(frozen=True)
class OrbitConfig:
    """A validated ``peeljax orbit``: what :func:`peeljax.periodic_orbit` (or, with ``V_range``,
    :func:`peeljax.orbits.orbit_diagram`) and the writers need; the commands read nothing else."""

    model: PeelingModel
    V: float  # the one V, or a diagram's STOP
    slips: int | None
    transient: float
    rtol: float
    atol: float
    max_iterations: int
    phi: str | None
    phi_defaults: tuple[str, ...] | None
    V_range: tuple[float, float, int] | None = None  # a diagram's START, STOP and SEEDS
    out: str | None = None
    plot: str | None = None
    json: bool = False
    progress: bool = True

    def settings(self) -> dict:
        """How the orbit is found, as the ``--out`` file and ``--json`` keep it."""
        return {"rtol": self.rtol, "atol": self.atol, "transient": self.transient, "slips_asked": self.slips,
                "max_iterations": self.max_iterations, "geometry": self.model.geometry, "phi": self.phi}  # fmt: skip


def validate_orbit(args: argparse.Namespace) -> OrbitConfig:
    """Every option checked before anything compiles, by the library's :func:`~peeljax.orbits.api.check_periodic_orbit`
    (V once: a diagram's START, the rest as for one V); a diagram's range START:STOP:SEEDS here."""
    V_range, V = (args.V, args.V[0]) if isinstance(args.V, tuple) else (None, args.V)
    rtol = _RTOL if args.rtol is None else args.rtol
    check_periodic_orbit(None, V, slips=args.slips, period=None, rtol=rtol, atol=args.atol,
                         max_iterations=args.max_iterations, transient=args.transient)  # fmt: skip
    if V_range is not None:
        lo, V, seeds = V_range
        if not lo < V:
            raise ValueError(f"--V START:STOP must have 0 < START < STOP, got {lo:g}:{V:g}")
        if not 2 <= seeds <= MAX_SEEDS:
            raise ValueError(f"--V START:STOP:SEEDS: SEEDS must be an integer in [2, {MAX_SEEDS}] (allowed range), got {seeds}")
        if args.slips is not None:
            raise ValueError("--slips applies to one orbit (--V a number); a diagram takes k from each seed run's repeat")
    atol = orbit_shooting(rtol=rtol, atol=args.atol).integrator.controller.atol  # the library's default atol
    model, phi_defaults = options.model_from(args)
    options.check_outputs(args)
    return OrbitConfig(model=model, V=float(V), slips=args.slips, transient=float(args.transient), rtol=float(rtol),
                       atol=float(atol), max_iterations=int(args.max_iterations), phi=args.phi, phi_defaults=phi_defaults,
                       V_range=V_range, out=args.out, plot=args.plot, json=args.json, progress=args.progress)  # fmt: skip


# ---------------------------------------------------------------------------- the command
def _record(orbit, config: OrbitConfig, wall: float) -> dict:
    """The ``--json`` object: the orbit (:meth:`~peeljax.PeriodicOrbit.as_dict`), its test
    functions, how it was found, the wall time and the files written."""
    return {
        "command": "orbit", **orbit.as_dict(), "test_functions": {k: float(v) for k, v in orbit.test_functions.items()},
        "settings": config.settings(), "phi_paper_defaults": None if config.phi_defaults is None else list(config.phi_defaults),
        "wall_time_s": wall, "out": config.out, "plot": config.plot}  # fmt: skip


def _summary(orbit, record: dict, config: OrbitConfig) -> list[str]:
    """How the orbit was sought, :meth:`~peeljax.PeriodicOrbit.summary`, the wall time and the files written."""
    return [
        f"{PROG} orbit: V = {config.V:g} m/s, tau = 0 (the DAE), Newton from the repeat of a {config.transient:g} s "
        f"run, rtol = {config.rtol:g}, atol = {config.atol:g}, geometry {config.model.geometry}",
        orbit.summary(), f"wall time {record['wall_time_s']:.3g} s (including compilation)", *wrote(record)]


def _orbit_command(args: argparse.Namespace, config: OrbitConfig) -> int:
    if config.V_range is not None:
        return _diagram_command(config)
    from ..orbits import OrbitNotFound, periodic_orbit

    print(f"{PROG}: a {config.transient:g} s run to find the repeat, then Newton on the return map at V = {config.V:g} "
          "m/s (compiling first: a minute or more) ...", file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    try:
        with Elapsed(config.progress, f"orbit at V = {config.V:g} m/s"):
            orbit = periodic_orbit(config.model, config.V, slips=config.slips, rtol=config.rtol, atol=config.atol,
                                   max_iterations=config.max_iterations, transient=config.transient)  # fmt: skip
    except OrbitNotFound as error:  # nothing to shoot for: said before any shooting
        reason = str(error).removeprefix("start: ")
        return fail(ValueError(f"no orbit to shoot for at V = {config.V:g} m/s: {reason}"))
    except ValueError as error:  # a refusal of the library the checks above did not foresee: one line, not a traceback
        return fail(error)
    converged = bool(orbit.converged)
    record = _record(orbit, config, time.perf_counter() - start)
    failed = write_files(record, ("--out", config.out, lambda path: orbit.save(path, config.settings())))
    if config.plot is not None and not converged:
        record["plot"] = None
        print(f"{PROG}: no figure: the orbit did not converge (--plot {config.plot} not written)", file=sys.stderr)
    failed += write_files(record, ("--plot", config.plot if converged else None, plotter("plot_orbit", orbit)))
    notes = [] if converged else [f"{PROG}: the orbit did not converge ({record['status']}): {record['reason']}"]
    code = report(record, config.json, lambda: _summary(orbit, record, config), failed, "the orbit's summary is above", notes)
    return EXIT_NOT_CONVERGED if not converged else code


# ---------------------------------------------------------------------------- the diagram
class _KeptSoFar:
    """--out of an orbit diagram written as it grows (after each seed's V and each branch,
    marked incomplete), so that Ctrl-C keeps what was finished; ``describe`` says what that is."""

    def __init__(self, out: str | None):
        self.out, self.branches, self.seeds = out, None, 0

    def save(self, diagram) -> None:
        diagram.save(self.out)
        self.branches, self.seeds = len(diagram.branches), len(diagram.seeds)

    def describe(self) -> str:
        if self.out is None or self.branches is None:
            return ("nothing was saved (no --out; with --out the diagram is written as it grows)" if self.out is None
                    else f"nothing was finished to keep in {self.out!r}")  # fmt: skip
        return (f"{self.out!r} holds what was finished, marked incomplete: {self.seeds} seed runs and {self.branches} "
                f"branch{'' if self.branches == 1 else 'es'} (pj.load reads it)")  # fmt: skip


def _diagram_command(config: OrbitConfig) -> int:
    from ..orbits import orbit_diagram

    (lo, hi, seeds), out, plot = config.V_range, config.out, config.plot
    print(f"{PROG}: the orbit diagram over V in [{lo:g}, {hi:g}] m/s: {seeds} V x 2 starts of {config.transient:g} s "
          "runs, each repeat's orbit continued over V (compiling first: minutes) ...", file=sys.stderr)  # fmt: skip
    kept = _KeptSoFar(out)
    with _interrupt.note(kept.describe):
        try:
            with Elapsed(config.progress, f"orbit diagram over V in [{lo:g}, {hi:g}] m/s"):
                diagram = orbit_diagram(config.model, V=(lo, hi), seeds=seeds, t_final=config.transient, rtol=config.rtol,
                                        progress=config.progress, on_progress=kept.save if out is not None else None)  # fmt: skip
        except ValueError as error:
            return fail(error)
        except OSError as error:  # --out, written as the diagram grows
            return write_failed("--out", out, error, "the diagram was not finished")
        except KeyboardInterrupt:
            return _interrupt.interrupted(kept.describe())
    record = {"command": "orbit", **diagram.as_dict(), "settings": config.settings(), "out": out, "plot": plot}
    failed = write_files(record, ("--out", out, diagram.save), ("--plot", plot, plotter("plot_orbit_diagram", diagram)))
    return report(record, config.json, [diagram.summary(), *wrote(record)], failed, "the diagram's summary is above")

