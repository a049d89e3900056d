"""``peeljax sweep --stick-slip-map``: the stick-slip map over V at one τ
(:func:`peeljax.sweeps.stick_slip_map`), with the options and checks of ``peeljax sweep``."""

from __future__ import annotations

import argparse
import sys
import time

from ..sweeps.engine import STARTS
from . import options
from ._common import PROG, checked, fail, phi_defaults, plotter, remedy_notes, report, write_then_plot, wrote
from ._engine import check_sweep_outputs, chunk, engine, engine_model, engine_record, engine_rho, engine_text, tau_grid

__all__ = ["map_command", "validate_map"]


def validate_map(args: argparse.Namespace) -> dict:
    """``--stick-slip-map``: every option checked, nothing compiled; returns the keyword arguments
    of :func:`peeljax.sweeps.stick_slip_map`."""
    V = options.check_positive_values("--V", args.V)
    if args.n_tau is not None:
        raise ValueError("--n-tau makes a grid of tau; --stick-slip-map runs over V at one --tau")
    tau = tau_grid([0.0] if args.tau is None else args.tau, None)
    if len(tau) != 1:
        raise ValueError(f"--stick-slip-map runs over V at one --tau (0: the DAE itself), got {len(tau)} values")
    for option, value in (("--dt", args.dt), ("--save-dt", args.save_dt), ("--save-every", args.save_every)):
        if value is not None:
            what = "a uniform mesh, which keeps no jumps" if option != "--save-dt" else "saved states"
            raise ValueError(f"{option} asks for {what}; --stick-slip-map reads the jumps of error-controlled runs")
    if args.window is not None:
        raise ValueError("--window: the stick-slip map's cycle statistics run from --transient to each run's end; give "
                         "--transient (and --t-final)")  # fmt: skip
    chosen = engine(args, dae=tau == [0.0])
    if chosen["fold"] == "stop":
        raise ValueError("--fold stop ends every run at its first fold: --stick-slip-map needs --fold jump (or follow)")
    model = engine_model(args)
    transient, _ = options.check_statistics_window(args.transient, None, args.t_final)
    check_sweep_outputs(args)
    return {
        "model": model, "V": V, "tau": tau[0], "t_final": float(args.t_final), "transient": transient,
        "starts": STARTS if args.start is None else (args.start,), "rtol": chosen["rtol"], "atol": chosen["atol"],
        **{key: chosen[key] for key in ("solver", "max_steps", "fold", "max_jumps") if key in chosen},
        "chunk": chunk(args), "rho": engine_rho(args), "progress": args.progress and not args.json}  # fmt: skip


def _run_map(kwargs: dict):
    from ..sweeps import stick_slip_map

    return stick_slip_map(**kwargs)


def _map_record(smap, kwargs: dict, args: argparse.Namespace, wall: float) -> dict:
    """The map as one JSON object: :meth:`~peeljax.sweeps.StickSlipMap.as_dict` and how it ran."""
    settings = smap.settings.get("sweep", {})
    ran = engine_record({**kwargs, "dt": None}, settings.get("method"))
    return {
        **smap.as_dict(), "method": ran["method"], "method_option": args.method,  # the stepper that ran, --method
        "rtol": kwargs["rtol"], "atol": kwargs["atol"], "rho": ran["rho"], "fold": settings.get("fold"),
        "max_jumps": settings.get("max_jumps"), "max_steps": settings.get("max_steps", kwargs.get("max_steps")),
        "wall_time_s": wall, "phi_paper_defaults": phi_defaults(args), "out": args.out, "plot": args.plot}  # fmt: skip


def map_command(args: argparse.Namespace) -> int:
    return checked(validate_map, _map_command)(args)


def _map_command(args: argparse.Namespace, kwargs: dict) -> int:
    tau = "tau = 0 (the DAE)" if kwargs["tau"] == 0 else f"tau = {kwargs['tau']:g} s"
    print(f"{PROG}: stick-slip map over {len(kwargs['V'])} values of V, {tau}, start {' and '.join(kwargs['starts'])} "
          f"({len(kwargs['V']) * len(kwargs['starts'])} runs), {engine_text({**kwargs, 'dt': None})} "
          "(compiling first: a few seconds) ...", file=sys.stderr)  # fmt: skip
    start = time.perf_counter()
    try:
        smap = _run_map(kwargs)
    except ValueError as error:
        return fail(error)
    record = _map_record(smap, kwargs, args, time.perf_counter() - start)
    failed = write_then_plot(record, args, smap.save, plotter("plot_stick_slip_map", smap))
    ran = engine_text({**kwargs, "dt": None}, smap.settings.get("sweep", {}).get("method"))
    lines = [str(smap), f"{ran}, max_steps {record['max_steps']}; wall time {record['wall_time_s']:.3g} s", *wrote(record)]
    notes = remedy_notes(smap.status, record["max_steps"])
    return report(record, args.json, lines, failed, "the map is above", notes)
