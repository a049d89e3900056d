"""``peeljax simulate``: one run, its summary, an .npz of the trajectory and a plot."""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import TAU_MAX, check_mesh, check_positive, check_tau, check_y0
from ..integrators.dense import output_times
from ..integrators.select import DEFAULT_ATOL as _ALPHA_ATOL
from ..integrators.select import integrator_for, refuse_with_dt, resolve_max_steps
from ..integrators.select import DEFAULT_RTOL as _ALPHA_RTOL
from ..model import PeelingModel
from ..simulate import check_run_memory, simulate, simulate_reference
from ..solution import Solution
from . import options
from ._common import STEPPERS, Elapsed, checked, library_defaults, plotter, report, solver_for, subcommand, write_files
from .simulate_report import announce, cycles, plot_title, regime_note, remedy_notes, summary_lines

__all__ = ["add_command", "run", "summarize", "validate_run", "write_npz"]

# --method: "default" (the library's stepper), "alpha", "diffrax" (the Kvaerno5 reference, on its
# output grid) and the other steppers of the error-controlled loop.
METHODS = ("default", "alpha", "diffrax", *(name for name in STEPPERS if name != "alpha"))
_UNIFORM_METHODS = ("default", "alpha")  # those that run the uniform mesh (--dt) and take --rho
# the defaults of a run and of the diffrax reference (--method diffrax), read once from the library
_RUN, _REFERENCE = library_defaults(simulate), library_defaults(simulate_reference)


def add_command(subparsers) -> None:
    parser = subcommand(subparsers, "simulate", checked(validate_run, _simulate_command), "integrate one run",
        "Integrate the homogenized peeling ODE (tau > 0) or the DAE itself (tau = 0) over [0, t_final], through the "
        "folds of phi, and report how it ended.", out_formats=(".npz", ".csv"))  # fmt: skip
    physics = parser.add_argument_group("problem")
    options.add_V(physics, many=False, default=_RUN["V"])
    tau_range = f"[0, {TAU_MAX:.0e}]".replace("e+0", "e")
    physics.add_argument("--tau", type=options.number("--tau"), default=_RUN["tau"],
                         help=f"tau [s] in {tau_range}: 0 is the DAE itself (v from G = phi(v, V), jumping at the folds of "
                         "phi); 0 needs error control (default %(default)s)")  # fmt: skip
    options.add_t_final(physics, default=_RUN["t_final"])
    physics.add_argument("--y0", type=float, nargs=4, metavar=("ALPHA0", "OMEGA0", "U0", "v0"),
                         help="initial state: peel angle alpha0 [rad], spool speed omega0 [rad/s], tape stretch u0 [m] "
                         "and peeling velocity v0 [m/s] > 0 (not the pull velocity --V) (default: the paper's "
                         "consistent data, v0 = 1e-10*V)")  # fmt: skip
    options.add_geometry_and_phi(physics)
    solver = parser.add_argument_group("integrator")
    options.add_method(solver, _RUN["rho"], "; or diffrax (the Kvaerno5 reference on its output grid)")
    solver.add_argument("--dt", type=float, default=None,
                        help="default/alpha: a uniform mesh of N = round(t_final/dt) alpha-method steps instead of error "
                        f"control, dt in (0, t_final]; diffrax: the output spacing (default: error control; "
                        f"1/{1 / _REFERENCE['dt']:g} for diffrax)")  # fmt: skip
    options.add_tolerances(solver, rtol_default=f"{_ALPHA_RTOL:g}; {_REFERENCE['rtol']:g} for diffrax",
                           atol_default=f"{_ALPHA_ATOL:g}; {_REFERENCE['atol']:g} for diffrax",
                           note="not on the uniform mesh")  # fmt: skip
    options.add_max_steps(solver)
    solver.add_argument("--save-dt", dest="save_dt", type=float, default=None, metavar="S",
                        help="output at t = 0, S, 2S, ... <= t_final (and t_final) [s], S in (0, t_final] (default: "
                        "error control writes its accepted steps; diffrax uses --dt)")  # fmt: skip
    folds = parser.add_argument_group("folds of phi (stick-slip jumps)")
    options.add_fold(folds, "--dt or --method diffrax")
    options.add_max_jumps(folds, default="as many as the run makes")
    options.add_statistics_window(folds, window=False, what="the cycle statistics (over [T, t_stop])")
    out = "write t, alpha, omega, u, v, F and the parameters: .npz (numpy), or .csv (text; the settings on # lines)"
    plot = "write v(t), alpha(t), F(t), or for a run with jumps v(t), G(t) and the G-v loop over phi(v, V)"
    options.add_output(parser, "progress (the elapsed wall time of a long run)", ("FILE.npz|FILE.csv", out), ("FILE.png", plot))


# ---------------------------------------------------------------------------- validation
@dataclass(frozen=True)
class RunConfig:
    """A validated run: everything the integrator and the writers need."""

    model: PeelingModel
    V: float
    tau: float
    dt: float | None  # the α-method's uniform step, or diffrax's output spacing; None: error control
    t_final: float
    n_steps: int | None  # uniform mesh (or diffrax output) intervals; None with error control
    method: str  # --method: "default", a stepper's name or "diffrax" (the reference)
    rho: float | None  # --method default or alpha only
    rtol: float | None  # error control or diffrax
    atol: float | None
    y0: tuple[float, ...] | None
    phi: str | None
    save_ts: tuple[float, ...] | None = None  # output times from --save-dt
    fold: str = "stop"  # what happens at a fold of φ (resolve_fold: jump under error control)
    max_jumps: int | None = None  # the jump record's size (error control); None: as many as the run makes
    transient: float = 0.0  # the cycle statistics' window starts here [s]
    phi_defaults: tuple[str, ...] | None = None  # coefficients --phi left at the paper's values
    max_steps: int | None = None  # error control's budget of step attempts; None: the library's

    @property
    def adaptive(self) -> bool:  # error control (any stepper), not the uniform mesh or the diffrax reference
        return self.method != "diffrax" and self.dt is None

    @property
    def uniform(self) -> bool:  # the α-method's uniform mesh (--dt)
        return self.method != "diffrax" and self.dt is not None

    @property
    def solver(self):  # the ``solver`` argument of peeljax.simulate (error control and the uniform mesh)
        return solver_for(self.method, self.rho)

    @property
    def budget(self) -> int | None:
        """The step budget the run gets: --max-steps, else the library's (None on the uniform mesh)."""
        if self.uniform or self.max_steps is not None:
            return self.max_steps
        return _REFERENCE["max_steps"] if self.method == "diffrax" else resolve_max_steps(None, keeps_steps=self.save_ts is None)

    @property
    def dae(self) -> bool:  # τ = 0: the DAE itself rather than the homogenized ODE
        return self.tau == 0.0


def validate_run(args: argparse.Namespace) -> RunConfig:
    """Check every option as the Python API would, without compiling anything."""
    reference = args.method == "diffrax"  # the Kvaerno5 reference: diffeqsolve's own loop, τ > 0, no fold events
    options.check_method(args.method, METHODS, args.dt, args.rho, (*_UNIFORM_METHODS, "diffrax"))
    check_positive("--V", args.V)
    if reference and args.tau == 0:
        raise ValueError("--tau 0 (the DAE itself, with jumps at the folds of phi) runs with error control (any stepper), "
                         f"not on the diffrax reference (--method diffrax): {_TO_ERROR_CONTROL}, or give tau in (0, "
                         f"{TAU_MAX:g}] (the homogenized ODE)")  # fmt: skip
    if args.tau != 0:  # τ = 0 on the uniform mesh: the library's refusal, when the integrator is made
        check_tau(args.tau, args.dt is None and not reference)
    check_positive("--t-final", args.t_final)
    dt = _REFERENCE["dt"] if reference and args.dt is None and args.save_dt is None else args.dt  # the reference's grid
    n_steps, save_ts = None if dt is None else check_mesh(dt, args.t_final), None
    if args.save_dt is not None:
        remedy = "give a larger --save-dt or a shorter --t-final"
        memory = lambda n: _check_memory(f"--save-dt {args.save_dt:g}", n, "ts", remedy)
        options.check_save_dt(args.save_dt, args.t_final, memory)  # counted first: the times could fill memory
        if dt is not None and not reference:  # the library's rule, in its words (option_names: the options')
            refuse_with_dt(dt, save_dt=args.save_dt)
        save_ts = tuple(output_times(args.save_dt, args.t_final))
    elif n_steps is not None:
        option = f"--dt {dt:g}" if args.dt is not None else "the diffrax output grid"
        _check_memory(option, n_steps + 1, "ts" if reference else "mesh", "give a larger --dt or a shorter --t-final")
    rho = (_RUN["rho"] if args.rho is None else args.rho) if args.method in _UNIFORM_METHODS else None  # the α-method's
    if reference and args.fold not in (None, "stop"):
        raise ValueError(f"--fold {args.fold} needs error control (any stepper), which cuts a step at a fold; with "
                         f"--method diffrax a run can only stop there: give --fold stop, or {_TO_ERROR_CONTROL}")  # fmt: skip
    max_jumps = options.check_max_jumps(args.max_jumps, None, "--method diffrax" if reference else None if args.dt is None else "--dt")
    transient, _ = options.check_statistics_window(args.transient, None, args.t_final)
    if reference:  # the diffrax reference: its own tolerances
        rtol, atol = options.check_tolerances(args.rtol, args.atol, (_REFERENCE["rtol"], _REFERENCE["atol"]))
        fold = "stop"
    else:  # the library's checks of ρ, the tolerances (not with --dt) and the fold mode; their defaults
        integrator = integrator_for(solver_for(args.method, rho), rho=_RUN["rho"] if rho is None else rho, dt=dt,
                                    t_final=args.t_final, rtol=args.rtol, atol=args.atol, fold=args.fold, dae=args.tau == 0)  # fmt: skip
        fold = getattr(getattr(integrator, "events", None), "mode", "stop")
        rtol, atol = (None, None) if dt is not None else (integrator.settings()[key] for key in ("rtol", "atol"))
    options.check_max_steps(args.max_steps, "--dt" if not reference and dt is not None else None)
    if args.max_steps is not None and save_ts is None and not reference:  # the accepted steps are the output
        _check_memory(f"--max-steps {args.max_steps}", args.max_steps + 1, "steps", "give a smaller --max-steps or a --save-dt")
    check_y0(args.y0)
    model, phi_defaults = options.model_from(args)
    options.check_outputs(args)
    return RunConfig(
        model=model, V=float(args.V), tau=float(args.tau), dt=None if dt is None else float(dt),
        t_final=float(args.t_final), n_steps=n_steps, method=args.method, rho=rho, rtol=rtol, atol=atol,
        y0=None if args.y0 is None else tuple(args.y0), phi=args.phi, save_ts=save_ts, fold=fold, max_jumps=max_jumps,
        transient=transient, phi_defaults=phi_defaults, max_steps=None if args.max_steps is None else int(args.max_steps))  # fmt: skip


_TO_ERROR_CONTROL = "choose a stepper with error control (--method default, or a name such as kvaerno5)"


def _check_memory(option: str, rows: int, kind: str, remedy: str) -> None:
    """The run's output must fit in memory (the rule of ``peeljax.simulate`` and ``peeljax.sweep``)."""
    try:
        check_run_memory(rows, kind, remedy=remedy)
    except ValueError as error:  # said with the option that asked for the rows
        raise ValueError(f"{option}: {error}") from None


# ---------------------------------------------------------------------------- running and reporting
def run(config: RunConfig) -> tuple[Solution, float]:
    """Integrate; returns the solution and the wall time [s] including compilation."""
    import jax

    start = time.perf_counter()
    ts = None if config.save_ts is None else np.asarray(config.save_ts)
    # --max-steps left out: the library's own budget (it depends on the output asked for)
    budget = {} if config.max_steps is None else {"max_steps": config.max_steps}
    if config.method == "diffrax":
        solution = simulate_reference(config.model, config.V, config.tau, config.dt if ts is None else None, config.t_final,
                                      config.y0, rtol=config.rtol, atol=config.atol, ts=ts, **budget)  # fmt: skip
    else:  # error control, or the uniform mesh (config.dt)
        control = {} if config.uniform else {"rtol": config.rtol, "atol": config.atol, "ts": ts, "fold": config.fold,
                                             "max_jumps": config.max_jumps, **budget}  # fmt: skip
        rho = _RUN["rho"] if config.rho is None else config.rho
        solution = simulate(config.model, config.V, config.tau, config.dt, config.t_final, rho, config.y0,
                            solver=config.solver, **control)  # fmt: skip
        if config.adaptive and ts is None:  # the accepted steps, without the rows left for more
            solution = solution.without_padding()
    solution = jax.block_until_ready(solution)  # JAX dispatches asynchronously: time the finished run
    return solution, time.perf_counter() - start


def step_used(solution: Solution, config: RunConfig) -> float:
    """The α-method's uniform step t_final/N, the diffrax output grid's spacing, or NaN (error control)."""
    if config.adaptive or config.uniform:
        return math.nan if config.adaptive else float(solution.stats["step_size"])
    if config.save_ts is not None:
        return float(config.save_ts[1] - config.save_ts[0]) if len(config.save_ts) > 1 else config.t_final
    return config.t_final / config.n_steps


def summarize(solution: Solution) -> dict:
    """:meth:`Solution.summary` (the ``--json`` fields of a run)."""
    return solution.summary()


def write_out(path: str, solution: Solution, config: RunConfig) -> None:
    """--out: :func:`write_npz`, or for a ``.csv`` the run's rows as text (:func:`peeljax.run_file.write_run_text`)."""
    from ..run_file import write_run_text

    if Path(path).suffix.lower() != ".csv":
        return write_npz(path, solution, config)
    write_run_text(path, solution, **_run_settings(solution, config))


def write_npz(path: str, solution: Solution, config: RunConfig) -> None:
    """The run as plain arrays and scalars (``np.load(path, allow_pickle=False)``; :func:`peeljax.load` reads it back):
    :func:`peeljax.run_file.write_run`, the one writer of the format, atomic."""
    from ..run_file import write_run

    write_run(path, solution, **_run_settings(solution, config))


def _run_settings(solution: Solution, config: RunConfig) -> dict:
    """The run's settings as :func:`peeljax.run_file.run_arrays` takes them."""
    return dict(model=config.model, V=config.V, tau=config.tau, t_final=config.t_final, dt=step_used(solution, config),
                rho=_rho_used(solution, config), rtol=config.rtol, atol=config.atol, method_option=config.method,
                fold=config.fold, max_jumps=config.max_jumps, transient=config.transient)  # fmt: skip


def _rho_used(solution: Solution, config: RunConfig) -> float | None:
    """ρ where the α-method ran (--method default may choose another stepper), else None."""
    return config.rho if config.rho is not None and solution.method.startswith("alpha") else None


def _simulate_command(args: argparse.Namespace, config: RunConfig) -> int:
    announce(config)
    # The run is one compiled loop: it reports its simulated time only at the end (a report from
    # inside would be a host callback in the integrator's loop); meanwhile the wall time is shown.
    with Elapsed(args.progress, f"simulating to t = {config.t_final:g} s"):
        solution, wall = run(config)
    summary = summarize(solution)
    record_size = getattr(solution.jumps, "max_jumps", config.max_jumps)  # --max-jumps, or the size the run grew to
    record = {
        **summary, "status_code": int(np.asarray(solution.status)),  # the StopReason (as in the .npz)
        "V": config.V, "tau": config.tau, "dt": step_used(solution, config), "dt_requested": config.dt,
        "save_dt": args.save_dt, "t_final": config.t_final, "n_steps": config.n_steps,
        "method": solution.method, "method_option": config.method,  # the stepper that ran, --method as given
        "geometry": config.model.geometry, "rho": _rho_used(solution, config), "rtol": config.rtol,
        "atol": config.atol, "y0": None if config.y0 is None else list(config.y0), "phi": config.phi,
        "phi_paper_defaults": None if config.phi_defaults is None else list(config.phi_defaults),
        "fold": config.fold, "max_jumps": record_size if config.adaptive else None,
        "max_steps": config.max_steps,  # --max-steps; null: the library's budget
        "transient": config.transient, "stats": {key: summary[key] for key in solution.stats if key in summary},
        "wall_time_s": wall, "out": args.out, "plot": args.plot}  # fmt: skip
    record.update({"note": note} if (note := regime_note(config)) else {})
    found = cycles(solution, config, record)
    if record.get("jumps"):  # the stick-slip figure: v(t) and G(t) with the jumps, the G-v loop
        settled = config.transient if config.transient < record["t_stop"] else None
        figure = plotter("plot_stick_slip", solution, config.model, config.V, transient=settled, title=plot_title(config, record))
    else:
        figure = plotter("plot_run", solution, config.model, V=config.V, title=plot_title(config, record))
    failed = write_files(record, ("--out", args.out, lambda path: write_out(path, solution, config)), ("--plot", args.plot, figure))
    return report(record, args.json, lambda: summary_lines(record, config, found), failed, "the run's summary is above",
                  remedy_notes(solution, config))  # fmt: skip
