"""``peeljax figures``: regenerate the paper's Figs. 2–7 and the structure figures as image files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._files import check_output_folder, image_formats, json_safe
from .._validation import check_positive
from . import options
from ._common import PROG, fail, write_failed

__all__ = ["add_command"]


def add_command(subparsers) -> None:
    parser = subparsers.add_parser(
        "figures",
        help="regenerate the paper's figures",
        description=(
            "Run the paper's simulations (V = 1.1, 2, 4 m/s; the tau lists and steps of peeljax.figures.RUNS) "
            "and write Figs. 2-7, phi with its extrema and |J_t| with the local index, plus captions.md."
        ),
    )
    parser.add_argument("--out", default="figures", metavar="FOLDER", help="output folder (created; default figures/)")
    parser.add_argument(
        "--t-final", dest="t_final", type=float, default=None,
        help="end time of every run [s], >= 0.05 (default: the paper's, peeljax.figures.write_figures'; shorter for a "
        "quick check)",
    )  # fmt: skip
    parser.add_argument("--format", default=None, help="image format: png, pdf, svg, ... (default: write_figures')")
    parser.add_argument("--json", action="store_true", help="print one JSON object (run facts, files) on stdout")
    options.add_progress(parser, "line per group of runs")
    parser.set_defaults(handler=_figures_command)


def _progress(args: argparse.Namespace):
    """A line on stderr per group of runs, or nothing with --no-progress."""
    if not options.progress_on(args):
        return False
    return lambda message: print(f"{PROG}: {message}", file=sys.stderr)


def _figures_command(args: argparse.Namespace) -> int:
    try:
        given = {}
        if args.t_final is not None:
            check_positive("t_final", args.t_final)
            if args.t_final < 0.05:
                raise ValueError(f"t_final must be >= 0.05 s (allowed range: [0.05, inf)), got {args.t_final}")
            given["t_final"] = args.t_final
        fmt = None if args.format is None else args.format.lower().lstrip(".")
        if fmt is not None and fmt not in image_formats():
            raise ValueError(f"--format: unknown image format {fmt!r}; use one of {', '.join(sorted(image_formats()))}")
        out = Path(args.out)
        check_output_folder("--out", args.out)
    except ValueError as error:
        return fail(error)

    from ..figures import write_figures

    try:
        facts = write_figures(out, **given, **({} if fmt is None else {"fmt": fmt}), progress=_progress(args))
    except OSError as error:
        return write_failed("--out", args.out, error, "the figures were computed but not all were saved")
    if args.json:
        print(json.dumps(json_safe(facts)))
    else:
        for path in facts["files"]:
            print(path)
        print(f"{len(facts['files'])} figures in {facts['total_seconds']:.1f} s; captions in {out / 'captions.md'}")
    return 0
