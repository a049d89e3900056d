"""``peeljax simulate``: one run, its summary, an .npz of the trajectory and a plot."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from .._validation import check_choice, check_mesh, check_positive, check_rho, check_y0
from ..adhesion import AdhesionLaw
from ..model import GEOMETRIES, PeelingModel
from ..simulate import simulate, simulate_reference
from ..solution import Solution
from ._common import PROG, check_output_path, checked, fail, json_safe, load_phi, plot_formats

__all__ = ["add_command", "run", "summarize", "validate_run", "write_npz"]

METHODS = ("alpha", "diffrax")
_METHOD_TITLES = {"alpha": "alpha-method", "diffrax": "diffrax Kvaerno5 reference"}
_PLOT_METHODS = {"alpha": "α-method", "diffrax": "diffrax Kvaerno5 reference"}
_DEFAULT_RTOL, _DEFAULT_ATOL = 1e-8, 1e-10


def _add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Physics and integrator options shared by the commands that run the model."""
    physics = parser.add_argument_group("problem")
    physics.add_argument("--V", type=float, default=1.1, help="pull velocity [m/s], > 0 (default %(default)s)")
    physics.add_argument(
        "--tau", type=float, default=0.01, help="homogenization time scale tau [s], > 0 (default %(default)s)"
    )
    physics.add_argument(
        "--t-final", dest="t_final", type=float, default=3.0, help="end time [s], >= dt (default %(default)s)"
    )
    physics.add_argument(
        "--geometry", default="paper", metavar="{paper,full}", help="'paper' approximations or 'full' (default paper)"
    )
    physics.add_argument(
        "--y0",
        type=float,
        nargs=4,
        metavar=("ALPHA", "OMEGA", "U", "V"),
        help="initial state with v > 0 (default: the paper's consistent data, v0 = 1e-10*V)",
    )
    physics.add_argument(
        "--phi", metavar="COEFFS.json", help="adhesion coefficients c1..p9 as JSON (default: the paper's law)"
    )
    solver = parser.add_argument_group("integrator")
    solver.add_argument(
        "--method", default="alpha", metavar="{alpha,diffrax}", help="alpha-method or diffrax reference (default alpha)"
    )
    solver.add_argument(
        "--dt",
        type=float,
        default=1 / 82,
        help="step [s] (alpha) or output spacing (diffrax); N = round(t_final/dt) (default 1/82)",
    )
    solver.add_argument("--rho", type=float, default=None, help="alpha-method's rho in [0, 1) (default 0; alpha only)")
    solver.add_argument(
        "--rtol", type=float, default=None, help=f"relative tolerance, > 0 (default {_DEFAULT_RTOL:g}; diffrax only)"
    )
    solver.add_argument(
        "--atol", type=float, default=None, help=f"absolute tolerance, > 0 (default {_DEFAULT_ATOL:g}; diffrax only)"
    )


def _add_output_arguments(parser: argparse.ArgumentParser) -> None:
    output = parser.add_argument_group("output")
    output.add_argument("--out", metavar="FILE.npz", help="write t, alpha, omega, u, v, F and the parameters (numpy)")
    output.add_argument("--plot", metavar="FILE.png", help="write v(t), alpha(t), F(t) panels (format from suffix)")
    output.add_argument("--json", action="store_true", help="print one JSON object on stdout instead of a summary")


def add_command(subparsers) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="integrate one run",
        description="Integrate the homogenized peeling ODE over [0, t_final] and report how it ended.",
    )
    _add_run_arguments(parser)
    _add_output_arguments(parser)
    parser.set_defaults(handler=_simulate_command)


# ---------------------------------------------------------------------------- validation
@dataclass(frozen=True)
class RunConfig:
    """A validated run: everything the integrator and the writers need."""

    model: PeelingModel
    V: float
    tau: float
    dt: float
    t_final: float
    n_steps: int
    method: str
    rho: float | None  # α-method only
    rtol: float | None  # diffrax only
    atol: float | None  # diffrax only
    y0: tuple[float, ...] | None
    phi: str | None


def validate_run(args: argparse.Namespace) -> RunConfig:
    """Check every option as the Python API would, without compiling anything.

    Raises:
        ValueError: naming the option and its allowed range.
    """
    check_choice("geometry", args.geometry, GEOMETRIES)
    check_choice("method", args.method, METHODS)
    positive = "(0, inf)"
    checked(positive, check_positive, "V", args.V)
    checked(positive, check_positive, "tau", args.tau)
    n_steps = checked("dt in (0, t_final], t_final in (0, inf)", check_mesh, args.dt, args.t_final)
    rho = rtol = atol = None
    if args.method == "alpha":
        rho = 0.0 if args.rho is None else args.rho
        checked("[0, 1)", check_rho, rho)
        if args.rtol is not None or args.atol is not None:
            raise ValueError("--rtol/--atol are the diffrax solver's tolerances: they apply with --method diffrax only")
    else:
        if args.rho is not None:
            checked("[0, 1)", check_rho, args.rho)
            raise ValueError("rho is the alpha-method's parameter: --rho applies with --method alpha only")
        rtol = _DEFAULT_RTOL if args.rtol is None else args.rtol
        atol = _DEFAULT_ATOL if args.atol is None else args.atol
        checked(positive, check_positive, "rtol", rtol)
        checked(positive, check_positive, "atol", atol)
    checked("finite (alpha, omega, u, v) with v > 0", check_y0, args.y0)
    adhesion = AdhesionLaw() if args.phi is None else load_phi(args.phi)
    check_output_path("--out", args.out)
    if args.plot is not None:
        check_output_path("--plot", args.plot, plot_formats())
    model = PeelingModel(adhesion=adhesion, geometry=args.geometry)
    return RunConfig(
        model=model,
        V=float(args.V),
        tau=float(args.tau),
        dt=float(args.dt),
        t_final=float(args.t_final),
        n_steps=n_steps,
        method=args.method,
        rho=rho,
        rtol=rtol,
        atol=atol,
        y0=None if args.y0 is None else tuple(args.y0),
        phi=args.phi,
    )


# ---------------------------------------------------------------------------- running and reporting
def run(config: RunConfig) -> tuple[Solution, float]:
    """Integrate; returns the solution and the wall time [s] including compilation."""
    import jax

    start = time.perf_counter()
    if config.method == "alpha":
        solution = simulate(config.model, config.V, config.tau, config.dt, config.t_final, config.rho, config.y0)
    else:
        solution = simulate_reference(
            config.model, config.V, config.tau, config.dt, config.t_final, config.y0, rtol=config.rtol, atol=config.atol
        )
    solution = jax.block_until_ready(solution)  # JAX dispatches asynchronously: time the finished run
    return solution, time.perf_counter() - start


def step_used(solution: Solution, config: RunConfig) -> float:
    """The α-method's actual step t_final/N, or the diffrax output grid's spacing."""
    if config.method == "alpha":
        return float(solution.stats["step_size"])
    return config.t_final / config.n_steps


def summarize(solution: Solution) -> dict:
    """:meth:`Solution.summary`, also for a run whose initial state was already rejected."""
    if np.asarray(solution.valid).any():
        return solution.summary()
    out = {
        "status": solution.status_name,
        "reason": solution.reason,
        "t_stop": float(solution.t_stop),
        "steps": 0,
        "v_final": math.nan,
        "v_min": math.nan,
        "v_max": math.nan,
    }
    out.update({key: np.asarray(value).tolist() for key, value in solution.stats.items()})
    return out


def _tension(solution: Solution, model: PeelingModel) -> np.ndarray:
    ys = np.asarray(solution.ys, dtype=float)
    tension = np.asarray(model.tension(ys[:, 2], ys[:, 0]), dtype=float)
    return np.where(np.asarray(solution.valid), tension, np.nan)


def write_npz(path: str, solution: Solution, config: RunConfig) -> None:
    """The run as plain arrays and scalars (loads with ``np.load(path, allow_pickle=False)``).

    Arrays t, alpha, omega, u, v, F (tension) and valid share one length, NaN after a stop.
    Scalars: status, reason, t_stop, V, tau, dt (the step used), t_final, rho (NaN for diffrax),
    rtol and atol (NaN for alpha), geometry, method, phi_json (the 14 coefficients, "" for a
    callable φ) and stats_json.
    """
    ys = np.asarray(solution.ys, dtype=float)
    adhesion = config.model.adhesion
    phi_json = json.dumps(adhesion.coefficients()) if isinstance(adhesion, AdhesionLaw) else ""
    stats = {key: np.asarray(value).tolist() for key, value in solution.stats.items()}
    arrays = {
        "t": np.asarray(solution.ts, dtype=float),
        "alpha": ys[:, 0],
        "omega": ys[:, 1],
        "u": ys[:, 2],
        "v": ys[:, 3],
        "F": _tension(solution, config.model),
        "valid": np.asarray(solution.valid, dtype=bool),
        "status": np.asarray(solution.status_name, dtype=str),
        "reason": np.asarray(solution.reason, dtype=str),
        "t_stop": np.float64(solution.t_stop),
        "V": np.float64(config.V),
        "tau": np.float64(config.tau),
        "dt": np.float64(step_used(solution, config)),
        "t_final": np.float64(config.t_final),
        "rho": np.float64(math.nan if config.rho is None else config.rho),
        "rtol": np.float64(math.nan if config.rtol is None else config.rtol),
        "atol": np.float64(math.nan if config.atol is None else config.atol),
        "geometry": np.asarray(config.model.geometry, dtype=str),
        "method": np.asarray(config.method, dtype=str),
        "phi_json": np.asarray(phi_json, dtype=str),
        "stats_json": np.asarray(json.dumps(stats), dtype=str),
    }
    # An open file keeps the name exactly as given (np.savez would append .npz to a bare name).
    with open(path, "wb") as handle:
        np.savez(handle, **arrays)


def _plot_title(config: RunConfig, dt: float) -> str:
    parts = [f"V = {config.V:g} m/s", f"τ = {config.tau:g} s", _PLOT_METHODS[config.method]]
    if config.method == "alpha":
        parts += [f"dt = {dt:.4g} s", f"ρ = {config.rho:g}"]
    else:
        parts += [f"rtol = {config.rtol:g}", f"output every {dt:.4g} s"]
    if config.model.geometry != "paper":
        parts.append(f"{config.model.geometry} geometry")
    return ", ".join(parts)


def _print_summary(record: dict, config: RunConfig, stats: dict) -> None:
    """A few human-readable lines (ASCII, whatever the terminal's encoding)."""
    settings = f"rho = {config.rho:g}" if config.rho is not None else f"rtol = {config.rtol:g}, atol = {config.atol:g}"
    print(
        f"peeljax simulate: {_METHOD_TITLES[config.method]}, V = {config.V:g} m/s, tau = {config.tau:g} s, "
        f"dt = {record['dt']:.6g} s ({config.n_steps} steps), t_final = {config.t_final:g} s, {settings}, "
        f"geometry {config.model.geometry}"
    )
    if record["status"] == "completed":
        print(f"completed: reached t = {record['t_stop']:.6g} s")
    else:
        print(f"stopped at t = {record['t_stop']:.6g} s: {record['reason']}")
    print(f"v [m/s]: final {record['v_final']:.6g}, min {record['v_min']:.6g}, max {record['v_max']:.6g}")
    print("stats: " + ", ".join(f"{key} {value}" for key, value in stats.items()))
    print(f"wall time {record['wall_time_s']:.3g} s (including compilation)")
    for key in ("out", "plot"):
        if record.get(key):
            print(f"wrote {record[key]}")


def _simulate_command(args: argparse.Namespace) -> int:
    try:
        config = validate_run(args)
    except (ValueError, TypeError) as error:
        return fail(error)
    print(
        f"{PROG}: {config.method} run with {config.n_steps} steps to t = {config.t_final:g} s "
        "(compiling first: a few seconds) ...",
        file=sys.stderr,
    )
    solution, wall = run(config)
    dt = step_used(solution, config)
    summary = summarize(solution)
    stats = {key: summary[key] for key in solution.stats if key in summary}
    record = {
        **summary,
        "V": config.V,
        "tau": config.tau,
        "dt": dt,
        "dt_requested": config.dt,
        "t_final": config.t_final,
        "n_steps": config.n_steps,
        "method": config.method,
        "geometry": config.model.geometry,
        "rho": config.rho,
        "rtol": config.rtol,
        "atol": config.atol,
        "y0": None if config.y0 is None else list(config.y0),
        "phi": config.phi,
        "stats": stats,
        "wall_time_s": wall,
        "out": args.out,
        "plot": args.plot,
    }
    if args.out is not None:
        write_npz(args.out, solution, config)
    if args.plot is not None:
        from ..plots import plot_run  # matplotlib only when a plot is asked for

        plot_run(solution, config.model, V=config.V, title=_plot_title(config, dt), path=args.plot)
    if args.json:
        print(json.dumps(json_safe(record), allow_nan=False))
    else:
        _print_summary(record, config, stats)
    return 0
