"""``peeljax fit``: fit the adhesion law's coefficients to observed runs (docs/fitting.md).

* ``--data`` (repeatable): runs as ``.npz`` (a ``peeljax simulate --out`` file among them: its
  ``tau`` becomes the default) or force records as text (columns t, F; optionally v, alpha and
  V), read by :mod:`peeljax.measurements.records`, never executed. Runs with v or alpha are fitted point
  by point (:func:`peeljax.fit.fit_adhesion`), force records by their stick-slip statistics or
  point by point (:func:`peeljax.fit.fit_records`).
* ``--table``: a stick-slip table (:func:`peeljax.fit.read_stick_slip_table`), fitted by
  Levenberg-Marquardt with uncertainties (:func:`peeljax.fit.fit_stick_slip`).

``--out`` gets the fitted coefficients at top level (``--phi`` and ``AdhesionLaw.from_json``
read it) with the fit's record; every default is the library function's.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .._atomic import write_text
from .._files import json_safe
from .._validation import check_choice, check_mesh, check_positive
from ..adhesion import COEFFICIENT_NAMES
from ..fit import QUANTITIES, Observation
from ..fit.parameters import check_free
from ..measurements.records import check_fit_samples, load_observations
from ..fit.records_fit import is_force_record
from ..fit.trajectory import OPTIMIZERS
from ..integrators.select import DEFAULT_ATOL, DEFAULT_MAX_STEPS, DEFAULT_RTOL, refuse_with_dt
from . import options
from ._common import PROG, checked, load_phi, plotter, subcommand, write_files
from .fit_table import (_DATA_ONLY, _POINTS_DEFAULTS, _RECORDS_DEFAULTS, _TABLE_DEFAULTS, _TABLE_ONLY, _at_least_1, _files_of, _finish,
                        _interrupted_fit, _points_tau, _records_command, _refuse, _table_command, _validate_records,
                        _validate_table, _visited_line)  # fmt: skip

__all__ = ["add_command"]


# The options of the group "the fit": (option, type, nargs, metavar, help); dest the option's name.
_FIT_OPTIONS = (
    ("--quantities", None, "+", "Q", "--data: the subset of v F alpha to fit (default: all in the data)"),
    ("--by", None, None, "{auto,statistics,points}", "--data force records (t, F): fit each by its stick-slip "
     "statistics, or point by point; auto: by statistics where it stick-slips (at least 10 slips after --transient), "
     "else by points (default auto; the choice is said on stderr)"),
    ("--method", None, None, "{orbit,window}", "--table: each row's statistics from its attractor (orbit: the "
     "periodic orbit's over one period, steady peeling's phi(V, V), a window where no periodic attractor) or from a "
     "window of a run from rest (window; needed for --tau > 0) (default orbit)"),
    ("--intervals", None, None, "{auto,profile,linear}", "--table and force records: profile-likelihood intervals "
     "beside the linearized ones where a bifurcation lies within them (auto), always (profile), never (linear) "
     "(default auto)"),
    ("--statistics", None, "+", "S", "--table: the table's statistics to fit (default: all it has)"),
    ("--steps", int, None, None, f"--data: optimizer iterations, >= 1 (default {_POINTS_DEFAULTS['steps']})"),
    ("--optimizer", None, None, "{adam,lbfgs}", f"--data: adam or lbfgs (default {_POINTS_DEFAULTS['optimizer']})"),
    ("--learning-rate", float, None, None, "--data: > 0 (default adam 0.02, lbfgs its line search)"),
    ("--patience", int, None, None, "--data: stop after this many iterations without progress, >= 1 (default "
     f"{_POINTS_DEFAULTS['patience']})"),
    ("--max-iterations", int, None, None, f"--table: Levenberg-Marquardt iterations at most, >= 1 (default "
     f"{_TABLE_DEFAULTS['max_iterations']}; force records {_RECORDS_DEFAULTS['max_iterations']})"),
    ("--n-starts", int, None, "N", "--table: Levenberg-Marquardt runs from the N best starting points, >= 1 (default "
     "1 with --method orbit, 3 with --method window)"))  # fmt: skip


def add_command(subparsers) -> None:
    parser = subcommand(subparsers, "fit", checked(_validate_fit, _fit_command), "fit the adhesion law phi to observed runs", (
        "Fit phi's coefficients to observed v(t) (and F(t), alpha(t)) at one or more V with exact gradients through the "
        "alpha-method (--data), or to a stick-slip table by Levenberg-Marquardt with uncertainties (--table). Data keys: "
        "t, v, V (optional F, alpha, t_F, t_alpha) per file, or V_0, t_0, v_0, V_1, ... for several V in one file."
    ), out_formats=(".json",))  # fmt: skip
    source = parser.add_argument_group("what is fitted (one of --data and --table)")
    source.add_argument("--data", action="append", default=None, metavar="FILE",
                        help="observations (repeatable): .npz, or a force record as CSV / whitespace text with a header naming "
                        "its columns: t [s], F [N] (the tension), optional v [m/s], alpha [rad], V [m/s] (default: none)")  # fmt: skip
    source.add_argument("--table", default=None, metavar="TABLE.csv",
                        help="instead of --data: a stick-slip table (CSV / whitespace text, columns V and any of F_mean, "
                        "F_slip, F_stick, period, slip_duration, each optionally with <name>_std), fitted by "
                        "Levenberg-Marquardt with uncertainties (default: none)")  # fmt: skip
    options.add_V(source, many=True, default=None, help="--data: the pull velocity [m/s] of text files that carry it "
                  "neither in a V column nor in their name (peel_V=1.1.csv), one value for all or one per file")  # fmt: skip
    source.add_argument("--decimate", type=int, default=None, metavar="N",
                        help="--data: keep every N-th sample of each file, N >= 1 (measured values, no filter): for a "
                        "record denser than the fit can hold (default: all samples)")  # fmt: skip
    problem = parser.add_argument_group("the model's runs")
    problem.add_argument("--tau", type=options.number("--tau"), default=None,
                         help="tau [s]: --data in (0, 1e6] (default: the data files' tau, else 0.01); --table in [0, "
                         "1e6] (default 0: the DAE with jumps)")  # fmt: skip
    options.add_t_final(problem, default=None, help="--data: end time of the runs [s], > 0 (default: the last observation)")
    problem.add_argument("--dt", type=float, default=None, help="--data: run the model on the uniform mesh of this step "
                         "[s], in (0, t_final] (default: error control)")  # fmt: skip
    options.add_tolerances(problem, rtol_default=f"{DEFAULT_RTOL:g}; --table: 1e-9 at tau 0, else 1e-7",
                           atol_default=f"{DEFAULT_ATOL:g}; --table: 1e-12 at tau 0, else 1e-10")  # fmt: skip
    options.add_max_steps(problem, default=f"{DEFAULT_MAX_STEPS} with --data, {_TABLE_DEFAULTS['max_steps']} with --table")
    options.add_statistics_window(
        problem, transient="0.5 s with --table, where the model's runs end at T + W: their second half; with --data "
        "force records fitted by statistics, the record's second half", window_default="T: the runs' second half",
        what="the statistics (--table: of the model's runs; --data: of each force record)")  # fmt: skip
    fit = parser.add_argument_group("the fit")
    fit.add_argument("--phi", metavar="START.json", help="start coefficients as JSON (default: the paper's law)")
    fit.add_argument("--free", nargs="+", metavar="NAME", default=None,
                     help=f"coefficients to fit, of c1, p1, ..., p9 (default all {len(COEFFICIENT_NAMES)}; --table: "
                     f"{' '.join(_TABLE_DEFAULTS['free'])}; force records: {' '.join(_RECORDS_DEFAULTS['free'])})")  # fmt: skip
    for option, kind, nargs, metavar, text in _FIT_OPTIONS:
        fit.add_argument(option, type=kind, nargs=nargs, metavar=metavar, default=None, help=text)
    fit.add_argument("--starts", dest="starts_deprecated", type=int, default=None, help=argparse.SUPPRESS)
    options.add_output(parser, "progress (iterations and loss)",
        out=("FITTED.json", "the fitted coefficients, loss history and settings (required with --data; with --table "
             "also the uncertainty, residuals and stop reason)"),
        plot=("FIT.png", "data vs fitted model, and fitted phi vs start (--table: with residuals and phi's 95%% band)"))  # fmt: skip


def _check_source(args: argparse.Namespace) -> None:
    """Exactly one of --data and --table, and no option of the other kind."""
    if args.data is not None and args.table is not None:
        raise ValueError("--table and --data exclude each other: fit a stick-slip table or runs, not both")
    if args.data is None and args.table is None:
        raise ValueError("give --data FILE (runs to fit) or --table TABLE.csv (a stick-slip table to fit)")
    if args.table is not None:
        _refuse(args, (*_DATA_ONLY, "decimate", "by"), "--table")
    if args.data is not None and args.out is None:
        raise ValueError("--out FITTED.json is required with --data")


def _fit_runs(fit_adhesion, observations, config: dict, args: argparse.Namespace):
    """:func:`peeljax.fit.fit_adhesion` with the command's settings."""
    given = {key: config[key] for key in ("tau", "dt", "t_final", "start", "weights", "rtol", "atol", "max_steps") if key in config}
    return fit_adhesion(observations, free=args.free, optimizer=args.optimizer, steps=args.steps, patience=args.patience,
                        learning_rate=args.learning_rate, progress=args.progress, **given)  # fmt: skip


def _write_fit(result, args: argparse.Namespace) -> None:
    """--out: the fitted coefficients and the fit's record as JSON (``--phi`` reads it)."""
    record = result.to_dict()
    record["settings"] = {**record["settings"], "data": list(args.data), "phi": args.phi}
    write_text(args.out, json.dumps(json_safe(record), indent=2, allow_nan=False) + "\n")


def _check_run_options(args: argparse.Namespace) -> None:
    """The options of a point-by-point fit whose ranges need no data file (checked first)."""
    if args.optimizer is not None:
        check_choice("--optimizer", args.optimizer, OPTIMIZERS)
    for option, value in (("--steps", args.steps), ("--patience", args.patience)):
        if value is not None:
            _at_least_1(option, value)
    options.check_max_steps(args.max_steps, None if args.dt is None else "--dt")
    if args.learning_rate is not None:
        check_positive("--learning-rate", args.learning_rate)
    if args.free is not None:
        check_free(args.free)
    for quantity in args.quantities or ():
        check_choice("--quantities", quantity, QUANTITIES)


def _validate(args: argparse.Namespace, observations: list[Observation], defaults: dict) -> dict:
    _refuse(args, _TABLE_ONLY, "--data with v or alpha (a point-by-point fit of the runs)")
    for name in (name for name in ("optimizer", "steps", "patience") if getattr(args, name) is None):
        setattr(args, name, _POINTS_DEFAULTS[name])  # None until here, so that a table fit can refuse them
    check_fit_samples(observations, [f"--data {name}" for name in _files_of(args.data, observations)], "--decimate")
    if args.quantities is not None:
        drop = {q: None for q in ("F", "alpha") if q not in args.quantities}
        observations = [Observation(**{**o.__dict__, **drop}) for o in observations]
    tau, dt, rtol, atol, n_steps = _points_tau(args, defaults), args.dt, args.rtol, args.atol, None
    t_final = args.t_final if args.t_final is not None else max(float(np.nanmax(o.t)) for o in observations)
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol)  # the library's rule (option_names: in the options' words)
        n_steps = check_mesh(dt, t_final)
    else:
        check_positive("--t-final", t_final)
        rtol, atol = options.check_tolerances(rtol, atol, (DEFAULT_RTOL, DEFAULT_ATOL))
    start = load_phi(args.phi)
    options.check_outputs(args)
    weights = {q: (1.0 if args.quantities is None or q in args.quantities else 0.0) for q in QUANTITIES}
    return {
        "observations": observations, "tau": float(tau), "dt": None if dt is None else float(dt), "t_final": float(t_final),
        "n_steps": n_steps, "rtol": rtol, "atol": atol, "start": start, "weights": weights,
        **({} if args.max_steps is None else {"max_steps": int(args.max_steps)}),  # left out: the library's
    }  # fmt: skip


def _engine(config: dict) -> str:
    if config["dt"] is not None:
        return f"uniform mesh of {config['n_steps']} steps"
    budget = config.get("max_steps", DEFAULT_MAX_STEPS)
    return f"error control rtol {config['rtol']:g}, atol {config['atol']:g}, at most {budget} step attempts a run"


def _validate_fit(args: argparse.Namespace) -> dict:
    """Every option checked before anything is fitted: the kind of fit from the source (a table, force records, runs
    with v or alpha) and its options."""
    _check_source(args)
    if args.table is not None:
        return _validate_table(args)
    _check_run_options(args)
    observations, defaults = load_observations(args.data, None if args.V is None else options.flatten(args.V), args.decimate)
    if args.by is not None or any(is_force_record(o) for o in observations):
        return _validate_records(args, observations, defaults)
    return _validate(args, observations, defaults)


def _fit_command(args: argparse.Namespace, config: dict) -> int:
    if "table" in config:
        return _table_command(args, config)
    if "records" in config:
        return _records_command(args, config)
    from ..fit import fit_adhesion

    observations = config["observations"]
    print(f"{PROG}: fitting {len(args.free or COEFFICIENT_NAMES)} coefficient(s) to {len(observations)} run(s) (V = "
          f"{', '.join(f'{o.V:g}' for o in observations)}), {_engine(config)}; compiling first ...", file=sys.stderr)  # fmt: skip
    try:
        result = _fit_runs(fit_adhesion, observations, config, args)
    except KeyboardInterrupt as stop:
        return _interrupted_fit(stop, args, write=_write_fit)
    uncertainty = getattr(result, "uncertainty", None)
    record = {
        "out": args.out, "plot": args.plot, "steps": result.steps, "initial_loss": result.initial_loss,
        "final_loss": result.final_loss, "loss_reduction": result.loss_reduction,
        "gradient_norm": result.gradient_norm, "v_range": list(result.v_range), "free": list(result.free),
        "coefficients": result.adhesion.coefficients(),
        "uncertainty": None if uncertainty is None else uncertainty.as_dict(), "wall_time_s": result.wall_time_s}  # fmt: skip
    failed = write_files(record, ("--out", args.out, lambda path: _write_fit(result, args)),
                         ("--plot", args.plot, plotter("plot_fit", result, observations)))  # fmt: skip
    fitted = ", ".join(f"{n} {result.adhesion.coefficients()[n]:.6g}" for n in result.free)
    return _finish(record, args, [
        f"peeljax fit: {result.steps} iterations ({args.optimizer}), loss {result.initial_loss:.4g} -> {result.final_loss:.4g} "
        f"({result.loss_reduction:.3g}x), gradient norm {result.gradient_norm:.3g}", _visited_line(record),
        uncertainty.table() if uncertainty is not None else f"fitted: {fitted}"], failed)  # fmt: skip
