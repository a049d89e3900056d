"""``peeljax tau-star``: τ* per V, the least resolvable τ (:func:`peeljax.least_tau`), with the
engine options of ``peeljax sweep``."""

from __future__ import annotations

import argparse
import sys
import time

from ..sweeps.least_tau import check_search
from ..sweeps.least_tau import least_tau as _least_tau_api
from . import options
from ._common import PROG, Elapsed, checked, library_defaults, option_names, phi_defaults, report, subcommand
from ._engine import add_engine, engine, engine_model, engine_record, engine_rho, engine_text

__all__ = ["add_command", "validate_tau_star"]

_TAU_STAR = library_defaults(_least_tau_api)  # the search, left out: peeljax.least_tau's


def add_command(subparsers) -> None:
    star = subcommand(subparsers, "tau-star", checked(validate_tau_star, _tau_star_command), "the least resolvable tau per V",
        "For each V, tau* = the least tested tau above which every tested tau completes [0, t_final], with "
        "tau*(1 - tau_rtol) stopping (docs/sweeps.md). All V are searched in parallel. The runs use error control "
        "(--rtol, --atol) by default, a uniform mesh with --dt.")  # fmt: skip
    add_engine(star)
    search, (lo, hi) = star.add_argument_group("the search"), _TAU_STAR["tau_range"]
    search.add_argument("--tau-range", dest="tau_range", type=float, nargs=2, default=[lo, hi], metavar=("LO", "HI"),
                        help=f"search interval [s], 0 < LO < HI (default {lo:g} {hi:g})")  # fmt: skip
    search.add_argument("--tau-rtol", dest="tau_rtol", type=float, default=_TAU_STAR["tau_rtol"],
                        help="relative resolution of tau* in (0, 1), not an integrator tolerance (default "
                        f"{_TAU_STAR['tau_rtol']:g})")  # fmt: skip
    search.add_argument("--n-points", dest="n_points", type=int, default=_TAU_STAR["n_points"],
                        help=f"tau values per V and round, an integer >= 2 (default {_TAU_STAR['n_points']})")  # fmt: skip
    options.add_output(star, "progress (the elapsed wall time)")


def validate_tau_star(args: argparse.Namespace) -> dict:
    V, chosen, model = options.check_positive_values("--V", args.V), engine(args), engine_model(args)
    lo, hi = check_search(args.tau_range, args.tau_rtol, args.n_points)  # the library's check
    return {"model": model, "V": V, **chosen, "t_final": float(args.t_final), "tau_range": (lo, hi),
            "tau_rtol": float(args.tau_rtol), "n_points": args.n_points, "rho": engine_rho(args)}  # fmt: skip


def _run_tau_star(kwargs: dict):
    from ..sweeps import least_tau

    return least_tau(**kwargs)


def _tau_star_command(args: argparse.Namespace, kwargs: dict) -> int:
    print(f"{PROG}: searching tau* for V = {kwargs['V']}, {engine_text(kwargs)} (compiling first: a few seconds) ...",
          file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    # least_tau runs its rounds as compiled batches and reports nothing in between: the wall time is shown
    with Elapsed(args.progress, "searching tau*"):
        result = _run_tau_star(kwargs)
    wall = time.perf_counter() - start
    record = {
        **result.as_dict(), **engine_record(kwargs), "t_final": kwargs["t_final"], "tau_range": list(kwargs["tau_range"]),
        "tau_rtol": kwargs["tau_rtol"], "max_steps": kwargs.get("max_steps"),  # --max-steps; null: the library's budget
        "wall_time_s": wall, "phi_paper_defaults": phi_defaults(args)}  # fmt: skip
    lines = [f"{PROG} tau-star: {engine_text(kwargs)}, t_final = {kwargs['t_final']:g} s, "
             f"tau_rtol = {kwargs['tau_rtol']:g}, {result.rounds} batched runs, {wall:.3g} s",
             option_names(result.summary())]  # fmt: skip (tau_range -> --tau-range)
    return report(record, args.json, lines)
