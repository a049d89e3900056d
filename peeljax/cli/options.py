"""The options the ``peeljax`` subcommands share, each declared once (help text with its default
and allowed range) beside the check that names the option (``--max-jumps``, never ``max_jumps``).

One vocabulary: ``--t-final`` ends each run [s]; statistics cover [--transient T, T + --window W]
(default: the second half of the run; ``fit --table``: W = T = 0.5 s); ``--V`` takes numbers or
``START:STOP:COUNT``; ``--n-*`` are counts; ``--max-steps`` is error control's budget of step
attempts; ``--no-progress`` silences stderr's progress.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

from .._validation import MAX_STEPS_LIMIT, TAU_MAX, check_choice, check_mesh, check_tolerance
from .._validation import check_max_steps as library_check_max_steps
from ..integrators.select import DEFAULT_ATOL, DEFAULT_MAX_STEPS, DEFAULT_MAX_STEPS_DENSE, DEFAULT_RTOL, integrator_for
from ..model import GEOMETRIES, PeelingModel
from ..sweeps.api import sweep
from ..sweeps.integrators import DEFAULT_SWEEP_MAX_JUMPS, sweep_plan
from ..sweeps.least_tau import least_tau
from ..sweeps.storage import check_writable_format, is_netcdf
from .._files import check_output_path, image_formats
from ._common import PROG, STEPPERS, library_default, read_phi, solver_for

# --max-jumps: the jump record is allocated in full (5 arrays of max_jumps, per trajectory).
MAX_JUMPS_LIMIT = 10_000_000
# A range START:STOP:COUNT makes at most this many values (a typo must not fill the memory).
MAX_VALUES = 1_000_000


# ---------------------------------------------------------------------------- values
def _as_number(option: str, token: str, many: bool) -> float:
    """One number of ``option``; a comma-separated list or a range gets a message saying how."""
    try:
        return float(token)
    except ValueError:
        pass
    if "," in token:
        parts = " ".join(part.strip() for part in token.split(",") if part.strip())
        how = f"separate values by spaces: {option} {parts}" if many else "it takes one value"
        raise argparse.ArgumentTypeError(f"{token!r} is not a number: {how}")
    raise argparse.ArgumentTypeError(f"{token!r} is not a number")


def number(option: str):
    """An argparse ``type`` for an option that takes one number (``--V 1,2`` says it takes one)."""

    def parse(token: str) -> float:
        if ":" in token:
            raise argparse.ArgumentTypeError(
                f"{token!r}: this command runs one value; a range START:STOP:COUNT is for peeljax sweep"
            )
        return _as_number(option, token, many=False)

    return parse


def numbers(option: str, ranges: bool = True):
    """An argparse ``type`` for one token of an ``nargs="+"`` option: a number, or (``ranges``) ``START:STOP:COUNT``,
    COUNT equally spaced values from START to STOP; returns a list (the lists of the tokens are joined by
    :func:`flatten`)."""

    def parse(token: str) -> list[float]:
        if ":" not in token:
            return [_as_number(option, token, many=True)]
        if not ranges:
            raise argparse.ArgumentTypeError(
                f"{token!r}: {option} takes numbers separated by spaces, not a range"
                + ("; a log-spaced grid is --tau LO HI --n-tau N" if option == "--tau" else "")
            )
        parts = token.split(":")
        if len(parts) != 3:
            raise argparse.ArgumentTypeError(
                f"{token!r} is not a range START:STOP:COUNT (e.g. {option} 0.2:8:40, 40 values from 0.2 to 8)"
            )
        try:
            start, stop = float(parts[0]), float(parts[1])
            count = int(parts[2])
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{token!r} is not a range START:STOP:COUNT: START and STOP numbers, COUNT an integer "
                f"(e.g. {option} 0.2:8:40)"
            ) from None
        if not 2 <= count <= MAX_VALUES:
            raise argparse.ArgumentTypeError(
                f"{token!r}: COUNT must be an integer in [2, {MAX_VALUES}] (allowed range), got {count}"
            )
        if not (math.isfinite(start) and math.isfinite(stop) and start < stop):
            raise argparse.ArgumentTypeError(f"{token!r}: a range needs finite START < STOP")
        return np.linspace(start, stop, count).tolist()

    return parse


def flatten(values) -> list[float]:
    """The values of an ``nargs="+"`` option parsed by :func:`numbers` (a default may be plain)."""
    out: list[float] = []
    for value in values:
        out.extend(value if isinstance(value, list) else [value])
    return [float(v) for v in out]


def check_positive_values(option: str, values) -> list[float]:
    """Finite values > 0, at least one."""
    values = flatten(values)
    if not values:
        raise ValueError(f"{option}: give at least one value (allowed range: (0, inf))")
    bad = [v for v in values if not math.isfinite(v) or v <= 0]
    if bad:
        raise ValueError(f"{option} must be finite and > 0 (allowed range: (0, inf)), got {bad[:3]}")
    return values


# ---------------------------------------------------------------------------- the problem
def add_V(group, *, many: bool, default, help: str | None = None) -> None:
    """--V: one pull velocity (simulate) or several (sweep, tau-star, fit), > 0."""
    if many:
        shown = " ".join(f"{v:g}" for v in default) if default else "none"
        group.add_argument(
            "--V", type=numbers("--V"), nargs="+", default=default, metavar="V",
            help=(help or "pull velocities [m/s]") + ", each > 0: numbers separated by spaces, or START:STOP:COUNT "
            f"for COUNT equally spaced values (--V 0.2:8:40) (default {shown})",
        )  # fmt: skip
    else:
        group.add_argument(
            "--V", type=number("--V"), default=default, help=f"{help or 'pull velocity [m/s]'}, > 0 (default {default:g})"
        )


def add_t_final(group, *, default: float | None, help: str | None = None) -> None:
    """--t-final: the end of each run [s]; ``default`` the library function's."""
    group.add_argument(
        "--t-final", dest="t_final", type=float, default=default,
        help=help or f"end time of each run [s], > 0 (default {default:g})",
    )  # fmt: skip


def add_geometry_and_phi(group, *, phi_meta: str = "COEFFS.json", phi_help: str | None = None) -> None:
    """--geometry and --phi: the model's spool approximations and its adhesion law."""
    geometry = library_default(PeelingModel, "geometry")
    group.add_argument(
        "--geometry", default=geometry, metavar="{paper,full}",
        help=f"'paper' (the paper's approximations) or 'full' (default {geometry})",
    )  # fmt: skip
    group.add_argument(
        "--phi", metavar=phi_meta,
        help=phi_help or "adhesion coefficients c1..p9 as JSON; those left out keep the paper's values "
        "(default: the paper's law)",
    )  # fmt: skip


def model_from(args: argparse.Namespace) -> tuple[PeelingModel, tuple[str, ...] | None]:
    """--geometry and --phi checked: the model and the coefficients --phi left at the paper's
    values (None without --phi)."""
    check_choice("--geometry", args.geometry, GEOMETRIES)
    if args.phi is None:
        from ..adhesion import AdhesionLaw

        return PeelingModel(adhesion=AdhesionLaw(), geometry=args.geometry), None
    law, kept = read_phi(args.phi)
    return PeelingModel(adhesion=law, geometry=args.geometry), kept


def tau_help(allowed: str) -> str:
    return f"tau [s] in {allowed}: 0 is the DAE itself (v from G = phi(v, V), jumping at the folds of phi)"


TAU_RANGE = f"[0, {TAU_MAX:.0e}]".replace("e+0", "e")


# ---------------------------------------------------------------------------- the integrator
def add_tolerances(group, *, rtol_default: str, atol_default: str, note: str = "not with --dt") -> None:
    """--rtol and --atol: error control's tolerances."""
    group.add_argument(
        "--rtol", type=float, default=None,
        help=f"error control's relative tolerance in (0, 1) (default {rtol_default}; {note})",
    )  # fmt: skip
    group.add_argument(
        "--atol", type=float, default=None,
        help=f"error control's absolute tolerance in (0, inf) (default {atol_default}; {note})",
    )  # fmt: skip


def check_method(method: str, allowed: tuple[str, ...], dt, rho, alpha_methods=("default", "alpha")) -> None:
    """--method among ``allowed``; a stepper other than the α-method (``method`` not in
    ``alpha_methods``) runs error control only: no uniform mesh (--dt), no ρ (--rho)."""
    check_choice("--method", method, allowed)
    if method in alpha_methods:
        return
    if dt is not None:
        raise ValueError(
            f"--dt asks for a uniform mesh, which only the alpha-method runs (--method default or alpha); "
            f"--method {method} runs error control: drop --dt (and set --rtol/--atol), or give --method alpha"
        )
    if rho is not None:
        raise ValueError(
            f"--rho is the alpha-method's parameter: it applies with --method default or alpha, not --method {method}"
        )


def refuse_with_dt(dt, given: dict) -> None:
    """Error control's options (``given``: values by option, None when left out) do not go with
    --dt's uniform mesh (the library's rule, :func:`peeljax.integrators.select.refuse_with_dt`)."""
    named = [option for option, value in given.items() if value is not None]
    if dt is not None and named:
        raise ValueError(
            f"{'/'.join(named)} set{'s' if len(named) == 1 else ''} the alpha-method's error control; --dt asks for "
            "a uniform mesh: give one or the other"
        )


def check_tolerances(rtol: float | None, atol: float | None, defaults: tuple[float, float]) -> tuple[float, float]:
    """--rtol in (0, 1) and --atol in (0, inf), each its default when not given."""
    rtol = defaults[0] if rtol is None else rtol
    atol = defaults[1] if atol is None else atol
    check_tolerance("--rtol", rtol, 1.0)
    check_tolerance("--atol", atol)
    return float(rtol), float(atol)


MAX_SAVE_TIMES = 10_000_001  # --save-dt: output times per run (a typo must not fill the memory)


def check_save_dt(save_dt: float, t_final: float, memory=None) -> int:
    """--save-dt S in (0, t_final]; returns the count of output times (0, S, 2S, ... and t_final), counted without
    making them: ``memory(count)``, the caller's check that they fit, first (it says what they would take), then
    at most :data:`MAX_SAVE_TIMES`."""
    from ..integrators.dense import output_count

    if not (math.isfinite(save_dt) and 0 < save_dt <= t_final):
        raise ValueError(f"--save-dt must lie in (0, t_final] = (0, {t_final:g}], got {save_dt:g}")
    if not math.isfinite(t_final / save_dt):  # a subnormal S: no count
        raise ValueError(f"--save-dt {save_dt:g} gives more output times than can be counted; the limit is 1e7")
    n_save = output_count(save_dt, t_final)
    if memory is not None:
        memory(n_save)
    if n_save > MAX_SAVE_TIMES:
        raise ValueError(f"--save-dt {save_dt:g} gives {n_save:.3g} output times per run; the limit is 1e7")
    return n_save


def add_max_steps(group, *, default: str | None = None) -> None:
    """--max-steps: error control's budget of step attempts per run."""
    default = default or (
        f"{DEFAULT_MAX_STEPS} where the accepted steps are the output, {DEFAULT_MAX_STEPS_DENSE:.0e} with "
        "--save-dt"
    )
    group.add_argument(
        "--max-steps", dest="max_steps", type=int, default=None, metavar="N",
        help=f"error control's budget of step attempts (accepted or rejected) per run, an integer in "
        f"[1, {MAX_STEPS_LIMIT}]; a run that uses it up stops, and stderr says so; not with --dt (default "
        f"{default})",
    )  # fmt: skip


def check_max_steps(max_steps: int | None, uniform_option: str | None = None) -> None:
    """--max-steps: None (the library's budget) or the library's range (a 32-bit count); refused
    with the uniform mesh (``uniform_option``, e.g. "--dt"), which takes no budget."""
    if max_steps is None:
        return
    library_check_max_steps(max_steps)
    if uniform_option is not None:
        raise ValueError(
            f"--max-steps (allowed range: [1, {MAX_STEPS_LIMIT}]) is error control's budget of step attempts; "
            f"{uniform_option} asks for a uniform mesh, which takes no budget: give one or the other"
        )


def add_max_jumps(group, *, default: int | str, per: str = "run") -> None:
    group.add_argument(
        "--max-jumps", dest="max_jumps", type=int, default=None, metavar="N",
        help=f"slots of each {per}'s jump record, an integer in [1, {MAX_JUMPS_LIMIT:.0e}]; "
        + ("one more jump stops the run" if per == "run" else f"each {per} keeps its last N jumps and never stops for it")
        + f"; error control only (default {default})",
    )  # fmt: skip


def check_max_jumps(max_jumps: int | None, default: int | None, uniform_option: str | None = None) -> int | None:
    """--max-jumps in [1, 1e7] (the record is allocated in full); its default when not given."""
    if max_jumps is None:
        return default
    if uniform_option is not None:
        raise ValueError(
            f"--max-jumps sizes the jump record of error control (any stepper), which {uniform_option} does not "
            "run: give one or the other"
        )
    if isinstance(max_jumps, bool) or not 1 <= max_jumps <= MAX_JUMPS_LIMIT:
        raise ValueError(
            f"--max-jumps must be a positive integer (allowed range: [1, {MAX_JUMPS_LIMIT:.0e}]; the jump record "
            f"is allocated in full), got {max_jumps}"
        )
    return int(max_jumps)


# ---------------------------------------------------------------------------- the batched engine
# The problem's and the integrator's options of peeljax sweep (its map too) and tau-star, checked as
# the keyword arguments of peeljax.sweep / peeljax.least_tau that choose the engine.
def add_engine(parser: argparse.ArgumentParser):
    """The problem's and the integrator's options of the batched engine; returns the integrator's
    argument group."""
    group = parser.add_argument_group("problem")
    add_V(group, many=True, default=list(library_default(least_tau, "V")))  # least_tau's grid, a sweep's too
    add_t_final(group, default=library_default(least_tau, "t_final"))  # peeljax.sweep's too
    add_geometry_and_phi(group)
    solver = parser.add_argument_group("integrator")
    solver.add_argument(
        "--dt", type=float, default=None,
        help="uniform-mesh step [s] of the alpha-method, in (0, t_final] (default: error control)",
    )  # fmt: skip
    add_tolerances(solver, rtol_default=f"{DEFAULT_RTOL:g}", atol_default=f"{DEFAULT_ATOL:g}")
    solver.add_argument("--rho", type=float, default=None, help="alpha-method's rho in [0, 1) (default 0)")
    solver.add_argument(
        "--method", "--solver", default="default", metavar="NAME",
        help=f"the stepper of error control: default (the library's choice: auto) or one of {', '.join(STEPPERS)}; "
        "--dt and --rho with default or alpha only (default: default)",
    )  # fmt: skip
    add_max_steps(solver, default=f"{DEFAULT_MAX_STEPS_DENSE:.0e}; stick-slip takes about 50-100 a jump")
    return solver


def engine(args: argparse.Namespace, dae: bool = False) -> dict:
    """The integrator's options (and a sweep's --fold, --max-jumps, --start) as the keyword arguments of
    :func:`peeljax.sweep` / :func:`peeljax.least_tau`, checked by the library's
    :func:`~peeljax.sweeps.integrators.sweep_plan` (their own check, before anything compiles); ``rtol``/``atol``
    left out are the defaults it chose, ``solver`` and ``max_steps`` only where given."""
    method, uniform = getattr(args, "method", "default"), None if args.dt is None else "--dt"
    check_method(method, ("default", *STEPPERS), args.dt, args.rho)
    check_max_steps(args.max_steps, uniform)
    saving = {name: getattr(args, name) for name in ("save_dt", "save_every") if hasattr(args, name)}
    chosen = {"dt": args.dt, "rtol": args.rtol, "atol": args.atol, **saving}
    if method != "default":
        chosen["solver"] = solver_for(method, engine_rho(args))
    if args.max_steps is not None:  # left out: the library's budget
        chosen["max_steps"] = int(args.max_steps)
    if hasattr(args, "fold"):  # a sweep's (least_tau stops at the folds)
        check_max_jumps(args.max_jumps, DEFAULT_SWEEP_MAX_JUMPS, uniform)
        chosen.update(fold=args.fold, max_jumps=args.max_jumps)
    plan = sweep_plan(
        chosen.get("solver"), engine_rho(args), args.dt, args.t_final, args.rtol, args.atol, saving.get("save_dt"),
        saving.get("save_every"), None, args.max_steps, chosen.get("fold", "stop"), args.max_jumps if
        hasattr(args, "fold") else None, dae, getattr(args, "start", None) or "paper",
    )  # fmt: skip
    if saving.get("save_dt") is not None:
        check_save_dt(saving["save_dt"], args.t_final)  # at most 1e7 output times
    if not plan.uniform:
        settings = plan.integrator.settings()
        chosen.update(rtol=settings["rtol"], atol=settings["atol"])
    return chosen


def engine_rho(args: argparse.Namespace) -> float:
    """--rho, else peeljax.sweep's (and least_tau's) default."""
    return library_default(sweep, "rho") if args.rho is None else float(args.rho)


def _stepper(kwargs: dict, ran: str | None = None) -> str | None:
    """The stepper's name: the one that ran (a result's ``settings["method"]``), else the one
    --method chose ("alpha" for an AlphaMethod); None: the library's default, not known before it ran."""
    if ran is not None:
        return "alpha" if ran.startswith("alpha") else ran
    solver = kwargs.get("solver")
    if kwargs["dt"] is not None or (solver is not None and not isinstance(solver, str)):
        return "alpha"  # the uniform mesh, or --method alpha's AlphaMethod
    return solver


def engine_text(kwargs: dict, ran: str | None = None) -> str:
    """Which engine runs, in words (ASCII): the stepper (``ran``: the one that ran, from the result's settings),
    error control with its tolerances or the uniform mesh, and ρ for the α-method."""
    stepper = _stepper(kwargs, ran)
    name = {"alpha": "alpha-method", None: "default stepper"}.get(stepper, stepper)
    if kwargs["dt"] is None:
        text = f"{name}, error control rtol = {kwargs['rtol']:g}, atol = {kwargs['atol']:g}"
    else:
        n_steps = check_mesh(kwargs["dt"], kwargs["t_final"])
        text = f"{name}, uniform mesh dt = {kwargs['t_final'] / n_steps:.6g} s ({n_steps} steps)"
    return text if stepper not in ("alpha", None) else f"{text}, rho = {kwargs['rho']:g}"


def engine_record(kwargs: dict, ran: str | None = None) -> dict:
    """The integrator's settings for the JSON output: method (the stepper that ran, from the result's settings, when
    given), dt (null with error control), rtol, atol, rho (null when the stepper is not the α-method)."""
    default = "alpha" if kwargs["dt"] is not None else integrator_for(t_final=1.0).settings()["method"]  # τ > 0's
    return {
        "method": default if ran is None else ran,
        "dt": kwargs["dt"],
        "rtol": kwargs["rtol"],
        "atol": kwargs["atol"],
        "rho": kwargs["rho"] if _stepper(kwargs, ran) in ("alpha", None) else None,
    }


def engine_model(args) -> PeelingModel:
    model, args.phi_defaults = model_from(args)
    return model


DEFAULT_CHUNK = library_default(sweep, "chunk")  # --chunk left out: peeljax.sweep's


def tau_grid(tau: list[float], n_tau: int | None) -> list[float]:
    """--tau values as given (all > 0, or all 0: the DAE), or with --n-tau a log-spaced grid between two values."""
    tau = flatten(tau)
    if tau and all(value == 0 for value in tau):
        if n_tau is not None:
            raise ValueError("--n-tau spaces tau logarithmically between LO > 0 and HI; --tau 0 is the DAE itself")
        return [0.0]
    if tau and any(value == 0 for value in tau):
        raise ValueError(
            f"--tau must be finite and > 0 (the homogenized ODE), or 0 alone (the DAE itself); got {tau}: "
            "the two are different problems, sweep them separately"
        )
    tau = check_positive_values("--tau", tau)
    if any(value > TAU_MAX for value in tau):
        raise ValueError(f"--tau must lie in (0, {TAU_MAX:g}] (allowed range), got {max(tau):g}")
    if n_tau is None:
        return tau
    if isinstance(n_tau, bool) or n_tau < 2:
        raise ValueError(f"--n-tau must be an integer >= 2 (allowed range: [2, inf)), got {n_tau}")
    if len(tau) != 2:
        raise ValueError(f"--n-tau needs exactly two --tau values LO HI, got {len(tau)}")
    if tau[0] >= tau[1]:
        raise ValueError(f"--tau LO HI needs LO < HI, got {tau[0]:g} {tau[1]:g}")
    return np.geomspace(tau[0], tau[1], n_tau).tolist()


def chunk(args: argparse.Namespace) -> int:
    return DEFAULT_CHUNK if args.chunk is None else int(args.chunk)


def check_sweep_outputs(args: argparse.Namespace) -> None:
    if args.chunk is not None and args.chunk < 1:
        raise ValueError(f"--chunk must be a positive integer (allowed range: [1, inf)), got {args.chunk}")
    check_outputs(args)
    if args.out is not None and is_netcdf(args.out):  # before the run: the extra may be missing
        try:
            check_writable_format(args.out)
        except ImportError as error:
            raise ValueError(f"--out {args.out!r}: {error}") from None


# ---------------------------------------------------------------------------- statistics window
def transient_default(t_final: float) -> float:
    """The one default rule: the statistics cover the second half of the run."""
    return t_final / 2.0


def add_statistics_window(group, *, window: bool = True, transient: str = "t_final/2: the second half of the run",
                          window_default: str = "up to --t-final", what: str = "the statistics") -> None:  # fmt: skip
    """--transient T and (``window``) --window W: ``what`` covers [T, T + W] [s]."""
    group.add_argument(
        "--transient", type=float, default=None, metavar="T",
        help=f"{what} start at T [s], >= 0: what comes before (the approach to the attractor) is left out "
        f"(default {transient})",
    )  # fmt: skip
    if window:
        group.add_argument(
            "--window", type=float, nargs="+", default=None, metavar="W",
            help=f"{what} cover [T, T + W]: W [s] > 0 (default {window_default})",
        )  # fmt: skip


def check_statistics_window(transient: float | None, window: float | None, t_final: float) -> tuple[float, float]:
    """[T, T + W] within [0, t_final] (the defaults: T = t_final/2, W = t_final - T)."""
    T = transient_default(t_final) if transient is None else transient
    if not (math.isfinite(T) and 0 <= T < t_final):
        raise ValueError(f"--transient must lie in [0, --t-final) = [0, {t_final:g}) [s], got {T:g}")
    W = t_final - T if window is None else window
    if not (math.isfinite(W) and 0 < W <= t_final - T * (1 - 1e-12)):
        raise ValueError(
            f"--window must lie in (0, {t_final - T:g}] [s] (allowed range: the statistics cover [--transient, "
            f"--transient + --window] within the run, [0, --t-final]), got {W:g}"
        )
    return float(T), float(min(W, t_final - T))


def one_window(window: list[float] | None, *, fractions_allowed: bool, t_final: float | None = None):
    """--window as given: None, one length [s], or (``fractions_allowed``: sweep) the old form W0 W1, two fractions
    of t_final, returned as (transient, window) in seconds with a deprecation note on stderr."""
    if window is None:
        return None, None
    if len(window) == 1:
        return None, float(window[0])
    if len(window) == 2 and fractions_allowed:
        w0, w1 = window
        if not (math.isfinite(w0) and math.isfinite(w1) and 0 <= w0 < w1 <= 1):
            raise ValueError(
                f"--window W0 W1 (the deprecated form: fractions of t_final) must satisfy 0 <= W0 < W1 <= 1, got "
                f"{w0:g} {w1:g}; give --transient T --window W in seconds"
            )
        T, W = w0 * t_final, (w1 - w0) * t_final
        deprecated(f"--window {w0:g} {w1:g}", f"--transient {T:g} --window {W:g}", "(fractions of t_final)")
        return T, W
    raise ValueError(
        f"--window takes one length W [s] (the statistics cover [--transient, --transient + W]), got {len(window)} "
        "values" + ("" if fractions_allowed else "; sweep's old form W0 W1 is --transient T --window W here")
    )


# ---------------------------------------------------------------------------- output and progress
def add_outputs(parser, *, out_meta: str, out_help: str, plot_meta: str = "FILE.png", plot_help: str) -> None:
    parser.add_argument("--out", metavar=out_meta, help=out_help)
    parser.add_argument("--plot", metavar=plot_meta, help=f"{plot_help} (format from the suffix; default: none)")


_FORMATS = {".npz": "numpy", ".nc": "netCDF", ".json": "JSON", ".csv": "text"}


def check_outputs(args: argparse.Namespace) -> None:
    """--out and --plot: the folder exists and is writable, the image format known; --out's suffix, if it has one,
    among those the command writes (``args.out_formats``, set by its parser): ``--out sweep.csv`` would be a numpy
    file under a CSV name."""
    out, formats = getattr(args, "out", None), getattr(args, "out_formats", None)
    if out is not None and formats:
        suffix = os.path.splitext(out)[1].lower()
        if suffix and suffix not in formats:
            written = " or ".join(f"FILE{s} ({_FORMATS[s]})" for s in formats)
            command = f"peeljax {args.command}" if getattr(args, "command", None) else "this command"
            raise ValueError(f"--out {out!r}: {command} writes {written}, not a {suffix} file")
    check_output_path("--out", out)
    if getattr(args, "plot", None) is not None:
        check_output_path("--plot", args.plot, image_formats())


def add_json(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout instead of a summary")


def add_progress(parser, what: str = "progress") -> None:
    parser.add_argument(
        "--no-progress", dest="progress", action="store_false",
        help=f"no {what} on stderr (default: shown; what runs and how it ended are always said)",
    )  # fmt: skip


def progress_on(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "progress", True))


def deprecated(old: str, new: str, what: str = "") -> None:
    """One line on stderr: ``old`` still works until peeljax 0.3.0; ``new`` is its spelling now."""
    what = f" {what}" if what else ""
    print(f"{PROG}: note: {old}{what} is deprecated and is removed in peeljax 0.3.0: give {new}", file=sys.stderr)
