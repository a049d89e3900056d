"""Pieces shared by the ``peeljax`` subcommands: option checks, file checks, JSON output."""

from __future__ import annotations

import argparse
import difflib
import json
import math
import re
import sys
import threading
import time

import numpy as np

from .._files import json_safe
from ..adhesion import COEFFICIENT_NAMES, AdhesionLaw, read_json
from ..integrators import SOLVER_NAMES
from ..solution import StopReason

PROG = "peeljax"

STEPPERS = tuple(SOLVER_NAMES)  # the steppers that the error-controlled loop takes ("auto": Tsit5 ↔ α-method)

# A negative number in any spelling float() reads (-1e-6, -inf, -nan, -.5): argparse's own
# pattern (-1, -0.5) takes "-1e-6" for an option and answers "expected one argument", so the
# range check of the option never sees it. No option of peeljax looks like a number.
# A range START:STOP:COUNT that starts below zero (--V -1:2:4) is a value too, refused by its check.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*(e[+-]?\d+)?|\.\d+(e[+-]?\d+)?|inf(inity)?|nan)(:[^\s]*)?$", re.IGNORECASE)


_NUMBER = re.compile(r"^\s*[+-]?(\d+\.?\d*|\.\d+)(e[+-]?\d+)?\s*$", re.IGNORECASE)  # a finite number float() reads


class Parser(argparse.ArgumentParser):
    """An ArgumentParser that reads a negative number in any spelling as a value (``--rtol -1e-6``: the range
    check answers) and answers a misspelled option or command with the closest one."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def parse_args(self, args=None, namespace=None):
        words, commands = sys.argv[1:] if args is None else list(args), self._commands()
        if commands and not words:  # argparse: "the following arguments are required: COMMAND"
            self.error(f"give a command: {', '.join(commands)} ({self.prog} COMMAND --help lists its options)")
        for word in words if commands else ():  # an unknown option before the command: argparse says COMMAND is missing
            if not word.startswith("-"):
                break
            if (name := word.split("=", 1)[0]) not in self._option_string_actions:
                if close := difflib.get_close_matches(name.lstrip("-"), list(commands), n=1):
                    self.error(f"unrecognized option {name} (did you mean the command {close[0]}, without dashes?)")
                self.error(unrecognized([word], self))
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:  # argparse's own: "unrecognized arguments: --t-finl 3", from the top-level parser
            command = commands.get(getattr(parsed, "command", None))  # the subcommand's parser that read the line
            others = {name: parser for name, parser in commands.items() if parser is not command}
            (command or self).error(unrecognized(extras, command or self, others))
        return parsed

    def _commands(self) -> dict:
        """The subcommands' parsers by name (none without subcommands)."""
        action = next((a for a in self._actions if isinstance(a, argparse._SubParsersAction)), None)
        return {} if action is None else dict(action.choices)

    def _get_value(self, action, arg_string):
        """argparse's "invalid int value: '1e5'" said for a user: not an integer, write 100000."""
        try:
            return super()._get_value(action, arg_string)
        except argparse.ArgumentError:
            if action.type not in (int, float):
                raise
            number = float(arg_string) if _NUMBER.match(arg_string) else math.nan
            write = f": write {int(number)}" if math.isfinite(number) and number == int(number) else ""
            what = f"an integer{write}" if action.type is int else "a number"
            raise argparse.ArgumentError(action, f"{arg_string!r} is not {what}") from None

    def _check_value(self, action, value):
        if action.choices is not None and value not in action.choices:
            choices = [str(choice) for choice in action.choices]
            close = difflib.get_close_matches(str(value), choices, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}{hint} (choose from {', '.join(map(repr, choices))})")
        super()._check_value(action, value)


def unrecognized(extras: list[str], parser: argparse.ArgumentParser, others: dict | None = None) -> str:
    """The words argparse did not recognize, in one message: for an option of other commands (``others``: their
    parsers by name) which they are, for a misspelled option the closest of ``parser``'s options (``--t-finl`` ->
    ``--t-final``), for a stray value the rule that every value follows its option."""
    known = [name for name in parser._option_string_actions if name.startswith("--")]
    options = [word for word in extras if word.startswith("-") and not _NEGATIVE_NUMBER.match(word)]
    if not options:
        return f"unexpected value {' '.join(extras)!r}: every value follows its option (e.g. --V 1.1); {parser.prog} --help lists them"
    parts = []
    for word in options:
        name = word.split("=", 1)[0]
        elsewhere = [command for command, other in (others or {}).items() if name in other._option_string_actions]
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        if elsewhere:
            commands = ", ".join(elsewhere[:-1]) + " and " + elsewhere[-1] if len(elsewhere) > 1 else elsewhere[0]
            parts.append(f"{name} (an option of peeljax {commands}, not of {parser.prog})")
        else:
            parts.append(f"{name} (did you mean {close[0]}?)" if close else name)
    return f"unrecognized {'option' if len(parts) == 1 else 'options'} {', '.join(parts)}: {parser.prog} --help lists the options"


def read_phi(path: str) -> tuple[AdhesionLaw, tuple[str, ...]]:
    """The adhesion law in a JSON file and the coefficients it left out (they keep the paper's values), the one-line
    note about those printed on stderr; every failure becomes a ValueError naming --phi."""
    try:
        law, kept = read_json(path)
    except OSError as error:  # a directory, no permission, …: read_json handles only a missing file
        raise ValueError(f"--phi: cannot read {path!r} ({error.strerror or error})") from None
    except RecursionError:  # json's decoder recurses once per level: [[[[…]]]] a few thousand deep
        raise ValueError(f"--phi: {path!r} is not a JSON object of coefficients (nested too deeply)") from None
    except ValueError as error:  # read_json's messages name --phi, those of the coefficients the file
        message = str(error)
        raise ValueError(message if message.startswith("--phi") else f"--phi: {message}") from None
    if kept:
        given = ", ".join(name for name in COEFFICIENT_NAMES if name not in kept)
        print(f"{PROG}: note: --phi {path} sets {given}; {', '.join(kept)} keep the paper's values", file=sys.stderr)
    return law, kept


def load_phi(path: str | None) -> AdhesionLaw:
    """:func:`read_phi`'s law; without a file (None) the paper's."""
    return AdhesionLaw() if path is None else read_phi(path)[0]


def write_failed(option: str, path: str, error: OSError, what: str) -> int:
    """After a run: say what could not be written and where, instead of a traceback (exit 1)."""
    print(f"{PROG}: error: could not write {option} {path!r} ({error.strerror or error}); {what}", file=sys.stderr)
    return 1


def library_default(function, name: str):
    """The default of ``function``'s parameter ``name``: the command line's default, never restated."""
    return library_defaults(function)[name]


def library_defaults(function) -> dict:
    """The defaults of ``function``'s parameters by name."""
    import inspect

    return {name: p.default for name, p in inspect.signature(function).parameters.items()}


def solver_for(method: str, rho: float | None):
    """``--method`` as the ``solver`` argument of :func:`peeljax.simulate` / :func:`peeljax.sweep`: None for
    "default" (the library's choice), an ``AlphaMethod(rho=rho)`` for "alpha" (so that ``--rho`` reaches it), else
    the stepper's name."""
    if method != "alpha":
        return None if method == "default" else method
    from ..integrators import AlphaMethod

    return AlphaMethod() if rho is None else AlphaMethod(rho=rho)  # left out: its own default ρ


def max_steps_remedy(budget) -> str:
    """The line after a run that used up its step budget (stderr)."""
    now = "" if budget is None else f" (now {budget})"
    return f"{PROG}: the step budget was used up before t_final: raise --max-steps{now} or loosen --rtol"


def remedy_notes(status, budget) -> list[str]:
    """After trajectories (a sweep's, a map's) that used up their step budget: how many, and the remedy (stderr)."""
    status = np.asarray(status).ravel()
    out_of_steps = int(np.count_nonzero(status == int(StopReason.MAX_STEPS)))
    said = f"{PROG}: {out_of_steps} of {status.size} trajectories stopped at their step budget"
    return [said, max_steps_remedy(budget)] if out_of_steps else []


def phi_defaults(args: argparse.Namespace) -> list[str] | None:
    """The coefficients --phi left at the paper's values (None without --phi)."""
    return None if (kept := getattr(args, "phi_defaults", None)) is None else list(kept)


def stats_text(stats: dict, jumps_said: bool = False) -> str:
    """The run's counters as ``key value, ...``, only those that mean something for this run: no NaN (``step_size``
    under error control, which has no one step), no Newton counts where none were counted (an explicit stepper;
    diffrax's implicit ones count theirs inside), no ``steps`` beside ``accepted_steps`` (the same count, or
    accepted + rejected for the diffrax reference), no ``jumps`` where a line of its own gives them
    (``jumps_said``); floats to 4 significant digits."""
    hidden = {"steps"} if "accepted_steps" in stats else set()
    hidden |= {"jumps"} if jumps_said else set()
    hidden |= set() if stats.get("newton_iterations") else {"newton_iterations", "max_newton_iterations"}
    shown = {key: value for key, value in stats.items() if key not in hidden and not (isinstance(value, float) and math.isnan(value))}
    return ", ".join(f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}" for key, value in shown.items())


def subcommand(subparsers, name: str, handler, help: str, description: str, **defaults) -> argparse.ArgumentParser:
    """A subcommand's parser with its ``handler`` (and ``defaults`` such as ``out_formats``) set."""
    parser = subparsers.add_parser(name, help=help, description=description)
    parser.set_defaults(handler=handler, **defaults)
    return parser


def checked(validate, command):
    """A handler that runs ``command(args, validate(args))``; a refusal of ``validate`` (ValueError, TypeError: the
    library's checks, before anything compiles) is :func:`fail`'s one line and exit 2."""

    def handler(args: argparse.Namespace) -> int:
        try:
            config = validate(args)
        except (ValueError, TypeError) as error:
            return fail(error)
        return command(args, config)

    return handler


def wrote(record: dict) -> list[str]:
    """The summary's last lines: the files written (``record``'s out and plot)."""
    return [f"wrote {record[key]}" for key in ("out", "plot") if record.get(key)]


def fail(error: Exception) -> int:
    """A refusal: ``peeljax: error: <message>`` on stderr, in the command line's words; exit 2."""
    message = option_names(str(error))
    print(f"{PROG}: error: {message}{closest_choice(message)}", file=sys.stderr)
    return 2


# The refusals that list what is allowed: "must be one of a, b; got 'x'" (and ", got"), and
# "unknown ['x', 'y']; allowed: a, b".
_ONE_OF = re.compile(r"one of ([^;]+?)[;,] got '([^']*)'")
_ALLOWED = re.compile(r"\[([^\]]*)\]; allowed: ([^;()]+)")


def closest_choice(message: str) -> str:
    """``"; did you mean 'tsit5'?"`` for a refusal that lists the allowed names, when a given name is close to one of
    them (case aside: ``Tsit5``, ``C1``); else ""."""
    found = _ONE_OF.search(message)
    if found is not None:
        allowed, given = found.group(1).split(", "), [found.group(2)]
    elif (found := _ALLOWED.search(message)) is not None:
        allowed, given = found.group(2).strip().split(", "), re.findall(r"'([^']*)'", found.group(1))
    else:
        return ""
    lowered = {name.lower(): name for name in allowed}
    named = [lowered[c[0]] for name in given if (c := difflib.get_close_matches(name.lower(), list(lowered), n=1))]
    return "; did you mean " + ", ".join(map(repr, named)) + "?" if named and len(named) == len(given) else ""


# Python parameter names (with an underscore: never a word of prose) and their options.
_PARAMETERS = {name: "--" + name.replace("_", "-") for name in (
    "max_jumps", "max_steps", "t_final", "save_dt", "save_every", "n_tau", "n_points", "n_starts", "max_iterations",
    "learning_rate", "tau_rtol", "tau_range", "random_starts", "seed_rounds", "boundary_tol", "lyapunov_time",
    "num_processes", "process_id")} | {"join_timeout": "--distributed-timeout"}  # fmt: skip
_UNDERSCORED = re.compile(r"(?<![\w-])(" + "|".join(_PARAMETERS) + r")\b")
_ASSIGNED = re.compile(r"(?<![\w-])(--[a-z][\w-]*)=(?=\w)")  # --max-jumps=5 (from max_jumps=5) -> --max-jumps 5
_ANOTHER_OUT = re.compile(r"\banother out\b")
_CHOSEN = re.compile(r"(?<![\w-])(fold|method|by|intervals)='(\w+)'")
# A parameter given its value ("dt=0.01", "tau=0"), the integrator a run's options make
# ("a diffrax solver (Kvaerno5)": the command line's --method diffrax) and its remedy.
_GIVEN = re.compile(r"(?<![\w-])(dt|tau)=([^\s,;()']+)")
_DIFFRAX_SOLVER = re.compile(r"\ba diffrax solver \(\w+\)")
# Remedies said in the Python API's words (peeljax.OrbitNotFound's), in the command line's.
_PHRASES = (
    ("run longer", "run longer (a larger --transient)"),
    ("a run too short", "a run too short (--transient)"),
    ("give start=(alpha, omega) and slips= to shoot near it",
     "the Python API shoots from a given state: peeljax.periodic_orbit(start=(alpha, omega), slips=K)"),
    ("give coordinator HOST:PORT", "give --coordinator HOST:PORT"), ("the same coordinator?", "the same --coordinator?"),
    ("or detect them under SLURM's srun", "or --distributed under SLURM's srun"), ("drop dt,", "drop --dt,"))  # fmt: skip
# The library's words for error control and the uniform mesh (sweep_plan's messages)
_MESH_PHRASES = (("(dt=None)", "(no --dt)"), ("(dt given)", "(--dt given)"))
# Names that open a library message ("tau must be ...", "y0: ..."), and those whose option has another name.
_LEADING = re.compile(r"^(V|tau|dt|rtol|atol|rho|y0|geometry|transient|window|fold|start|free|statistics|coordinator|"
                      r"decimate|paths|slips)\b(?![-=])")
_RENAMED = {"paths": "--data"}  # peeljax.measurements.records.load_observations(paths): the --data files


def option_names(message: str) -> str:
    """A library message in the command line's words: ``max_jumps`` → ``--max-jumps``, ``fold='stop'`` → ``--fold
    stop`` (``method=``, ``by=``, ``intervals=`` too), ``dt=0.01`` → ``--dt 0.01``, a remedy in the API's words in
    the options', and a message that opens with a parameter's name (``tau must be ...``) opens with its option."""
    message = _ASSIGNED.sub(r"\1 ", _UNDERSCORED.sub(lambda m: _PARAMETERS[m.group(1)], message))
    message = _ANOTHER_OUT.sub("another --out", message)  # the library's "choose another out"
    message = _CHOSEN.sub(r"--\1 \2", message)  # fold='stop' -> --fold stop, method='orbit' -> --method orbit
    for said, option in _MESH_PHRASES:  # before the next line would read "dt=None" as a value given
        message = message.replace(said, option)
    message = _GIVEN.sub(r"--\1 \2", message)  # dt=0.01 -> --dt 0.01
    message = _DIFFRAX_SOLVER.sub("--method diffrax", message).replace("drop dt/solver", "drop --dt/--method")
    for said, option in _PHRASES:
        message = message.replace(said, option)
    return _LEADING.sub(lambda m: _RENAMED.get(m.group(1), "--" + m.group(1)), message)


# Seconds between two "still running" lines of a long compiled run (tests make it short).
HEARTBEAT_S = 30.0


class Elapsed:
    """While a compiled run goes on (it cannot report from inside without a host callback in its loop), a line on
    stderr every :data:`HEARTBEAT_S` seconds with the wall time elapsed, and on leaving one with the total;
    nothing when ``on`` is False."""

    def __init__(self, on: bool, what: str):
        self.on, self.what, self._stop, self._thread, self._start = on, what, threading.Event(), None, 0.0

    def __enter__(self):
        self._start = time.perf_counter()
        if self.on:
            self._thread = threading.Thread(target=self._beat, args=(sys.stderr,), daemon=True)
            self._thread.start()
        return self

    def _beat(self, stream) -> None:
        while not self._stop.wait(HEARTBEAT_S):
            print(f"{PROG}: {self.what}: still running, {time.perf_counter() - self._start:.0f} s elapsed", file=stream, flush=True)

    def __exit__(self, kind, value, traceback):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self.on and kind is None:
            print(f"{PROG}: {self.what}: done in {time.perf_counter() - self._start:.3g} s", file=sys.stderr)
        return False


# The summaries use a few non-ASCII signs; the plain output promises ASCII.
ASCII = str.maketrans({"→": "->", "—": "-", "–": "-", "≈": "~", "τ": "tau", "φ": "phi", "≥": ">=", "±": "+-",
                       "−": "-", "λ": "lambda", "≤": "<="})  # fmt: skip


def ascii_text(text: str) -> str:
    """``text`` in plain ASCII, whatever the terminal's encoding (what has no spelling: ``?``)."""
    return text.translate(ASCII).encode("ascii", "replace").decode("ascii")


def write_files(record: dict, *writers) -> list:
    """Each ``(option, path, write)`` with a path: ``write(path)``. A failure is kept as ``(option, path, error)``
    and its key of ``record`` (``out``, ``plot``) set to None: the result is reported whatever could not be written."""
    failed = []
    for option, path, write in (writer for writer in writers if writer[1] is not None):
        try:
            write(path)
        except OSError as error:
            failed.append((option, path, error))
            record[option.lstrip("-")] = None
    return failed


def write_then_plot(record: dict, args: argparse.Namespace, save, figure) -> list:
    """--out with ``save``, then --plot with ``figure`` only beside a written file (:func:`write_files`)."""
    return write_files(record, ("--out", args.out, save)) or write_files(record, ("--plot", args.plot, figure))


def plotter(name: str, *args, module: str = "peeljax.plots", **kwargs):
    """A writer for :func:`write_files`: ``module.name(*args, path=path, **kwargs)``, imported
    (matplotlib) only when the figure is drawn."""
    import importlib

    return lambda path: getattr(importlib.import_module(module), name)(*args, path=path, **kwargs)


def report(record: dict, as_json: bool, lines, failed=(), what: str = "", notes=()) -> int:
    """``--json``: ``record`` as the one JSON object on stdout (strict: NaN is null); else the summary ``lines``
    (ASCII). Then on stderr the ``notes`` and each file that could not be written (``failed``, after ``what`` was
    reported). Returns the exit status: 1 when a file failed, else 0."""
    print(json.dumps(json_safe(record), allow_nan=False) if as_json else ascii_text("\n".join(lines() if callable(lines) else lines)))
    for note in notes:
        print(note, file=sys.stderr)
    for option, path, error in failed:
        write_failed(option, path, error, what)
    return 1 if failed else 0
