"""Pieces shared by the ``peeljax`` subcommands: option checks, file checks, JSON output."""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import tempfile
from pathlib import Path

from ..adhesion import COEFFICIENT_NAMES, AdhesionLaw, read_json

PROG = "peeljax"

try:  # the steppers that the error-controlled loop takes (peeljax.integrators.STEPPER_NAMES)
    from ..integrators import STEPPER_NAMES
except ImportError:  # a peeljax from before the loop took any stepper: the same names
    STEPPER_NAMES = ("alpha", "tsit5", "dopri5", "dopri8", "kvaerno3", "kvaerno4", "kvaerno5")
STEPPERS = tuple(STEPPER_NAMES)
# --max-steps: the loop counts its step attempts in 32 bits (a larger budget would wrap around).
MAX_STEPS_LIMIT = 2**31 - 1

# A negative number in any spelling float() reads (-1e-6, -inf, -nan, -.5): argparse's own
# pattern (-1, -0.5) takes "-1e-6" for an option and answers "expected one argument", so the
# range check of the option never sees it. No option of peeljax looks like a number.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*(e[+-]?\d+)?|\.\d+(e[+-]?\d+)?|inf(inity)?|nan)$", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """An ArgumentParser (subcommands' parsers included) that reads a negative number in any
    spelling as a value, e.g. ``--rtol -1e-6``, so that the option's range check answers."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER


def read_phi(path: str) -> tuple[AdhesionLaw, tuple[str, ...]]:
    """The adhesion law in a JSON file and the coefficients it left out (they keep the paper's
    values), the one-line note about those printed on stderr; every failure becomes a
    ValueError naming --phi."""
    try:
        law, kept = read_json(path)
    except OSError as error:  # a directory, no permission, …: read_json handles only a missing file
        raise ValueError(f"--phi: cannot read {path!r} ({error.strerror or error})") from None
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith("--phi") else f"--phi: {message}") from None
    if kept:
        given = [name for name in COEFFICIENT_NAMES if name not in kept]
        print(
            f"{PROG}: note: --phi {path} sets {', '.join(given)}; {', '.join(kept)} keep the paper's values",
            file=sys.stderr,
        )
    return law, kept


def load_phi(path: str) -> AdhesionLaw:
    """:func:`read_phi`'s law."""
    return read_phi(path)[0]


def _probe_folder(option: str, folder: Path) -> None:
    """Create and remove a file in ``folder``: the one test of writability that also catches
    read-only mounts, permissions and pseudo file systems such as /proc."""
    try:
        handle, name = tempfile.mkstemp(prefix=".peeljax-probe-", dir=folder)
        os.close(handle)
        os.remove(name)
    except OSError as error:
        raise ValueError(f"{option}: cannot write in the folder {str(folder)!r} ({error.strerror or error})") from None


def _file_in_the_way(path: Path) -> Path | None:
    """The first existing ancestor of ``path`` (or ``path`` itself) if it is a file, else None."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return None if candidate.is_dir() else candidate
    return None


def check_output_path(option: str, path: str | None, suffixes: set[str] | None = None) -> None:
    """Fail now rather than after a long run: the folder must exist and be writable, the suffix known."""
    if path is None:
        return
    target = Path(path)
    if target.is_dir():
        raise ValueError(f"{option}: {path!r} is a directory, expected a file name")
    folder = target.parent
    if not folder.is_dir():
        blocker = _file_in_the_way(folder)
        if blocker is not None:
            raise ValueError(f"{option}: {str(blocker)!r} is a file, not a folder")
        raise ValueError(f"{option}: the folder {str(folder)!r} does not exist")
    suffix = target.suffix.lstrip(".").lower()
    if suffixes is not None and suffix and suffix not in suffixes:
        raise ValueError(f"{option}: unknown image format {suffix!r}; use one of {', '.join(sorted(suffixes))}")
    _probe_folder(option, folder)


def check_output_folder(option: str, path: str) -> None:
    """An output folder: absent (its parent must exist; it is created) or a writable folder."""
    folder = Path(path)
    blocker = _file_in_the_way(folder)
    if blocker is not None:
        what = repr(path) if blocker == folder else f"{str(blocker)!r}, on the way to {path!r},"
        raise ValueError(f"{option}: {what} is a file, not a folder")
    if not folder.exists() and not folder.parent.is_dir():
        raise ValueError(f"{option}: the parent folder {str(folder.parent)!r} does not exist")
    _probe_folder(option, folder if folder.exists() else folder.parent)


def write_failed(option: str, path: str, error: OSError, what: str) -> int:
    """After a run: say what could not be written and where, instead of a traceback (exit 1)."""
    print(f"{PROG}: error: could not write {option} {path!r} ({error.strerror or error}); {what}", file=sys.stderr)
    return 1


def plot_formats() -> set[str]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return set(FigureCanvasAgg(Figure()).get_supported_filetypes())


def checked(allowed: str, check, *args):
    """Run a library check; add the allowed range where its message lacks one (e.g. "must be finite")."""
    try:
        return check(*args)
    except ValueError as error:
        message = str(error)
        if "allowed range" in message or allowed in message:
            raise
        raise ValueError(f"{message} (allowed range: {allowed})") from None


def solver_for(method: str, rho: float | None):
    """``--method`` as the ``solver`` argument of :func:`peeljax.simulate` / :func:`peeljax.sweep`:
    None for "default" (the library's choice), an ``AlphaMethod(rho=rho)`` for "alpha" (so that
    ``--rho`` reaches it), else the stepper's name."""
    if method == "default":
        return None
    if method == "alpha":
        from ..integrators import AlphaMethod

        return AlphaMethod(rho=0.0 if rho is None else rho)
    return method


def check_max_steps(max_steps: int | None, uniform_option: str | None) -> None:
    """--max-steps: None (the library's budget) or an integer in [1, 2**31 - 1]; refused with the
    uniform mesh (``uniform_option``, e.g. "--dt"), which takes no budget."""
    if max_steps is None:
        return
    if max_steps < 1:
        raise ValueError(f"--max-steps must be a positive integer (allowed range: [1, inf)), got {max_steps}")
    if max_steps > MAX_STEPS_LIMIT:
        raise ValueError(
            f"--max-steps {max_steps} exceeds the loop's count of step attempts (a 32-bit integer): "
            f"give at most {MAX_STEPS_LIMIT} (allowed range: [1, inf))"
        )
    if uniform_option is not None:
        raise ValueError(
            f"--max-steps (allowed range: [1, inf)) is error control's budget of step attempts; {uniform_option} "
            "asks for a uniform mesh, which takes no budget: give one or the other"
        )


def max_steps_remedy(budget) -> str:
    """The line after a run that used up its step budget (stderr)."""
    now = "" if budget is None else f" (now {budget})"
    return f"{PROG}: the step budget was used up before t_final: raise --max-steps{now} or loosen --rtol"


def json_safe(value):
    """NaN/inf → null, so the output is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


def fail(error: Exception) -> int:
    print(f"{PROG}: error: {error}", file=sys.stderr)
    return 2
