"""``peeljax fit``: fit the adhesion law's coefficients to observed runs.

Data files (``--data``, repeatable; ``np.load(..., allow_pickle=False)``), either layout:

* one pull velocity per file: a scalar ``V`` and 1-D arrays ``t``, ``v`` of one length, and
  optionally ``F`` (the tension [N]) and ``alpha`` [rad], on the same times ``t`` or on their
  own ``t_F`` / ``t_alpha``. A ``peeljax simulate --out`` file is such a file (its NaN
  entries after a stop are ignored; its ``tau`` becomes the default);
* several pull velocities in one file: ``V_0, t_0, v_0`` (and ``F_0, alpha_0, t_F_0,
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
        "--data", action="append", required=True, metavar="OBSERVED.npz", help="observations (repeatable)"
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


def _scalar(data, key: str, path: str) -> float:
    value = np.asarray(data[key])
    if value.size != 1 or not np.issubdtype(value.dtype, np.number):
        raise ValueError(f"--data {path!r}: {key!r} must be a number")
    return float(value.reshape(()))


def _array(data, key: str, path: str) -> np.ndarray:
    value = np.asarray(data[key])
    if value.ndim != 1 or not np.issubdtype(value.dtype, np.number) or value.size < 2:
        raise ValueError(f"--data {path!r}: {key!r} must be a 1-D numeric array of at least 2 entries")
    return value.astype(float)


def _check_series(path: str, key: str, time_key: str, times: np.ndarray, values: np.ndarray) -> None:
    """NaN marks a missing entry (ignored); an infinite value or time, or times that do not
    increase, mean a broken file."""
    if np.any(np.isinf(values)):
        raise ValueError(f"--data {path!r}: {key!r} has infinite entries (NaN marks a missing value; inf is not one)")
    if np.any(np.isinf(times)):
        raise ValueError(f"--data {path!r}: {time_key!r} has infinite entries")
    finite = times[np.isfinite(times)]
    if np.any(np.diff(finite) <= 0):
        i = int(np.flatnonzero(np.diff(finite) <= 0)[0])
        raise ValueError(
            f"--data {path!r}: the times {time_key!r} must increase strictly, got {finite[i]:g} then {finite[i + 1]:g}"
        )


def _observation(data, path: str, suffix: str) -> Observation:
    keys = set(data.files)
    for key in ("V", "t", "v"):
        if key + suffix not in keys:
            raise ValueError(
                f"--data {path!r}: missing {key + suffix!r} (keys: t, v, V and optional F, alpha; or V_0, t_0, v_0, ...)"
            )
    V = _scalar(data, "V" + suffix, path)
    if not (math.isfinite(V) and V > 0):
        raise ValueError(f"--data {path!r}: V{suffix} must be > 0 (allowed range: (0, inf)), got {V}")
    t = _array(data, "t" + suffix, path)
    fields = {"v": _array(data, "v" + suffix, path)}
    if fields["v"].shape != t.shape:
        raise ValueError(f"--data {path!r}: 't{suffix}' and 'v{suffix}' must have one length")
    _check_series(path, "v" + suffix, "t" + suffix, t, fields["v"])
    for q in ("F", "alpha"):
        if q + suffix in keys:
            values = _array(data, q + suffix, path)
            times = _array(data, f"t_{q}{suffix}", path) if f"t_{q}{suffix}" in keys else t
            if times.shape != values.shape:
                raise ValueError(f"--data {path!r}: {q}{suffix!s} and its times must have one length")
            time_key = f"t_{q}{suffix}" if f"t_{q}{suffix}" in keys else "t" + suffix
            _check_series(path, q + suffix, time_key, times, values)
            fields[q], fields[f"t_{q}"] = values, times
    observation = Observation(V=V, t=t, **fields)
    if len(observation.series("v")[0]) < 2:
        raise ValueError(f"--data {path!r}: fewer than 2 finite v{suffix} values")
    return observation


def load_observations(paths: list[str]) -> tuple[list[Observation], dict]:
    """Observations from .npz files (layouts in the module docstring) and the files' tau/dt if they agree."""
    observations, defaults = [], {"tau": set(), "dt": set()}
    for path in paths:
        if not Path(path).is_file():
            raise ValueError(f"--data: file {path!r} does not exist")
        try:
            data = np.load(path, allow_pickle=False)
        except Exception as error:  # noqa: BLE001  (any failure to parse the file is bad input)
            raise ValueError(f"--data {path!r}: not a readable .npz without pickles ({type(error).__name__})") from None
        if not hasattr(data, "files"):
            raise ValueError(f"--data {path!r}: expected an .npz archive of named arrays")
        with data:
            try:
                _read_file(data, path, observations, defaults)
            except ValueError as error:
                if "allow_pickle" in str(error):
                    raise ValueError(f"--data {path!r}: not a readable .npz without pickles (object arrays)") from None
                raise
    return observations, {k: next(iter(v)) for k, v in defaults.items() if len(v) == 1}


def _read_file(data, path, observations, defaults):
    """Append the file's observations; collect its tau and dt."""
    if "V_0" in data.files:
        i = 0
        while f"V_{i}" in data.files:
            observations.append(_observation(data, path, f"_{i}"))
            i += 1
    else:
        observations.append(_observation(data, path, ""))
    for key in ("tau", "dt"):
        if key in data.files:
            try:
                value = _scalar(data, key, path)
            except ValueError:
                continue
            if math.isfinite(value) and value > 0:
                defaults[key].add(value)


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
    observations, defaults = load_observations(args.data)
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
