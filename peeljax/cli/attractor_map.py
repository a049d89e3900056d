"""``peeljax map``: every attractor over V, labelled, with basins and boundaries
(:func:`peeljax.attractor_map`)."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..attractor_map import DEFAULT_V, attractor_map, check_attractor_map_options
from . import options
from ._common import PROG, fail, library_default, phi_defaults, plotter, report, write_files

__all__ = ["add_command", "validate_attractor_map"]

_DEFAULTS = {
    name: library_default(attractor_map, name)
    for name in ("random_starts", "seed", "t_final", "seed_rounds", "boundary_tol", "lyapunov_time", "transient",
                 "extend", "branch_tol", "chaos_threshold", "orbit_rtol")
}


def add_command(subparsers) -> None:
    parser = subparsers.add_parser(
        "map",
        help="every attractor over V: labels, basins, boundaries",
        description=(
            "Runs from rest, steady peeling and random states on the stick branch at every V (tau = 0, the DAE "
            "itself), then from the neighbours' attractors; labels each attractor steady, periodic (k slips per "
            "period, its orbit and Floquet multiplier), quasi-periodic or chaotic (Lyapunov exponents through the "
            "jumps); locates where every branch ends to --boundary-tol (docs/attractors.md)."
        ),
    )
    problem = parser.add_argument_group("problem")
    grid = DEFAULT_V
    problem.add_argument(
        "--V", type=options.numbers("--V"), nargs="+", default=None, metavar="V",
        help="the grid of pull velocities [m/s], increasing, each > 0: numbers separated by spaces, or "
        f"START:STOP:COUNT for COUNT equally spaced values (default {grid[0]:g}:{grid[-1]:g}:{grid.size})",
    )  # fmt: skip
    options.add_t_final(problem, default=_DEFAULTS["t_final"], help=f"length of each run [s], > 0 (default {_DEFAULTS['t_final']:g}; its second half is the window)")  # fmt: skip
    options.add_geometry_and_phi(problem)
    search = parser.add_argument_group("the search")
    search.add_argument("--random-starts", dest="random_starts", type=int, default=_DEFAULTS["random_starts"],
                        help=f"random states on the stick branch per V, >= 0 (default {_DEFAULTS['random_starts']})")  # fmt: skip
    search.add_argument("--seed", type=int, default=_DEFAULTS["seed"], help=f"their seed (default {_DEFAULTS['seed']})")
    search.add_argument("--seed-rounds", dest="seed_rounds", type=int, default=_DEFAULTS["seed_rounds"],
                        help=f"rounds of runs from the neighbours' attractors, >= 0 (default {_DEFAULTS['seed_rounds']})")  # fmt: skip
    search.add_argument("--boundary-tol", dest="boundary_tol", type=float, default=_DEFAULTS["boundary_tol"],
                        help=f"bracket width of each boundary [m/s], > 0; 0: boundaries not located (default {_DEFAULTS['boundary_tol']:g})")  # fmt: skip
    search.add_argument("--lyapunov-time", dest="lyapunov_time", type=float, default=_DEFAULTS["lyapunov_time"],
                        help=f"averaging time of the Lyapunov exponents [s] (default {_DEFAULTS['lyapunov_time']:g})")  # fmt: skip
    output = parser.add_argument_group("output")
    options.add_outputs(output, out_meta="FILE.npz", out_help="write the map (.npz; peeljax.load reads it)",
                        plot_help="draw the map")  # fmt: skip
    options.add_json(output)
    options.add_progress(output, "a line per round")
    parser.set_defaults(handler=_map_command, out_formats=(".npz",))


def validate_attractor_map(args: argparse.Namespace) -> dict:
    """Every option checked, nothing compiled; the keyword arguments of :func:`peeljax.attractor_map`."""
    V = DEFAULT_V if args.V is None else np.asarray(options.check_positive_values("--V", args.V))
    options.check_outputs(args)
    model, args.phi_defaults = options.model_from(args)
    kwargs = {
        "model": model, "V": V, "t_final": float(args.t_final), "random_starts": args.random_starts, "seed": args.seed,
        "seed_rounds": args.seed_rounds, "boundary_tol": None if args.boundary_tol == 0 else args.boundary_tol,
        "lyapunov_time": args.lyapunov_time, "progress": options.progress_on(args) and not args.json,
    }  # fmt: skip
    check_attractor_map_options(  # the library's checks; what the command line leaves out, the library's defaults
        model, V, args.random_starts, args.seed, kwargs["t_final"], _DEFAULTS["transient"], args.seed_rounds,
        _DEFAULTS["extend"], kwargs["boundary_tol"], _DEFAULTS["branch_tol"], args.lyapunov_time,
        _DEFAULTS["chaos_threshold"], _DEFAULTS["orbit_rtol"], {},
    )  # fmt: skip
    return kwargs


def _map_command(args: argparse.Namespace) -> int:
    try:
        kwargs = validate_attractor_map(args)
    except (ValueError, TypeError) as error:
        return fail(error)
    print(f"{PROG}: attractor map over {kwargs['V'].size} values of V, {kwargs['random_starts']} random starts each "
          "(compiling first: about a minute) ...", file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    amap = attractor_map(**kwargs)
    wall = time.perf_counter() - start
    record = {
        **amap.as_dict(),
        "wall_time_s": wall,
        "phi_paper_defaults": phi_defaults(args),
        "out": args.out,
        "plot": args.plot,
    }
    failed = write_files(record, ("--out", args.out, amap.save))
    if not failed:
        failed = write_files(record, ("--plot", args.plot, plotter("plot_attractor_map", amap)))
    lines = [amap.summary()] + [f"wrote {record[key]}" for key in ("out", "plot") if record[key]]
    return report(record, args.json, lines, failed, "the map is above")
