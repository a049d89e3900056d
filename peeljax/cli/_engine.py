"""The options of the batched engine, shared by ``peeljax sweep`` (its ``--stick-slip-map`` too)
and ``peeljax tau-star``: declared once, read as the keyword arguments of :func:`peeljax.sweep` /
:func:`peeljax.least_tau` and checked by the library's own
:func:`~peeljax.sweeps.integrators.sweep_plan` before anything compiles."""

from __future__ import annotations

import argparse

import numpy as np

from .._validation import check_mesh, check_tau
from ..integrators.select import DEFAULT_ATOL, DEFAULT_MAX_STEPS_DENSE, DEFAULT_RTOL, integrator_for
from ..model import PeelingModel
from ..sweeps.api import sweep
from ..sweeps.integrators import DEFAULT_SWEEP_MAX_JUMPS, sweep_plan
from ..sweeps.least_tau import least_tau
from ..sweeps.storage import check_writable_format, is_netcdf
from ._common import STEPPERS, library_default, solver_for
from .options import (add_geometry_and_phi, add_max_steps, add_method, add_t_final, add_tolerances, add_V, check_max_jumps,
                      check_max_steps, check_method, check_outputs, check_save_dt, flatten, model_from)  # fmt: skip


def add_engine(parser: argparse.ArgumentParser):
    """The problem's and the integrator's options of the batched engine (peeljax sweep, its map, tau-star); returns
    the integrator's argument group."""
    group = parser.add_argument_group("problem")
    add_V(group, many=True, default=list(library_default(least_tau, "V")))  # least_tau's grid, a sweep's too
    add_t_final(group, default=library_default(least_tau, "t_final"))  # peeljax.sweep's too
    add_geometry_and_phi(group)
    solver = parser.add_argument_group("integrator")
    solver.add_argument("--dt", type=float, default=None,
                        help="uniform-mesh step [s] of the alpha-method, in (0, t_final] (default: error control)")  # fmt: skip
    add_tolerances(solver, rtol_default=f"{DEFAULT_RTOL:g}", atol_default=f"{DEFAULT_ATOL:g}")
    add_method(solver, library_default(sweep, "rho"))
    add_max_steps(solver, default=f"{DEFAULT_MAX_STEPS_DENSE:.0e}; stick-slip takes about 50-100 a jump")
    return solver


def engine(args: argparse.Namespace, dae: bool = False) -> dict:
    """The integrator's options (and a sweep's --fold, --max-jumps, --start) as the keyword arguments of
    :func:`peeljax.sweep` / :func:`peeljax.least_tau`, checked by the library's
    :func:`~peeljax.sweeps.integrators.sweep_plan` (before anything compiles); ``rtol``/``atol`` left out are the
    defaults it chose, ``solver`` and ``max_steps`` only where given."""
    method, uniform, sweeping = getattr(args, "method", "default"), None if args.dt is None else "--dt", hasattr(args, "fold")
    check_method(method, ("default", *STEPPERS), args.dt, args.rho)
    check_max_steps(args.max_steps, uniform)
    saving = {name: getattr(args, name) for name in ("save_dt", "save_every") if hasattr(args, name)}
    chosen = {"dt": args.dt, "rtol": args.rtol, "atol": args.atol, **saving}
    if method != "default":
        chosen["solver"] = solver_for(method, engine_rho(args))
    if args.max_steps is not None:  # left out: the library's budget
        chosen["max_steps"] = int(args.max_steps)
    if sweeping:  # a sweep's (least_tau stops at the folds)
        check_max_jumps(args.max_jumps, DEFAULT_SWEEP_MAX_JUMPS, uniform)
        chosen.update(fold=args.fold, max_jumps=args.max_jumps)
    plan = sweep_plan(chosen.get("solver"), engine_rho(args), args.dt, args.t_final, args.rtol, args.atol, saving.get("save_dt"),
                      saving.get("save_every"), None, args.max_steps, chosen.get("fold", "stop"),
                      args.max_jumps if sweeping else None, dae, getattr(args, "start", None) or "paper")  # fmt: skip
    if saving.get("save_dt") is not None:
        check_save_dt(saving["save_dt"], args.t_final)  # at most 1e7 output times
    if not plan.uniform:
        settings = plan.integrator.settings()
        chosen.update(rtol=settings["rtol"], atol=settings["atol"])
    return chosen


def engine_rho(args: argparse.Namespace) -> float:
    """--rho, else peeljax.sweep's (and least_tau's) default."""
    return library_default(sweep, "rho") if args.rho is None else float(args.rho)


def _stepper(kwargs: dict, ran: str | None = None) -> str | None:
    """The stepper's name: the one that ran (a result's ``settings["method"]``), else the one --method chose ("alpha"
    for an AlphaMethod); None: the library's default, not known before it ran."""
    if ran is not None:
        return "alpha" if ran.startswith("alpha") else ran
    solver = kwargs.get("solver")  # the uniform mesh, or --method alpha's AlphaMethod: the α-method
    return "alpha" if kwargs["dt"] is not None or (solver is not None and not isinstance(solver, str)) else solver


def engine_text(kwargs: dict, ran: str | None = None) -> str:
    """Which engine runs, in words (ASCII): the stepper (``ran``: the one that ran), error control with its
    tolerances or the uniform mesh, and ρ for the α-method."""
    stepper = _stepper(kwargs, ran)
    name = {"alpha": "alpha-method", None: "default stepper"}.get(stepper, stepper)
    n_steps = None if kwargs["dt"] is None else check_mesh(kwargs["dt"], kwargs["t_final"])
    text = (f"{name}, error control rtol = {kwargs['rtol']:g}, atol = {kwargs['atol']:g}" if n_steps is None else
            f"{name}, uniform mesh dt = {kwargs['t_final'] / n_steps:.6g} s ({n_steps} steps)")  # fmt: skip
    return text if stepper not in ("alpha", None) else f"{text}, rho = {kwargs['rho']:g}"


def engine_record(kwargs: dict, ran: str | None = None) -> dict:
    """The integrator's settings for the JSON output: method (the stepper that ran, when given), dt (null with error
    control), rtol, atol, rho (null when the stepper is not the α-method)."""
    default = "alpha" if kwargs["dt"] is not None else integrator_for(t_final=1.0).settings()["method"]  # τ > 0's
    rho = kwargs["rho"] if _stepper(kwargs, ran) in ("alpha", None) else None
    return {"method": default if ran is None else ran, "dt": kwargs["dt"], "rtol": kwargs["rtol"], "atol": kwargs["atol"], "rho": rho}


def engine_model(args) -> PeelingModel:
    model, args.phi_defaults = model_from(args)
    return model


DEFAULT_CHUNK = library_default(sweep, "chunk")  # --chunk left out: peeljax.sweep's


def tau_grid(tau: list[float], n_tau: int | None) -> list[float]:
    """--tau values as given (all > 0, or all 0: the DAE), or with --n-tau a log-spaced grid between two values."""
    tau = flatten(tau)
    if tau and all(value == 0 for value in tau):
        if n_tau is not None:
            raise ValueError("--n-tau spaces tau logarithmically between LO > 0 and HI; --tau 0 is the DAE itself")
        return [0.0]
    if any(value == 0 for value in tau):
        raise ValueError(f"--tau must be finite and > 0 (the homogenized ODE), or 0 alone (the DAE itself); got {tau}: "
                         "the two are different problems, sweep them separately")  # fmt: skip
    check_tau(tau)
    if n_tau is None:
        return tau
    if isinstance(n_tau, bool) or n_tau < 2:
        raise ValueError(f"--n-tau must be an integer >= 2 (allowed range: [2, inf)), got {n_tau}")
    if len(tau) != 2 or tau[0] >= tau[1]:
        raise ValueError(f"--n-tau needs exactly two --tau values LO < HI, got {' '.join(f'{t:g}' for t in tau)}")
    return np.geomspace(tau[0], tau[1], n_tau).tolist()


def chunk(args: argparse.Namespace) -> int:
    return DEFAULT_CHUNK if args.chunk is None else int(args.chunk)


def check_sweep_outputs(args: argparse.Namespace) -> None:
    if args.chunk is not None and args.chunk < 1:
        raise ValueError(f"--chunk must be a positive integer (allowed range: [1, inf)), got {args.chunk}")
    check_outputs(args)
    if args.out is not None and is_netcdf(args.out):  # before the run: the extra may be missing
        try:
            check_writable_format(args.out)
        except ImportError as error:
            raise ValueError(f"--out {args.out!r}: {error}") from None
