"""The ``peeljax`` command's entry point, outside the package so that it runs before JAX loads.

Importing :mod:`peeljax` imports JAX, which takes 1.5–3 s; a Ctrl-C in that window reached
Python's default handler (an ``ImportError`` or ``KeyboardInterrupt`` traceback, or a swallowed
interrupt). Here SIGINT is taken first: until :func:`peeljax.cli.main` installs its own guard,
it prints the command's one line and ends the process with status 130.
"""

from __future__ import annotations

import os
import signal
import sys


def _interrupted_while_starting(signum, frame) -> None:
    try:
        sys.stderr.write("peeljax: interrupted\n")
        sys.stderr.flush()
    finally:
        os._exit(130)


def main(argv: list[str] | None = None) -> int:
    """Run ``peeljax`` with ``argv`` (default: the process's arguments)."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    from peeljax.cli import main as run  # imports JAX

    return run(argv)


if __name__ == "__main__":
    raise SystemExit(main())
