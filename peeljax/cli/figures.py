"""``peeljax figures``: regenerate the paper's Figs. 2–7 and the structure figures as image files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._files import check_output_folder, image_formats, json_safe
from .._validation import check_positive
from . import options
from ._common import PROG, checked, subcommand, write_failed

__all__ = ["add_command"]


def add_command(subparsers) -> None:
    parser = subcommand(subparsers, "figures", checked(_check, _figures_command), "regenerate the paper's figures",
        "Run the paper's simulations (V = 1.1, 2, 4 m/s; the tau lists and steps of peeljax.figures.RUNS) and write "
        "Figs. 2-7, phi with its extrema and |J_t| with the local index, plus captions.md.")  # fmt: skip
    parser.add_argument("--out", default="figures", metavar="FOLDER", help="output folder (created; default figures/)")
    parser.add_argument("--t-final", dest="t_final", type=float, default=None,
                        help="end time of every run [s], >= 0.05 (default: the paper's, peeljax.figures.write_figures'; "
                        "shorter for a quick check)")  # fmt: skip
    parser.add_argument("--format", default=None, help="image format: png, pdf, svg, ... (default: write_figures')")
    parser.add_argument("--json", action="store_true", help="print one JSON object (run facts, files) on stdout")
    options.add_progress(parser, "line per group of runs")


def _check(args: argparse.Namespace) -> dict:
    """The options as :func:`peeljax.figures.write_figures`' keyword arguments (those given)."""
    given = {}
    if args.t_final is not None:
        check_positive("t_final", args.t_final)
        if args.t_final < 0.05:
            raise ValueError(f"t_final must be >= 0.05 s (allowed range: [0.05, inf)), got {args.t_final}")
        given["t_final"] = args.t_final
    if args.format is not None:
        given["fmt"] = args.format.lower().lstrip(".")
        if given["fmt"] not in image_formats():
            raise ValueError(f"--format: unknown image format {given['fmt']!r}; use one of {', '.join(sorted(image_formats()))}")
    check_output_folder("--out", args.out)
    return given


def _figures_command(args: argparse.Namespace, given: dict) -> int:
    from ..figures import write_figures

    say = args.progress and (lambda message: print(f"{PROG}: {message}", file=sys.stderr))
    try:
        facts = write_figures(Path(args.out), **given, progress=say)
    except OSError as error:
        return write_failed("--out", args.out, error, "the figures were computed but not all were saved")
    if args.json:
        print(json.dumps(json_safe(facts)))
    else:
        print("\n".join(facts["files"]))
        print(f"{len(facts['files'])} figures in {facts['total_seconds']:.1f} s; captions in {Path(args.out) / 'captions.md'}")
    return 0
