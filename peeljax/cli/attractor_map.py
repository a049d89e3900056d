"""``peeljax map``: every attractor over V, labelled, with basins and boundaries
(:func:`peeljax.attractor_map`)."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..attractor_map import DEFAULT_V, attractor_map, check_attractor_map_options
from . import options
from ._common import PROG, checked, library_defaults, phi_defaults, plotter, report, subcommand, write_then_plot, wrote

__all__ = ["add_command", "validate_attractor_map"]

_DEFAULTS = library_defaults(attractor_map)


def add_command(subparsers) -> None:
    parser = subcommand(subparsers, "map", checked(validate_attractor_map, _map_command), "every attractor over V: labels, "
                        "basins, boundaries", "Runs from rest, steady peeling and random states on the stick branch at "
                        "every V (tau = 0, the DAE itself), then from the neighbours' attractors; labels each attractor "
                        "steady, periodic, quasi-periodic or chaotic (Lyapunov exponents through the jumps); locates "
                        "where every branch ends to --boundary-tol (docs/attractors.md).", out_formats=(".npz",))  # fmt: skip
    problem, grid, d = parser.add_argument_group("problem"), DEFAULT_V, _DEFAULTS
    options.add_V(problem, many=True, default=None, help="the grid of pull velocities [m/s], increasing",
                  shown=f"{grid[0]:g}:{grid[-1]:g}:{grid.size}")  # fmt: skip
    options.add_t_final(problem, default=d["t_final"],
                        help=f"length of each run [s], > 0 (default {d['t_final']:g}; its second half is the window)")
    options.add_geometry_and_phi(problem)
    search = parser.add_argument_group("the search")
    for option, kind, text in (
        ("--random-starts", int, "random states on the stick branch per V, >= 0"), ("--seed", int, "their seed"),
        ("--seed-rounds", int, "rounds of runs from the neighbours' attractors, >= 0"),
        ("--boundary-tol", float, "bracket width of each boundary [m/s], > 0; 0: boundaries not located"),
        ("--lyapunov-time", float, "averaging time of the Lyapunov exponents [s]"),
    ):  # fmt: skip
        default = d[option[2:].replace("-", "_")]
        search.add_argument(option, type=kind, default=default, help=f"{text} (default {default:g})")
    options.add_output(parser, "a line per round", out=("FILE.npz", "write the map (.npz; peeljax.load reads it)"),
                       plot=("FILE.png", "draw the map"))  # fmt: skip


def validate_attractor_map(args: argparse.Namespace) -> dict:
    """Every option checked, nothing compiled; the keyword arguments of :func:`peeljax.attractor_map`."""
    V = DEFAULT_V if args.V is None else np.asarray(options.check_positive_values("--V", args.V))
    options.check_outputs(args)
    model, args.phi_defaults = options.model_from(args)
    kwargs = {
        "model": model, "V": V, "t_final": float(args.t_final), "random_starts": args.random_starts, "seed": args.seed,
        "seed_rounds": args.seed_rounds, "boundary_tol": None if args.boundary_tol == 0 else args.boundary_tol,
        "lyapunov_time": args.lyapunov_time, "progress": args.progress and not args.json}  # fmt: skip
    # the library's checks, of the options given and (left out here) its defaults
    given = {key: value for key, value in kwargs.items() if key != "progress"}
    left_out = {name: _DEFAULTS[name] for name in ("transient", "extend", "branch_tol", "chaos_threshold", "orbit_rtol")}
    check_attractor_map_options(**given, **left_out, sweep_kwargs={})
    return kwargs


def _map_command(args: argparse.Namespace, kwargs: dict) -> int:
    print(f"{PROG}: attractor map over {kwargs['V'].size} values of V, {kwargs['random_starts']} random starts each "
          "(compiling first: about a minute) ...", file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    amap = attractor_map(**kwargs)
    record = {**amap.as_dict(), "wall_time_s": time.perf_counter() - start, "phi_paper_defaults": phi_defaults(args),
              "out": args.out, "plot": args.plot}  # fmt: skip
    failed = write_then_plot(record, args, amap.save, plotter("plot_attractor_map", amap))
    return report(record, args.json, [amap.summary(), *wrote(record)], failed, "the map is above")
