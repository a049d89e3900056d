"""The ``peeljax`` command line: ``peeljax simulate ...`` (one module per subcommand; a part of one
in its own module: :mod:`.simulate_report`, :mod:`.sweep_map`, :mod:`.fit_table`; the options
several share in :mod:`.options`, the batched engine's in :mod:`._engine`).

The command line only translates: it parses, calls one library function and prints. Inputs
are checked with the Python API's own checks (:mod:`peeljax._validation`, the library
functions' own) before anything is compiled; defaults are read from the library functions;
the one error path (:func:`._common.fail`) says the library's parameter names as options. Bad
input prints ``peeljax: error: <message>`` on stderr and exits with status 2, as argparse's own
usage errors do. A run that completes or stops early (an impasse point, a failed Newton
iteration, …) exits with status 0: stopping is a result, reported in the summary, the
``--json`` object and the ``--out`` file.

With ``--json`` stdout carries exactly one JSON object; progress notes always go to stderr.
Each subcommand module has ``add_command(subparsers)``, which registers it (:func:`._common.subcommand`) with
its ``handler``, most often :func:`._common.checked`: the command's validation, then its run.
"""

from __future__ import annotations

import argparse

from . import attractor_map as _attractor_map
from . import figures as _figures
from . import fit as _fit
from . import orbit as _orbit
from . import simulate as _simulate
from . import sweep as _sweep
from . import tau_star as _tau_star
from . import _interrupt
from .._files import json_safe
from ._common import PROG, Parser
from .simulate import summarize, validate_run, write_npz

__all__ = ["build_parser", "json_safe", "main", "summarize", "validate_run", "write_npz"]

COMMANDS = (_simulate, _sweep, _tau_star, _orbit, _attractor_map, _figures, _fit)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per command (each sets ``handler``)."""
    from .._version import __version__

    parser = Parser(prog=PROG, description="Stick-slip peeling of an adhesive tape off a rotating spool (homogenized DAE, in JAX).")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_command(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    0: the run completed or stopped early (see its status); 2: bad input (nothing was run);
    130: interrupted (Ctrl-C; a sweep with --out says how many chunks are saved). After a real
    SIGINT it does not return: it ends the process with status 130 (``os._exit``), as JAX's
    clean-up at the interpreter's exit crashes while a compiled program still runs.
    """
    with _interrupt.guard():  # Ctrl-C in any phase: 130 and one line (after a real SIGINT main does not return)
        try:
            try:
                args = build_parser().parse_args(argv)
            except SystemExit as exit_:  # argparse has printed its usage error (2) or --help (0)
                return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
            return args.handler(args)
        except KeyboardInterrupt:  # one line, no traceback, the shell's status for SIGINT
            return _interrupt.interrupted()
