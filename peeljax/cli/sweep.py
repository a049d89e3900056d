"""``peeljax sweep``: a batched sweep over V and τ, or (``--stick-slip-map``) the stick-slip map
over V; its engine's options are ``peeljax tau-star``'s too (:mod:`.tau_star`)."""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

from ..sweeps.integrators import DEFAULT_SWEEP_MAX_JUMPS
from . import _interrupt, options
from ..sweeps.api import sweep as sweep_api
from ..sweeps import distributed
from ..sweeps.storage import saved_chunks
from ._common import PROG, checked, fail, library_default, phi_defaults, plotter, remedy_notes, report, subcommand, wrote
from ._common import write_failed, write_files
from ._engine import DEFAULT_CHUNK, add_engine, check_sweep_outputs, chunk, engine, engine_model, engine_record
from ._engine import engine_rho, engine_text, tau_grid
from .sweep_map import map_command

__all__ = ["add_command", "validate_sweep"]


# ---------------------------------------------------------------------------- parsers
def add_command(subparsers) -> None:
    parser = subcommand(subparsers, "sweep", checked(_check, _sweep_command), "batched runs over a grid of V and tau", (
        "Integrate every (V, tau) of a grid in compiled batches (error control by default, any stepper: --method; --dt for "
        "the alpha-method's uniform mesh); write per-trajectory summaries (v statistics over [--transient, --transient + "
        "--window], stick-slip events, steps taken). With --out the sweep is written chunk by chunk and a rerun resumes."
    ), out_formats=(".npz", ".nc"))  # fmt: skip
    solver = add_engine(parser)
    solver.add_argument("--save-dt", dest="save_dt", type=float, default=None, metavar="S",
                        help="error control only: also save the states at t = 0, S, 2S, ... and t_final [s], S in "
                        "(0, t_final] (default: none)")  # fmt: skip
    solver.add_argument("--save-every", dest="save_every", type=int, default=None, metavar="N",
                        help="uniform mesh only (with --dt): also save the states every N steps, N >= 1 (default: none)")
    grid = parser.add_argument_group("the grid of tau")
    grid.add_argument("--tau", type=options.numbers("--tau", ranges=False), nargs="+", default=None,
                      help="tau values [s]: all in (0, 1e6] (the homogenized ODE) or 0 (the DAE itself, jumping at the "
                      "folds of phi; error control only); with --n-tau, two numbers LO HI give a log-spaced grid "
                      "(default 1e-3 1e-1; with --stick-slip-map 0)")  # fmt: skip
    grid.add_argument("--n-tau", dest="n_tau", type=int, default=None,
                      help="points of a log-spaced tau grid from --tau LO to HI, an integer >= 2 (default: none, the --tau values "
                      "as given)")  # fmt: skip
    grid.add_argument("--chunk", type=int, default=None, help=f"trajectories per compiled batch, >= 1 (default {DEFAULT_CHUNK})")
    folds = parser.add_argument_group("folds of phi (stick-slip jumps; error control only)")
    options.add_fold(folds, "--dt")
    options.add_max_jumps(folds, default=DEFAULT_SWEEP_MAX_JUMPS, per="trajectory")
    folds.add_argument("--start", default=None, metavar="{paper,steady}",
                       help="each trajectory's initial state: 'paper' (the tape at rest) or 'steady' (steady peeling, "
                       "v = V) (default paper; with --stick-slip-map both, one after the other)")  # fmt: skip
    options.add_statistics_window(
        parser.add_argument_group("statistics"), what="the v statistics (the stick-slip map's cycle statistics)",
        window_default="t_final - T; with --stick-slip-map the statistics run to each run's end")  # fmt: skip
    parser.add_argument_group("the stick-slip map over V").add_argument(
        "--stick-slip-map", dest="stick_slip_map", action="store_true",
        help="instead of the (V, tau) sweep: at one --tau (default 0, the DAE), one sweep over --V per start (both "
        "unless --start), each run's jumps after --transient reduced to its cycle statistics; --out writes the map's "
        "arrays (.npz), --plot its figure against V (forces at the jumps over phi's folds, repeat period, v amplitude)")  # fmt: skip
    options.add_output(parser, "progress bar", out=("FILE.npz", "results (numpy, with each trajectory's jump record; FILE.nc: "
                       "netCDF with labelled dimensions, needs pip install \"peeljax[xarray]\"); chunks in FILE.npz.chunks/, "
                       "resumable; with --stick-slip-map the map's arrays; peeljax.load reads either back"),
                       plot=("FILE.png", "the stick-slip map over (V, tau) (tau > 0); with --stick-slip-map the map "
                             "against V"))  # fmt: skip
    _add_distributed_options(parser)


def _add_distributed_options(parser: argparse.ArgumentParser) -> None:
    """One ``peeljax sweep`` per process, with the same options (docs/sweeps.md); without these nothing joins JAX's
    distributed runtime (jax.distributed.initialize's arguments; None: one process, or what --distributed detects)."""
    group = parser.add_argument_group("several processes (JAX's distributed runtime: one command per process, same options; "
                                      "docs/sweeps.md)")  # fmt: skip
    under_srun, timeout = "with --distributed under srun", distributed.DEFAULT_TIMEOUT
    group.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0, which every process connects "
                       f"to (default: $JAX_COORDINATOR_ADDRESS; {under_srun}: the job's first node)")  # fmt: skip
    group.add_argument("--num-processes", type=int, metavar="N", help=f"processes in the sweep, >= 1 ({under_srun}: $SLURM_NTASKS)")
    group.add_argument("--process-id", type=int, metavar="I", help="this process's rank, 0 <= I < N; 0 writes --out and "
                       f"reports ({under_srun}: $SLURM_PROCID)")  # fmt: skip
    group.add_argument("--distributed", action="store_true", help="join the other processes, taking what the three "
                       "options above leave out from the environment ($JAX_COORDINATOR_ADDRESS, SLURM's srun)")  # fmt: skip
    group.add_argument("--distributed-timeout", dest="distributed_timeout", type=float, default=timeout, metavar="S",
                       help=f"seconds to wait for every process to reach the coordinator, > 0 (default {timeout:g})")


# ---------------------------------------------------------------------------- validation
# The settings a sweep's --out records (peeljax.sweep's names) and the options that set them.
_SETTING_OPTIONS = {
    "V": "--V", "tau": "--tau", "dae": "--tau", "t_final": "--t-final", "window": "--transient/--window",
    "method": "--method", "solver": "--method/--rho", "rtol": "--rtol", "atol": "--atol", "max_steps": "--max-steps",
    "dt": "--dt", "n_steps": "--dt", "fold": "--fold", "max_jumps": "--max-jumps", "start": "--start",
    "save_dt": "--save-dt", "save_every": "--save-every", "chunk": "--chunk", "model": "--geometry/--phi"}  # fmt: skip
_DIFFER = re.compile(r"made with different settings \(([^()]*) differ\)")


def resume_refusal(message: str, args: argparse.Namespace) -> str:
    """The library's refusal to resume an --out made with other settings, in the options the user set: ``tau`` is
    --tau (and --n-tau when given); ``chunk`` only when --chunk was given (else it follows from the grid's size,
    which the options named beside it changed); the statistics window only when --t-final is the same (it is kept
    as fractions of t_final)."""
    found = _DIFFER.search(message)
    if found is None:
        return message
    names = [name.strip() for name in found.group(1).split(",")]
    dropped = {"chunk"} if args.chunk is None and len(names) > 1 else set()
    dropped |= {"n_steps"} if {"dt", "t_final"} & set(names) else set()  # n_steps = t_final/dt
    dropped |= {"window"} if "t_final" in names else set()  # kept as fractions of t_final: --transient may be as before
    said, renamed = [], {"--tau": "--tau/--n-tau"} if args.n_tau is not None else {}
    if args.chunk is None:
        renamed["--chunk"] = f"the batch size (--chunk, default {DEFAULT_CHUNK}, at most the number of trajectories)"
    for option in (_SETTING_OPTIONS.get(name, name) for name in names if name not in dropped):
        said += [] if renamed.get(option, option) in said else [renamed.get(option, option)]
    joined = " and ".join(said) if len(said) <= 2 else ", ".join(said[:-1]) + " and " + said[-1]
    return f"{message[: found.start()]}made with a different {joined}{message[found.end() :]}"


def validate_sweep(args: argparse.Namespace) -> dict:
    """Every option checked, nothing compiled; returns the keyword arguments of :func:`peeljax.sweep`."""
    V, tau = options.check_positive_values("--V", args.V), tau_grid([1e-3, 1e-1] if args.tau is None else args.tau, args.n_tau)
    chosen, model, window = engine(args, dae=tau == [0.0]), engine_model(args), _window(args)
    if args.plot is not None and tau == [0.0]:
        raise ValueError("--plot draws the (V, tau) map, whose tau axis is logarithmic: with --tau 0 (the DAE) add "
                         "--stick-slip-map for the map against V")  # fmt: skip
    check_sweep_outputs(args)
    return {
        "model": model, "V": V, "tau": tau, **chosen, "t_final": float(args.t_final), "grid": "outer",
        "window": window, "chunk": chunk(args), "out": args.out, "rho": engine_rho(args), "progress": args.progress and not args.json,
        "start": library_default(sweep_api, "start") if args.start is None else args.start}  # fmt: skip


def _window(args: argparse.Namespace) -> tuple[float, float]:
    """--transient T and --window W [s] as :func:`peeljax.sweep`'s ``window``, two fractions of
    t_final (the statistics cover [T, T + W]); the old --window W0 W1 read with a note."""
    T, W = options.one_window(args.window, fractions_allowed=True, t_final=args.t_final)
    if T is not None:  # the old form: its fractions as given (an --out written with them resumes)
        if args.transient is not None:
            raise ValueError("--window W0 W1 (the deprecated form) sets the transient too: give --transient T --window W")
        return (float(args.window[0]), float(args.window[1]))
    T, W = options.check_statistics_window(args.transient, W, args.t_final)
    return (T / args.t_final, min(1.0, (T + W) / args.t_final))


def _run_sweep(kwargs: dict):
    from ..sweeps import sweep

    return sweep(**kwargs)


# ---------------------------------------------------------------------------- several processes
def distributed_settings(args: argparse.Namespace) -> distributed.Processes | None:
    """The process options, checked by :func:`peeljax.sweeps.distributed.processes`; None for one process."""
    given = (args.coordinator, args.num_processes, args.process_id)
    asked = args.distributed or given != (None, None, None)
    if asked and args.stick_slip_map:
        raise ValueError("--coordinator, --num-processes, --process-id and --distributed run the (V, tau) sweep over "
                         "several processes, not --stick-slip-map")  # fmt: skip
    processes = distributed.processes(*given, args.distributed_timeout, detect=args.distributed)
    tasks = os.environ.get("SLURM_NTASKS")  # srun started several, but nothing joins them
    if not asked and os.environ.get("SLURM_PROCID") is not None and tasks not in (None, "1"):
        print(f"{PROG}: note: SLURM started {tasks} tasks; without --distributed (or --coordinator, "
              "--num-processes, --process-id) each runs the whole sweep by itself", file=sys.stderr)  # fmt: skip
    return processes


def join_processes(processes: distributed.Processes | None, args: argparse.Namespace) -> int | None:
    """Join JAX's distributed runtime (:func:`peeljax.sweeps.distributed.join`; nothing for None): None once
    joined, else the exit status after a message. A process that cannot join in time exits 2 itself."""
    if processes is None:
        return None
    try:
        distributed.join(processes, on_timeout=_not_joined)
    except (RuntimeError, ValueError) as error:
        print(f"{PROG}: error: {processes.describe()}: could not join ({error})", file=sys.stderr)
        return 2
    _quiet_stdout(keep=processes.process_id == 0)
    args.plot = args.plot if processes.process_id == 0 else None  # process 0 reports; the others compute their share
    return None


def _not_joined(message: str) -> None:
    """The join's watchdog: the refusal, exit 2 (the main thread is blocked inside JAX's C++ client)."""
    fail(ValueError(message))
    sys.stderr.flush()
    os._exit(2)


def _quiet_stdout(keep: bool) -> None:
    """Send what the runtime's C++ prints on stdout (gloo's "Rank 0 is connected to 1 peer ranks") to stderr, so that
    stdout carries only peeljax's report (one JSON object with --json); keep that report only in process 0."""
    sys.stdout.flush()
    report = os.dup(1)
    os.dup2(2, 1)  # file descriptor 1, which C++ writes to, is now stderr
    sys.stdout = os.fdopen(report, "w") if keep else open(os.devnull, "w")  # noqa: SIM115 (the process's life)
    if not keep:
        os.close(report)


def _check(args: argparse.Namespace) -> tuple:
    """The process options (checked first, joined after the sweep's own checks) and the sweep's keyword arguments
    (None for --stick-slip-map, checked by :func:`.sweep_map.map_command`)."""
    return distributed_settings(args), None if args.stick_slip_map else validate_sweep(args)


def _sweep_command(args: argparse.Namespace, checked_: tuple) -> int:
    processes, kwargs = checked_
    if kwargs is None:
        return map_command(args)
    joined = join_processes(processes, args)
    if joined is not None:
        return joined
    n = len(kwargs["V"]) * len(kwargs["tau"])
    print(f"{PROG}: sweep of {n} trajectories, {engine_text(kwargs)} (compiling first: a few seconds) ...", file=sys.stderr)
    start = time.perf_counter()
    # Ctrl-C's line says how many chunks are saved, whichever thread prints it (cli._interrupt)
    with _interrupt.note(lambda: _saved_chunks(args.out)):
        try:
            result = _run_sweep(kwargs)
        except ValueError as error:  # e.g. an --out made with other settings, or too much output
            return fail(ValueError(resume_refusal(str(error), args)))
        except OSError as error:  # the chunk files: written as they finish
            return write_failed("--out", args.out, error, "the chunks written before it are kept; rerun to resume")
        except KeyboardInterrupt:
            return _interrupt.interrupted(_saved_chunks(args.out))
    wall = time.perf_counter() - start
    if not kwargs["progress"]:  # the progress bar's own line said it otherwise
        _print_resumed(result, args.out)
    record = {
        "n": len(result), "n_completed": int(result.completed.sum()), "V": kwargs["V"], "tau": kwargs["tau"],
        **engine_record(kwargs, result.settings.get("method")), "method_option": args.method,  # the stepper that ran, --method
        "max_steps": result.settings.get("max_steps"),  # the budget of step attempts (error control)
        "save_dt": kwargs["save_dt"], "save_every": kwargs["save_every"], "t_final": kwargs["t_final"],
        "window": list(kwargs["window"]),  # fractions of t_final, as pj.sweep takes them
        "transient": kwargs["window"][0] * kwargs["t_final"],  # [s]: --transient
        "window_s": (kwargs["window"][1] - kwargs["window"][0]) * kwargs["t_final"],  # [s]: --window
        "fold": result.settings.get("fold"), "max_jumps": result.settings.get("max_jumps"), "start": kwargs["start"],
        "wall_time_s": wall, "phi_paper_defaults": phi_defaults(args),
        "computed_chunks": list(result.computed_chunks), "out": args.out, "plot": args.plot, **result.as_dict()}  # fmt: skip
    failed = write_files(record, ("--plot", args.plot, plotter("plot_sweep_map", result)))
    notes = remedy_notes(result.status, result.settings.get("max_steps", kwargs.get("max_steps")))
    return report(record, args.json, lambda: _sweep_lines(record, result, kwargs, wall), failed,
                  "the sweep's results are above", notes)  # fmt: skip


def _saved_chunks(out: str | None) -> str:
    """After an interruption: how many chunks are saved, and how to go on (from the chunk folder)."""
    if out is None:
        return "nothing was saved (no --out); with --out a rerun resumes from the chunks finished"
    saved, total = saved_chunks(out)
    chunks = f"{saved} chunk{'' if saved == 1 else 's'}" if total is None else f"{saved} of {total} chunks"
    return f"{chunks} saved in {str(out) + '.chunks'!r}; rerun the same command to resume"


def _print_resumed(result, out: str | None) -> None:
    """The line :func:`peeljax.sweep` prints with its progress bar when it resumed an --out."""
    n_chunks = -(-len(result) // int(result.settings["chunk"]))
    if out is not None and (loaded := n_chunks - len(result.computed_chunks)):
        print(f"resumed: {loaded} of {n_chunks} chunks loaded from {str(out) + '.chunks'!r}", file=sys.stderr)


def _sweep_lines(record: dict, result, kwargs: dict, wall: float) -> list[str]:
    """The sweep's summary: what ran, then one row per trajectory."""
    t_final, (w0, w1) = kwargs["t_final"], kwargs["window"]
    folds = "" if result.jumps is None else f"; start {record['start']}, fold {record['fold']} (max_jumps {record['max_jumps']})"
    return [
        f"{PROG} sweep: {record['n']} trajectories, {record['n_completed']} completed t = {t_final:g} s, wall time {wall:.3g} s",
        f"{engine_text(kwargs, result.settings.get('method'))}; v statistics over t in [{w0 * t_final:g}, "
        f"{w1 * t_final:g}] s (--transient {w0 * t_final:g} --window {(w1 - w0) * t_final:g}){folds}",
        result.table(), *wrote(record)]
