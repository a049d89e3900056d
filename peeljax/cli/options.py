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

from .._validation import MAX_STEPS_LIMIT, check_choice, check_positive, check_tolerance
from .._validation import check_max_steps as library_check_max_steps
from ..integrators.select import DEFAULT_MAX_STEPS, DEFAULT_MAX_STEPS_DENSE
from ..model import GEOMETRIES, PeelingModel
from .._files import check_output_path, image_formats
from ._common import PROG, STEPPERS, library_default, read_phi

MAX_JUMPS_LIMIT = 10_000_000  # --max-jumps: the jump record is allocated in full (5 arrays of max_jumps a run)
MAX_VALUES = 1_000_000  # values of one range START:STOP:COUNT (a typo must not fill the memory)
MAX_SAVE_TIMES = 10_000_001  # --save-dt: output times per run (a typo must not fill the memory)


# ---------------------------------------------------------------------------- values
def _as_number(option: str, token: str, many: bool) -> float:
    """One number of ``option``; a comma-separated list or a range gets a message saying how."""
    try:
        return float(token)
    except ValueError:
        parts = " ".join(part.strip() for part in token.split(",") if part.strip())
        how = "" if "," not in token else f": separate values by spaces: {option} {parts}" if many else ": it takes one value"
        raise argparse.ArgumentTypeError(f"{token!r} is not a number{how}") from None


def number(option: str):
    """An argparse ``type`` for an option that takes one number (``--V 1,2`` says it takes one)."""

    def parse(token: str) -> float:
        if ":" in token:
            raise argparse.ArgumentTypeError(f"{token!r}: this command runs one value; a range START:STOP:COUNT is for peeljax sweep")
        return _as_number(option, token, many=False)

    return parse


def numbers(option: str, ranges: bool = True):
    """An argparse ``type`` for one token of an ``nargs="+"`` option: a number, or (``ranges``) ``START:STOP:COUNT``,
    COUNT equally spaced values from START to STOP; returns a list (joined by :func:`flatten`)."""

    def parse(token: str) -> list[float]:
        if ":" not in token:
            return [_as_number(option, token, many=True)]
        if not ranges:
            log = "; a log-spaced grid is --tau LO HI --n-tau N" if option == "--tau" else ""
            raise argparse.ArgumentTypeError(f"{token!r}: {option} takes numbers separated by spaces, not a range{log}")
        parts = token.split(":")
        try:
            if len(parts) != 3:
                raise ValueError(token)
            start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
        except ValueError:
            raise argparse.ArgumentTypeError(f"{token!r} is not a range START:STOP:COUNT: START and STOP numbers, COUNT "
                                             f"an integer (e.g. {option} 0.2:8:40, 40 values from 0.2 to 8)") from None
        if not 2 <= count <= MAX_VALUES:
            raise argparse.ArgumentTypeError(f"{token!r}: COUNT must be an integer in [2, {MAX_VALUES}] (allowed range), got {count}")
        if not (math.isfinite(start) and math.isfinite(stop) and start < stop):
            raise argparse.ArgumentTypeError(f"{token!r}: a range needs finite START < STOP")
        return np.linspace(start, stop, count).tolist()

    return parse


def flatten(values) -> list[float]:
    """The values of an ``nargs="+"`` option parsed by :func:`numbers` (a default may be plain)."""
    return [float(v) for value in values for v in (value if isinstance(value, list) else [value])]


def check_positive_values(option: str, values) -> list[float]:
    """Finite values > 0 (the library's check, :func:`peeljax._validation.check_positive`)."""
    values = flatten(values)
    check_positive(option, values)
    return values


# ---------------------------------------------------------------------------- the problem
def add_V(group, *, many: bool, default, help: str | None = None, shown: str | None = None) -> None:
    """--V: one pull velocity (simulate) or several (sweep, tau-star, fit, map), > 0; ``shown``: the default in words."""
    if not many:
        group.add_argument("--V", type=number("--V"), default=default, help=f"{help or 'pull velocity [m/s]'}, > 0 (default {default:g})")
        return
    shown = shown or (" ".join(f"{v:g}" for v in default) if default else "none")
    group.add_argument("--V", type=numbers("--V"), nargs="+", default=default, metavar="V",
                       help=f"{help or 'pull velocities [m/s]'}, each > 0: numbers separated by spaces, or START:STOP:COUNT "
                       f"for COUNT equally spaced values (--V 0.2:8:40) (default {shown})")  # fmt: skip


def add_t_final(group, *, default: float | None, help: str | None = None) -> None:
    """--t-final: the end of each run [s]; ``default`` the library function's."""
    group.add_argument("--t-final", dest="t_final", type=float, default=default,
                       help=help or f"end time of each run [s], > 0 (default {default:g})")  # fmt: skip


def add_geometry_and_phi(group) -> None:
    """--geometry and --phi: the model's spool approximations and its adhesion law."""
    geometry = library_default(PeelingModel, "geometry")
    group.add_argument("--geometry", default=geometry, metavar="{paper,full}",
                       help=f"'paper' (the paper's approximations) or 'full' (default {geometry})")  # fmt: skip
    group.add_argument("--phi", metavar="COEFFS.json", help="adhesion coefficients c1..p9 as JSON; those left out keep "
                       "the paper's values (default: the paper's law)")  # fmt: skip


def model_from(args: argparse.Namespace) -> tuple[PeelingModel, tuple[str, ...] | None]:
    """--geometry and --phi checked: the model and the coefficients --phi left at the paper's values (None without
    --phi)."""
    check_choice("--geometry", args.geometry, GEOMETRIES)  # (the model's own message lists no choices to suggest)
    law, kept = (None, None) if args.phi is None else read_phi(args.phi)
    return PeelingModel(adhesion=law, geometry=args.geometry), kept


# ---------------------------------------------------------------------------- the integrator
def add_tolerances(group, *, rtol_default: str, atol_default: str, note: str = "not with --dt") -> None:
    """--rtol and --atol: error control's tolerances."""
    for name, kind, upper, default in (("rtol", "relative", "1", rtol_default), ("atol", "absolute", "inf", atol_default)):
        group.add_argument(f"--{name}", type=float, default=None,
                           help=f"error control's {kind} tolerance in (0, {upper}) (default {default}; {note})")


def add_method(group, rho_default: float, more: str = "") -> None:
    """--method (the stepper; ``more``: what else it takes) and --rho, the α-method's ρ."""
    group.add_argument("--method", "--solver", default="default", metavar="NAME",
                       help=f"the stepper of error control: default (the library's choice: auto) or one of "
                       f"{', '.join(STEPPERS)}{more}; --dt and --rho with default or alpha only (default: default)")  # fmt: skip
    group.add_argument("--rho", type=float, default=None, help=f"alpha-method's rho in [0, 1) (default {rho_default:g})")


def check_method(method: str, allowed: tuple[str, ...], dt, rho, alpha_methods=("default", "alpha")) -> None:
    """--method among ``allowed``; a stepper other than the α-method (``method`` not in ``alpha_methods``) runs error
    control only: no uniform mesh (--dt), no ρ (--rho)."""
    check_choice("--method", method, allowed)
    if method not in alpha_methods and dt is not None:
        raise ValueError(f"--dt asks for a uniform mesh, which only the alpha-method runs (--method default or alpha); "
                         f"--method {method} runs error control: drop --dt (and set --rtol/--atol), or give --method alpha")  # fmt: skip
    if method not in alpha_methods and rho is not None:
        raise ValueError(f"--rho is the alpha-method's parameter: it applies with --method default or alpha, not --method {method}")


def check_tolerances(rtol: float | None, atol: float | None, defaults: tuple[float, float]) -> tuple[float, float]:
    """--rtol in (0, 1) and --atol in (0, inf) (the library's checks), each its default when not given."""
    rtol, atol = defaults[0] if rtol is None else rtol, defaults[1] if atol is None else atol
    check_tolerance("--rtol", rtol, 1.0)
    check_tolerance("--atol", atol)
    return float(rtol), float(atol)


def check_save_dt(save_dt: float, t_final: float, memory=None) -> int:
    """--save-dt S in (0, t_final]; returns the count of output times (0, S, 2S, ... and t_final), counted without
    making them: ``memory(count)``, the caller's check that they fit, first, then at most :data:`MAX_SAVE_TIMES`."""
    from ..integrators.dense import output_count

    if not (math.isfinite(save_dt) and 0 < save_dt <= t_final):
        raise ValueError(f"--save-dt must lie in (0, t_final] = (0, {t_final:g}], got {save_dt:g}")
    n_save = output_count(save_dt, t_final) if math.isfinite(t_final / save_dt) else math.inf  # a subnormal S: no count
    if memory is not None and n_save < math.inf:
        memory(n_save)
    if n_save > MAX_SAVE_TIMES:
        raise ValueError(f"--save-dt {save_dt:g} gives {n_save:.3g} output times per run; the limit is 1e7")
    return n_save


def add_max_steps(group, *, default: str | None = None) -> None:
    """--max-steps: error control's budget of step attempts per run."""
    default = default or f"{DEFAULT_MAX_STEPS} where the accepted steps are the output, {DEFAULT_MAX_STEPS_DENSE:.0e} with --save-dt"
    group.add_argument("--max-steps", dest="max_steps", type=int, default=None, metavar="N",
                       help=f"error control's budget of step attempts (accepted or rejected) per run, an integer in [1, "
                       f"{MAX_STEPS_LIMIT}]; a run that uses it up stops, and stderr says so; not with --dt (default "
                       f"{default})")  # fmt: skip


def check_max_steps(max_steps: int | None, uniform_option: str | None = None) -> None:
    """--max-steps: None (the library's budget) or the library's range; refused with the uniform mesh
    (``uniform_option``, e.g. "--dt"), which takes no budget."""
    if max_steps is not None:
        library_check_max_steps(max_steps)
    if max_steps is not None and uniform_option is not None:
        raise ValueError(f"--max-steps (allowed range: [1, {MAX_STEPS_LIMIT}]) is error control's budget of step attempts; "
                         f"{uniform_option} asks for a uniform mesh, which takes no budget: give one or the other")  # fmt: skip


def add_fold(group, stop_with: str) -> None:
    """--fold: what a run does at a fold of φ (stop is the only choice without error control: ``stop_with``)."""
    group.add_argument("--fold", default=None, metavar="{jump,stop,follow}",
                       help="at a fold of phi: 'jump' (v jumps to the other stable branch at fixed alpha, omega, u; the "
                       "run goes on), 'stop' (the run ends there, the paper's behaviour) or 'follow' (tau > 0: jump at "
                       "impasse points only, follow singular passages); jump and follow need error control, any "
                       f"stepper (default: jump with error control, stop with {stop_with})")  # fmt: skip


def add_max_jumps(group, *, default: int | str, per: str = "run") -> None:
    stop = "one more jump stops the run" if per == "run" else f"each {per} keeps its last N jumps and never stops for it"
    group.add_argument("--max-jumps", dest="max_jumps", type=int, default=None, metavar="N",
                       help=f"slots of each {per}'s jump record, an integer in [1, {MAX_JUMPS_LIMIT:.0e}]; {stop}; error "
                       f"control only (default {default})")  # fmt: skip


def check_max_jumps(max_jumps: int | None, default: int | None, uniform_option: str | None = None) -> int | None:
    """--max-jumps in [1, 1e7] (the record is allocated in full); its default when not given."""
    if max_jumps is None:
        return default
    if uniform_option is not None:
        raise ValueError(f"--max-jumps sizes the jump record of error control (any stepper), which {uniform_option} does "
                         "not run: give one or the other")  # fmt: skip
    if isinstance(max_jumps, bool) or not 1 <= max_jumps <= MAX_JUMPS_LIMIT:
        raise ValueError(f"--max-jumps must be a positive integer (allowed range: [1, {MAX_JUMPS_LIMIT:.0e}]; the jump "
                         f"record is allocated in full), got {max_jumps}")  # fmt: skip
    return int(max_jumps)


# ---------------------------------------------------------------------------- statistics window
def add_statistics_window(group, *, window: bool = True, transient: str = "t_final/2: the second half of the run",
                          window_default: str = "up to --t-final", what: str = "the statistics") -> None:  # fmt: skip
    """--transient T and (``window``) --window W: ``what`` covers [T, T + W] [s]."""
    group.add_argument("--transient", type=float, default=None, metavar="T",
                       help=f"{what} start at T [s], >= 0: what comes before (the approach to the attractor) is left "
                       f"out (default {transient})")  # fmt: skip
    if window:
        group.add_argument("--window", type=float, nargs="+", default=None, metavar="W",
                           help=f"{what} cover [T, T + W]: W [s] > 0 (default {window_default})")  # fmt: skip


def check_statistics_window(transient: float | None, window: float | None, t_final: float) -> tuple[float, float]:
    """[T, T + W] within [0, t_final] (the defaults, the one rule: T = t_final/2, W = t_final - T)."""
    T = t_final / 2.0 if transient is None else transient
    if not (math.isfinite(T) and 0 <= T < t_final):
        raise ValueError(f"--transient must lie in [0, --t-final) = [0, {t_final:g}) [s], got {T:g}")
    W = t_final - T if window is None else window
    if not (math.isfinite(W) and 0 < W <= t_final - T * (1 - 1e-12)):
        raise ValueError(f"--window must lie in (0, {t_final - T:g}] [s] (allowed range: the statistics cover "
                         f"[--transient, --transient + --window] within the run, [0, --t-final]), got {W:g}")  # fmt: skip
    return float(T), float(min(W, t_final - T))


def one_window(window: list[float] | None, *, fractions_allowed: bool, t_final: float | None = None):
    """--window as given: None, one length [s], or (``fractions_allowed``: sweep) the old form W0 W1, two fractions
    of t_final, returned as (transient, window) in seconds with a deprecation note on stderr."""
    if window is None or len(window) == 1:
        return None, None if window is None else float(window[0])
    if len(window) == 2 and fractions_allowed:
        w0, w1 = window
        if not (math.isfinite(w0) and math.isfinite(w1) and 0 <= w0 < w1 <= 1):
            raise ValueError(f"--window W0 W1 (the deprecated form: fractions of t_final) must satisfy 0 <= W0 < W1 <= 1, "
                             f"got {w0:g} {w1:g}; give --transient T --window W in seconds")  # fmt: skip
        T, W = w0 * t_final, (w1 - w0) * t_final
        deprecated(f"--window {w0:g} {w1:g}", f"--transient {T:g} --window {W:g}", "(fractions of t_final)")
        return T, W
    old_form = "" if fractions_allowed else "; sweep's old form W0 W1 is --transient T --window W here"
    raise ValueError(f"--window takes one length W [s] (the statistics cover [--transient, --transient + W]), got "
                     f"{len(window)} values{old_form}")


# ---------------------------------------------------------------------------- output and progress
def add_output(parser, progress: str, out: tuple[str, str] | None = None, plot: tuple[str, str] | None = None):
    """The group "output": --out (``out``: its metavar and help) and --plot (``plot``) where the command writes them,
    --json and --no-progress (``progress``: what it silences)."""
    group = parser.add_argument_group("output")
    if out is not None:
        group.add_argument("--out", metavar=out[0], help=f"{out[1]} (default: none)")
    if plot is not None:
        group.add_argument("--plot", metavar=plot[0], help=f"{plot[1]} (format from the suffix; default: none)")
    group.add_argument("--json", action="store_true", help="print one JSON object on stdout instead of a summary")
    add_progress(group, progress)
    return group


_FORMATS = {".npz": "numpy", ".nc": "netCDF", ".json": "JSON", ".csv": "text"}


def check_outputs(args: argparse.Namespace) -> None:
    """--out and --plot: the folder exists and is writable, the image format known; --out's suffix, if any, among those
    the command writes (``args.out_formats``, set by its parser): ``--out sweep.csv`` would be numpy under a CSV name."""
    out, formats = getattr(args, "out", None), getattr(args, "out_formats", None)
    suffix = "" if out is None else os.path.splitext(out)[1].lower()
    if formats and suffix and suffix not in formats:
        written = " or ".join(f"FILE{s} ({_FORMATS[s]})" for s in formats)
        command = f"peeljax {args.command}" if getattr(args, "command", None) else "this command"
        raise ValueError(f"--out {out!r}: {command} writes {written}, not a {suffix} file")
    check_output_path("--out", out)
    if getattr(args, "plot", None) is not None:
        check_output_path("--plot", args.plot, image_formats())


def add_progress(parser, what: str = "progress") -> None:
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help=f"no {what} on stderr (default: shown; what runs and how it ended are always said)")  # fmt: skip


def deprecated(old: str, new: str, what: str = "") -> None:
    """One line on stderr: ``old`` still works until peeljax 0.3.0; ``new`` is its spelling now."""
    print(f"{PROG}: note: {old}{' ' + what if what else ''} is deprecated and is removed in peeljax 0.3.0: give {new}", file=sys.stderr)
