"""``peeljax fit``: fit the adhesion law's coefficients to observed runs.

Data files (``--data``, repeatable; read by :mod:`peeljax.fit.data`, never executed):

* a force record: CSV or whitespace-separated text, ``#`` comment lines, a header naming the
  columns ``t`` [s] and ``F`` [N] (the tension), optionally ``v`` [m/s], ``alpha`` [rad] and a
  constant ``V`` [m/s]; the pull velocity from that column, the file name (``peel_V=1.1.csv``)
  or ``--V`` (one value for all such files, or one per ``--data``), which must agree;
* ``.npz`` (``np.load(..., allow_pickle=False)``), either layout:

  - one pull velocity per file: a scalar ``V`` and 1-D arrays ``t``, ``v`` of one length, and
    optionally ``F`` (the tension [N]) and ``alpha`` [rad], on the same times ``t`` or on their
    own ``t_F`` / ``t_alpha``. A ``peeljax simulate --out`` file is such a file (its NaN
    entries after a stop are ignored; its ``tau`` becomes the default);
  - several pull velocities in one file: ``V_0, t_0, v_0`` (and ``F_0, alpha_0, t_F_0,
    t_alpha_0``), ``V_1, t_1, v_1``, … with consecutive indices from 0.

Output (``--out``): a JSON object with the 14 coefficients ``c1, p1, …, p9`` at top level
(``AdhesionLaw.from_json`` and ``--phi`` read it), ``loss_history``, ``initial_loss``,
``final_loss``, ``gradient_norm``, ``v_range`` (the visited v: φ is determined only there),
``start`` and ``settings``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from .._validation import check_mesh, check_positive, check_tolerance
from ..adhesion import COEFFICIENT_NAMES, AdhesionLaw
from ..fit import QUANTITIES, Observation
from ..fit.data import DataFileError, read_force_record, read_npz
from ..integrators.select import DEFAULT_ATOL, DEFAULT_RTOL
from ._common import PROG, check_output_path, checked, fail, json_safe, load_phi, plot_formats

__all__ = ["add_command", "load_observations"]

OPTIMIZERS = ("adam", "lbfgs")


def add_command(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit",
        help="fit the adhesion law phi to observed runs",
        description=(
            "Fit phi's coefficients to observed v(t) (and F(t), alpha(t)) at one or more pull velocities "
            "with exact gradients through the alpha-method. Data keys: t, v, V (optional F, alpha, t_F, t_alpha) "
            "per file, or V_0, t_0, v_0, V_1, ... for several V in one file."
        ),
    )
    parser.add_argument(
        "--data",
        action="append",
        required=True,
        metavar="FILE",
        help="observations (repeatable): .npz, or a force record as CSV / whitespace text with a header naming "
        "its columns: t [s], F [N] (the tension), optional v [m/s], alpha [rad], V [m/s]",
    )
    parser.add_argument(
        "--V",
        dest="V",
        type=float,
        nargs="+",
        default=None,
        metavar="V",
        help="pull velocity [m/s] of text --data files that carry it neither in a V column nor in their name "
        "(peel_V=1.1.csv): one value for all files, or one per --data file in order",
    )
    parser.add_argument(
        "--out", required=True, metavar="FITTED.json", help="the fitted coefficients, loss history and settings"
    )
    parser.add_argument(
        "--tau", type=float, default=None, help="tau [s], > 0 (default: the data files' tau, else 0.01)"
    )
    parser.add_argument(
        "--dt",
        type=float,
        default=None,
        help="run the model on the uniform mesh of this step [s] (default: the error-controlled alpha-method)",
    )
    parser.add_argument(
        "--rtol",
        type=float,
        default=None,
        help="error control's relative tolerance in (0, 1) (default 1e-6; not with --dt)",
    )
    parser.add_argument("--atol", type=float, default=None, help="its absolute tolerance, > 0 (default 1e-9; not with --dt)")
    parser.add_argument(
        "--t-final", dest="t_final", type=float, default=None, help="end time (default: last observation)"
    )
    parser.add_argument("--steps", type=int, default=500, help="optimizer iterations, >= 1 (default %(default)s)")
    parser.add_argument("--optimizer", default="adam", metavar="{adam,lbfgs}", help="adam (default) or lbfgs")
    parser.add_argument(
        "--learning-rate",
        dest="learning_rate",
        type=float,
        default=None,
        help="> 0 (default adam 0.02, lbfgs line search)",
    )
    parser.add_argument("--patience", type=int, default=50, help="early stopping patience, >= 1 (default %(default)s)")
    parser.add_argument("--free", nargs="+", metavar="NAME", default=None, help="coefficients to fit (default all 14)")
    parser.add_argument(
        "--quantities",
        nargs="+",
        metavar="Q",
        default=None,
        help="subset of v F alpha to fit (default: all in the data)",
    )
    parser.add_argument("--phi", metavar="START.json", help="start coefficients (default: the paper's law)")
    parser.add_argument("--plot", metavar="FIT.png", help="data vs fitted model, and fitted phi vs start")
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.set_defaults(handler=_fit_command)


def _V_per_file(paths: list[str], V) -> list[float | None]:
    """--V: one pull velocity for every --data file, or one per file in order (None: not given)."""
    if V is None:
        return [None] * len(paths)
    values = list(V) if isinstance(V, (list, tuple)) else [V]
    for value in values:
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"--V must be > 0 [m/s] (allowed range: (0, inf)), got {value:g}")
    if len(values) == 1:
        return values * len(paths)
    if len(values) != len(paths):
        raise ValueError(
            f"--V takes one value for all --data files or one per file: {len(values)} values for {len(paths)} files"
        )
    return values


def load_observations(paths: list[str], V=None) -> tuple[list[Observation], dict]:
    """Observations from the --data files and the .npz files' tau/dt where they agree.

    ``.npz`` files keep their layouts (module docstring); any other file is a text force
    record (:func:`peeljax.fit.data.read_force_record`: a CSV or whitespace table with columns
    t, F and optionally v, alpha, V). ``V`` (``--V``): the pull velocity of text files that carry
    it neither in a V column nor in their name, one value for all files or one per file.

    Raises:
        ValueError: starting with ``--data`` and naming the file (and the line and column or
            field at fault), or naming ``--V``.
    """
    observations, defaults = [], {"tau": set(), "dt": set()}
    for path, V_file in zip(paths, _V_per_file(paths, V)):
        if not Path(path).is_file():
            raise ValueError(f"--data: file {path!r} does not exist")
        try:
            if Path(path).suffix.lower() == ".npz":
                found, settings = read_npz(path, V=V_file)
                for key, value in settings.items():
                    defaults[key].add(value)
            else:
                found = [read_force_record(path, V=V_file)]
        except DataFileError as error:
            raise ValueError(f"--data: {error}") from None
        observations.extend(found)
    return observations, {k: next(iter(v)) for k, v in defaults.items() if len(v) == 1}


def _validate(args: argparse.Namespace) -> dict:
    if args.optimizer not in OPTIMIZERS:
        raise ValueError(f"--optimizer must be one of {', '.join(OPTIMIZERS)}, got {args.optimizer!r}")
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1 (allowed range: [1, inf)), got {args.steps}")
    if args.patience < 1:
        raise ValueError(f"--patience must be >= 1 (allowed range: [1, inf)), got {args.patience}")
    if args.learning_rate is not None:
        checked("(0, inf)", check_positive, "learning_rate", args.learning_rate)
    if args.free is not None:
        unknown = [n for n in args.free if n not in COEFFICIENT_NAMES]
        if unknown:
            raise ValueError(f"--free: unknown coefficient(s) {unknown}; allowed: {', '.join(COEFFICIENT_NAMES)}")
    if args.quantities is not None:
        unknown = [q for q in args.quantities if q not in QUANTITIES]
        if unknown or "v" not in args.quantities and not args.quantities:
            raise ValueError(f"--quantities: unknown {unknown}; allowed: {', '.join(QUANTITIES)}")
    observations, defaults = load_observations(args.data, args.V)
    if args.quantities is not None:
        drop = {q: None for q in ("F", "alpha") if q not in args.quantities}
        observations = [Observation(**{**o.__dict__, **drop}) for o in observations]
    tau = args.tau if args.tau is not None else defaults.get("tau", 0.01)
    dt = args.dt
    checked("(0, inf)", check_positive, "tau", tau)
    t_last = max(float(np.nanmax(o.t)) for o in observations)
    t_final = args.t_final if args.t_final is not None else t_last
    rtol, atol = args.rtol, args.atol
    if dt is not None:
        for option, value in (("--rtol", rtol), ("--atol", atol)):
            if value is not None:
                raise ValueError(f"{option} sets the error control that --dt replaces by a uniform mesh: give one of them")
        n_steps = checked("dt in (0, t_final], t_final in (0, inf)", check_mesh, dt, t_final)
    else:
        checked("(0, inf)", check_positive, "t_final", t_final)
        rtol = DEFAULT_RTOL if rtol is None else rtol
        atol = DEFAULT_ATOL if atol is None else atol
        checked("(0, 1)", check_tolerance, "rtol", rtol, 1.0)
        checked("(0, inf)", check_tolerance, "atol", atol)
        n_steps = None
    start = AdhesionLaw() if args.phi is None else load_phi(args.phi)
    check_output_path("--out", args.out)
    if args.plot is not None:
        check_output_path("--plot", args.plot, plot_formats())
    weights = {q: (1.0 if args.quantities is None or q in args.quantities else 0.0) for q in QUANTITIES}
    return {
        "observations": observations,
        "tau": float(tau),
        "dt": None if dt is None else float(dt),
        "t_final": float(t_final),
        "n_steps": n_steps,
        "rtol": rtol,
        "atol": atol,
        "start": start,
        "weights": weights,
    }


def _engine(config: dict) -> str:
    if config["dt"] is None:
        return f"error control rtol {config['rtol']:g}, atol {config['atol']:g}"
    return f"uniform mesh of {config['n_steps']} steps"


def _fit_command(args: argparse.Namespace) -> int:
    try:
        config = _validate(args)
    except (ValueError, TypeError) as error:
        return fail(error)
    from ..fit import fit_adhesion

    observations = config["observations"]
    print(
        f"{PROG}: fitting {len(args.free or COEFFICIENT_NAMES)} coefficient(s) to {len(observations)} run(s) "
        f"(V = {', '.join(f'{o.V:g}' for o in observations)}), {_engine(config)}; compiling first ...",
        file=sys.stderr,
    )
    result = fit_adhesion(
        observations,
        tau=config["tau"],
        dt=config["dt"],
        t_final=config["t_final"],
        free=args.free,
        start=config["start"],
        optimizer=args.optimizer,
        steps=args.steps,
        learning_rate=args.learning_rate,
        weights=config["weights"],
        patience=args.patience,
        progress=args.progress,
        rtol=config["rtol"],
        atol=config["atol"],
    )
    record = result.to_dict()
    record["settings"] = {**record["settings"], "data": list(args.data), "phi": args.phi}
    Path(args.out).write_text(json.dumps(json_safe(record), indent=2, allow_nan=False) + "\n")
    if args.plot is not None:
        from ..plots import plot_fit

        plot_fit(result, observations, path=args.plot)
    summary = {
        "out": args.out,
        "plot": args.plot,
        "steps": result.steps,
        "initial_loss": result.initial_loss,
        "final_loss": result.final_loss,
        "loss_reduction": result.loss_reduction,
        "gradient_norm": result.gradient_norm,
        "v_range": list(result.v_range),
        "free": list(result.free),
        "coefficients": result.adhesion.coefficients(),
        "wall_time_s": result.wall_time_s,
    }
    if args.json:
        print(json.dumps(json_safe(summary), allow_nan=False))
    else:
        print(
            f"peeljax fit: {result.steps} iterations ({args.optimizer}), loss {result.initial_loss:.4g} -> {result.final_loss:.4g} "
            f"({result.loss_reduction:.3g}x), gradient norm {result.gradient_norm:.3g}"
        )
        print(
            f"visited v in [{result.v_range[0]:.3g}, {result.v_range[1]:.3g}] m/s: phi is determined by the data only there"
        )
        print("fitted: " + ", ".join(f"{n} {result.adhesion.coefficients()[n]:.6g}" for n in result.free))
        print(f"wrote {args.out}" + (f" and {args.plot}" if args.plot else ""))
    return 0
