"""``peeljax fit`` (:mod:`.fit`): the Levenberg-Marquardt fits, of a stick-slip table (``--table``,
:func:`peeljax.fit.fit_stick_slip`) and of force records (``--data`` with t, F:
:func:`peeljax.fit.fit_records`), and what every fit of the command shares: the library's
defaults, the refusal of an option of the other kind of fit, the report and Ctrl-C.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from .._validation import check_choice, check_positive, check_tau
from ..fit import DataFileError, Observation
from ..fit.parameters import check_free
from ..measurements.records import check_fit_samples
from ..fit.records_fit import fit_records, poorly_determined
from ..fit.table import INTERVALS, METHODS, fit_stick_slip
from ..fit.trajectory import fit_adhesion
from . import _interrupt, options
from .._files import check_input_file
from ._common import PROG, library_defaults, load_phi, plotter, report, write_files

# The fits' defaults, read from their home modules (the commands call ``peeljax.fit``'s).
_TABLE_DEFAULTS = library_defaults(fit_stick_slip)  # --table
_RECORDS_DEFAULTS = library_defaults(fit_records)  # --data force records (t, F)
_POINTS_DEFAULTS = library_defaults(fit_adhesion)  # --data runs with v or alpha, fitted point by point


def _files_of(paths: list[str], observations: list[Observation]) -> list[str]:
    """The --data file of each observation (an .npz may hold several; matched by order)."""
    if len(paths) == len(observations):
        return list(paths)
    return [f"{', '.join(paths)} (the run at V = {o.V:g})" for o in observations]


_TABLE_ONLY = ("transient", "window", "n_starts", "starts_deprecated", "max_iterations", "statistics", "method", "intervals")
_DATA_ONLY = ("V", "dt", "t_final", "learning_rate", "quantities", "steps", "optimizer", "patience")
_COUNTERPART = {"steps": "--max-iterations", "max_iterations": "--steps"}  # the other kind of fit's option for the job


def _refuse(args: argparse.Namespace, names: tuple[str, ...], source: str) -> None:
    for name in (name for name in names if getattr(args, name) is not None):
        option = "--starts" if name == "starts_deprecated" else "--" + name.replace("_", "-")
        instead = f" (its counterpart there is {_COUNTERPART[name]})" if name in _COUNTERPART else ""
        raise ValueError(f"{option} does not apply to {source}{instead}")


def _table_window(args: argparse.Namespace) -> tuple[float, float]:
    """--transient T and --window W of the table fit: statistics over [T, T + W], the runs end at T + W; the other
    commands' rule (the second half of the run): W defaults to T, T to 0.5 s (or to W when only --window is given)."""
    _, window = options.one_window(args.window, fractions_allowed=False)
    if window is not None:
        check_positive("--window", window)
    transient = (_TABLE_DEFAULTS["transient"] if window is None else window) if args.transient is None else args.transient
    if not (math.isfinite(transient) and transient >= 0):
        raise ValueError(f"--transient must be >= 0 [s] (allowed range: [0, inf)), got {transient:g}")
    if window is None and transient == 0:
        raise ValueError("--window must be > 0 [s] (allowed range: (0, inf)): with --transient 0 give --window")
    return float(transient), float(transient if window is None else window)


def _n_starts(args: argparse.Namespace) -> int | None:
    if args.starts_deprecated is not None:
        options.deprecated(f"--starts {args.starts_deprecated}", f"--n-starts {args.starts_deprecated}")
        if args.n_starts is not None:
            raise ValueError("--starts is the old spelling of --n-starts: give --n-starts only")
    n = args.n_starts if args.starts_deprecated is None else args.starts_deprecated
    spelled = "--n-starts" if args.starts_deprecated is None else "--starts (now --n-starts)"
    return None if n is None else _at_least_1(spelled, n)  # None: the library's, 1 with --method orbit, 3 with window


def _read_table(args: argparse.Namespace):
    from ..fit import read_stick_slip_table

    check_input_file("--table", args.table)
    if Path(args.table).suffix.lower() == ".npz":
        raise ValueError(f"--table {args.table!r}: a stick-slip table is text (CSV or whitespace columns V, F_mean, ...); "
                         "runs in an .npz are fitted with --data")  # fmt: skip
    try:
        return read_stick_slip_table(args.table)
    except DataFileError as error:
        raise ValueError(f"--table: {error}") from None
    except OSError as error:
        raise ValueError(f"--table: cannot read {args.table!r} ({error.strerror or error})") from None


def _validate_table(args: argparse.Namespace) -> dict:
    """--table's options, all checked before anything is compiled."""
    from ..measurements.stick_slip_table import STATISTICS
    from ..fit.table import table_tolerances

    table, source = _read_table(args), f"the stick-slip table {args.table}"
    tau = _TABLE_DEFAULTS["tau"] if args.tau is None else args.tau
    check_tau(tau, True)
    transient, window = _table_window(args)
    n_starts = _n_starts(args)
    max_iterations = _max_iterations(args, _TABLE_DEFAULTS)
    options.check_max_steps(args.max_steps)
    rtol, atol = options.check_tolerances(*table_tolerances(tau, args.rtol, args.atol), (None, None))
    free = _free(args, _TABLE_DEFAULTS)
    statistics = table.statistics if args.statistics is None else tuple(args.statistics)
    unknown = [s for s in statistics if s not in table.statistics]
    if unknown:
        raise ValueError(f"--statistics: {unknown} not in {source}, which has {', '.join(table.statistics)} (of "
                         f"{', '.join(STATISTICS)})")  # fmt: skip
    n_measured = sum(int(np.sum(~np.isnan(table.values[s]))) for s in statistics)
    if n_measured <= len(free):
        raise ValueError(f"--free: {n_measured} measured values in {source} cannot determine {len(free)} coefficient(s) "
                         "with an error estimate; fit fewer")  # fmt: skip
    method = _choice("--method", args.method, METHODS, "orbit" if tau == 0 else "window")
    if method == "orbit" and tau != 0:
        raise ValueError(f"--method orbit needs --tau 0 (orbits of the DAE with jumps); --tau {tau:g} needs --method window")
    intervals = _choice("--intervals", args.intervals, INTERVALS, _TABLE_DEFAULTS["intervals"])
    start = load_phi(args.phi)
    options.check_outputs(args)
    return {
        "method": method, "intervals": intervals, "table": table, "source": source, "tau": float(tau),
        "transient": transient, "window": window, "n_starts": n_starts, "max_iterations": int(max_iterations),
        "rtol": rtol, "atol": atol, "free": free, "statistics": tuple(statistics), "start": start,
        **({} if args.max_steps is None else {"max_steps": int(args.max_steps)}),  # left out: fit_stick_slip's budget
    }  # fmt: skip


def _choice(option: str, value, allowed: tuple[str, ...], default: str) -> str:
    """An option among ``allowed``; ``default`` (the library's) when not given."""
    check_choice(option, default if value is None else value, allowed)
    return default if value is None else value


def _max_iterations(args: argparse.Namespace, defaults: dict) -> int:
    """--max-iterations >= 1; the fit's own default (``defaults``, the library's) when not given."""
    n = defaults["max_iterations"] if args.max_iterations is None else args.max_iterations
    return _at_least_1("--max-iterations", n)


def _at_least_1(option: str, n: int) -> int:
    if n < 1:
        raise ValueError(f"{option} must be >= 1 (allowed range: [1, inf)), got {n}")
    return int(n)


def _free(args: argparse.Namespace, defaults: dict) -> tuple[str, ...]:
    """--free, checked by the library; the fit's own default (``defaults``) when not given."""
    free = tuple(defaults["free"]) if args.free is None else tuple(args.free)
    check_free(free)
    return free


def _validate_records(args: argparse.Namespace, observations: list[Observation], defaults: dict) -> dict:
    """The options of force records fitted by statistics and/or point by point
    (:func:`peeljax.fit.fit_records`), all checked before anything is compiled."""
    from ..fit.records_fit import BY, how_fitted
    from ..model import PeelingModel

    _refuse(args, _DATA_ONLY[1:], "force records (t, F): fitted by their statistics or point by point")
    _refuse(args, ("window", "n_starts", "starts_deprecated", "method"),
            "force records (t, F) (their statistics run from --transient to each record's end)")  # fmt: skip
    by = _choice("--by", args.by, BY, _RECORDS_DEFAULTS["by"])
    transient = args.transient
    if transient is not None:
        t_end = min(float(np.nanmax(o.series("F")[0])) for o in observations if o.series("F") is not None)
        if not (math.isfinite(transient) and 0 <= transient < t_end):
            raise ValueError(f"--transient must lie in [0, {t_end:g}) [s] for these records (their statistics are "
                             f"taken after it), got {transient:g}")  # fmt: skip
    start = load_phi(args.phi)
    try:  # a record of too few slips to tell is judged by the start's own run, as fit_records does
        decided = how_fitted(observations, by, transient, PeelingModel(adhesion=start))
    except ValueError as error:
        raise ValueError(f"--by {by}: {error}") from None
    points = [o for o, (kind, _) in zip(observations, decided) if kind == "points"]
    if points:
        names = [f"--data {name}" for name, (kind, _) in zip(_files_of(args.data, observations), decided) if kind == "points"]
        check_fit_samples(points, names, "--decimate")
    tau = _points_tau(args, defaults)  # the τ of records fitted point by point
    from ..measurements.stick_slip_table import STATISTICS

    statistics = None if args.statistics is None else tuple(args.statistics)
    if unknown := [name for name in statistics or () if name not in STATISTICS]:
        raise ValueError(f"--statistics: {unknown} is not a statistic of force records; allowed: {', '.join(STATISTICS)}")
    max_iterations = _max_iterations(args, _RECORDS_DEFAULTS)
    free = _free(args, _RECORDS_DEFAULTS)
    rtol, atol = options.check_tolerances(args.rtol, args.atol, (_RECORDS_DEFAULTS["rtol"], _RECORDS_DEFAULTS["atol"]))
    intervals = _choice("--intervals", args.intervals, INTERVALS, _RECORDS_DEFAULTS["intervals"])
    options.check_outputs(args)
    return {"records": observations, "decided": decided, "by": by, "transient": transient, "tau": float(tau),
            "statistics": statistics, "max_iterations": int(max_iterations), "free": free, "rtol": rtol, "atol": atol,
            "intervals": intervals, "start": start}  # fmt: skip


_RECORDS_KEYS = ("free", "by", "transient", "tau", "rtol", "atol", "max_iterations", "statistics", "intervals")


def _records_command(args: argparse.Namespace, config: dict) -> int:
    """``peeljax fit --data`` with force records: :func:`peeljax.fit.fit_records`."""
    from ..fit import fit_records
    from ..model import PeelingModel

    for name, (kind, why) in zip(_files_of(args.data, config["records"]), config["decided"]):
        print(f"{PROG}: --data {name}: fitted by {kind} ({why})", file=sys.stderr)
    print(f"{PROG}: fitting {', '.join(config['free'])}; compiling first ...", file=sys.stderr)
    model, given = PeelingModel(adhesion=config["start"]), {key: config[key] for key in _RECORDS_KEYS}
    try:
        result = fit_records(config["records"], model, **given,
                             progress=_iteration_line("Levenberg-Marquardt") if args.progress else None)  # fmt: skip
    except KeyboardInterrupt as stop:
        return _interrupted_fit(stop, args)
    by_points = any(kind == "points" for kind, _ in config["decided"])  # each record's F(t) against the model's, and φ
    figure = plotter("plot_records_fit", result, config["records"], model=model, tau=config["tau"] if by_points else 0.0,
                     module="peeljax.plots.fit")  # fmt: skip
    poorly = None if args.json else poorly_determined(result, config["records"])
    notes = [] if poorly is None else [f"{PROG}: {poorly}"]
    return _report_lm(result, args, {"data": args.data, "phi": args.phi}, [result.summary()], figure, notes)


def _finish(record: dict, args: argparse.Namespace, lines: list[str], failed, notes=()) -> int:
    """A fit's report: --json or ``lines`` and the files written."""
    written = [record[key] for key in ("out", "plot") if record.get(key)]
    lines = lines + ["wrote " + " and ".join(written)] * bool(written)
    return report(record, args.json, lines, failed, "the fit's result is above", notes)


def _visited_line(record: dict) -> str:
    low, high = record["v_range"]
    return f"visited v in [{low:.3g}, {high:.3g}] m/s: phi is determined by the data only there"


def _report_lm(result, args: argparse.Namespace, settings: dict, lines: list[str], figure, notes=()) -> int:
    """A Levenberg-Marquardt fit's result (--table, force records): --out, --plot, the report."""
    result.settings.update(settings)
    record = {**result.to_dict(), "out": args.out, "plot": args.plot}
    failed = write_files(record, ("--out", args.out, result.to_json), ("--plot", args.plot, figure))
    return _finish(record, args, [*lines, _visited_line(record)], failed, notes)


def _interrupted_fit(stop: KeyboardInterrupt, args: argparse.Namespace, write=None) -> int:
    """Ctrl-C during a fit: its best point so far (``FitInterrupted.best``) written to --out
    where there is one, and the line on stderr says what was kept (exit 130)."""
    from ..fit import FitInterrupted

    best = stop.best if isinstance(stop, FitInterrupted) else None
    if best is None:
        return _interrupt.interrupted("nothing was fitted yet" + (f"; {args.out!r} not written" if args.out else ""))
    if args.out is None:
        coefficients = best.adhesion.coefficients()
        found = ", ".join(f"{name} = {coefficients[name]:.6g}" for name in best.free)
        return _interrupt.interrupted(f"the best point so far ({best.stop_reason}): {found}; not saved (no --out)")
    if write is not None:
        write(best, args)
    else:
        best.settings.update({"data": args.data, "table": getattr(args, "table", None), "phi": args.phi})
        best.to_json(args.out)
    return _interrupt.interrupted(f"{args.out!r} holds the best point so far ({best.stop_reason})")


def _iteration_line(what: str):
    """A progress callable for the Levenberg-Marquardt fits: one line per iteration on stderr."""
    began = time.perf_counter()
    return lambda iteration, loss: print(f"{PROG}: {what}: iteration {iteration}, loss {loss:.6g} "
                                         f"({time.perf_counter() - began:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip


def _table_command(args: argparse.Namespace, config: dict) -> int:
    """``peeljax fit --table``: Levenberg-Marquardt on the stick-slip statistics, with uncertainties."""
    from ..fit import fit_stick_slip
    from ..model import PeelingModel

    table, T, W = config["table"], config["transient"], config["window"]
    print(f"{PROG}: fitting {', '.join(config['free'])} to {config['source']} ({len(table)} rows, V = "
          f"{', '.join(f'{V:g}' for V in table.V)}; {', '.join(config['statistics'])}), tau {config['tau']:g}, statistics "
          f"over [{T:g}, {T + W:g}] s (--transient {T:g} --window {W:g}), at most {config['max_iterations']} iterations; "
          "compiling first ...", file=sys.stderr)  # fmt: skip
    model = PeelingModel(adhesion=config["start"])
    # the hook of fit_stick_slip (progress(iteration, chi2)); left out where it has none
    hooked = args.progress and "progress" in _TABLE_DEFAULTS
    progress = {"progress": _iteration_line("Levenberg-Marquardt")} if hooked else {}
    given = {key: value for key, value in config.items() if key not in ("table", "source", "start")}
    try:
        result = fit_stick_slip(table, model, **given, **progress)
    except KeyboardInterrupt as stop:
        return _interrupted_fit(stop, args)
    lines = [
        f"peeljax fit: {result.steps} iterations (Levenberg-Marquardt), loss {result.initial_loss:.4g} -> {result.final_loss:.4g}",
        f"stopped: {result.stop_reason}",
        *result.summary().splitlines()[2:],  # the coefficients, each row's attractor, the bifurcations, the intervals
    ]
    figure = plotter("plot_table_fit", result, table, model=model, module="peeljax.plots.fit")
    return _report_lm(result, args, {"table": args.table, "data": args.data, "phi": args.phi}, lines, figure)


def _points_tau(args: argparse.Namespace, defaults: dict) -> float:
    """τ of a fit point by point: --tau, else the data files' own (an .npz run's), else the library's; in (0, 1e6]. Files
    of DAE runs (τ = 0) take the default too, said on stderr: a fit point by point integrates the homogenized ODE."""
    default = _POINTS_DEFAULTS["tau"]
    if args.tau is None and defaults.get("tau") == 0.0:
        print(f"{PROG}: --data: the files hold runs at tau = 0 (the DAE with jumps; a jump's two rows read as the state "
              f"before it); a fit point by point integrates the homogenized ODE: tau = {default:g} (--tau to choose; "
              "1e-3 is closer to the DAE)", file=sys.stderr)  # fmt: skip
        return default
    tau = args.tau if args.tau is not None else defaults.get("tau", default)
    check_tau(tau)
    return tau
