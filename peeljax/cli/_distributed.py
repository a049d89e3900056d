"""``peeljax sweep`` over several processes: the process options, and joining JAX's distributed runtime.

A cluster's job script starts one ``peeljax sweep`` per process with the same sweep options and

* ``--coordinator HOST:PORT --num-processes N --process-id I`` (a coordinator address JAX also
  reads from ``JAX_COORDINATOR_ADDRESS``), or
* ``--distributed`` under SLURM's ``srun``: JAX's cluster detection fills in what is not given
  (the job's first node with a port from the job id, ``SLURM_NTASKS``, ``SLURM_PROCID``).

Without these options nothing here runs: a one-process sweep never calls
``jax.distributed.initialize``. The options are checked with the sweep's own before anything
is joined or compiled. Joining waits at most ``--distributed-timeout`` seconds for every process
to reach the coordinator; then the process prints which coordinator it waited for and exits
with status 2 (JAX itself would wait minutes, then abort with a C++ stack trace). Once joined,
processes other than 0 print nothing on stdout and draw no ``--plot``: process 0 reports (and,
in :func:`peeljax.sweep`, writes ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import socket
import sys
import threading

from ._common import PROG

__all__ = ["DEFAULT_TIMEOUT", "Processes", "add_distributed_options", "distributed_settings", "join_processes"]

DEFAULT_TIMEOUT = 60.0
_OPTIONS = ("coordinator", "num_processes", "process_id")


@dataclasses.dataclass(frozen=True)
class Processes:
    """Where this process stands among the others: JAX's ``initialize`` arguments (None: detected)."""

    coordinator: str | None
    num_processes: int | None
    process_id: int | None
    timeout: float

    def describe(self) -> str:
        where = self.coordinator or "the coordinator JAX's cluster detection chose"
        who = "this process" if self.process_id is None else f"process {self.process_id}"
        of = "" if self.num_processes is None else f" of {self.num_processes}"
        return f"{who}{of}, coordinator {where}"


def add_distributed_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "several processes (JAX's distributed runtime: one command per process, same options; docs/sweeps.md)"
    )
    group.add_argument(
        "--coordinator", default=None, metavar="HOST:PORT",
        help="address of process 0, which every process connects to (default: $JAX_COORDINATOR_ADDRESS; "
        "with --distributed under srun: the job's first node)",
    )  # fmt: skip
    group.add_argument(
        "--num-processes", dest="num_processes", type=int, default=None, metavar="N",
        help="processes in the sweep, >= 1 (with --distributed under srun: $SLURM_NTASKS)",
    )  # fmt: skip
    group.add_argument(
        "--process-id", dest="process_id", type=int, default=None, metavar="I",
        help="this process's rank, 0 <= I < N; 0 writes --out and reports (with --distributed under srun: "
        "$SLURM_PROCID)",
    )  # fmt: skip
    group.add_argument(
        "--distributed", action="store_true",
        help="join the other processes, taking what the three options above leave out from the environment "
        "($JAX_COORDINATOR_ADDRESS, SLURM's srun)",
    )  # fmt: skip
    group.add_argument(
        "--distributed-timeout", dest="distributed_timeout", type=float, default=DEFAULT_TIMEOUT, metavar="S",
        help=f"seconds to wait for every process to reach the coordinator, > 0 (default {DEFAULT_TIMEOUT:g})",
    )  # fmt: skip


def _check_coordinator(address: str, source: str) -> str:
    host, colon, port = address.strip().rpartition(":")
    if not colon or not host.strip("[]") or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{source} must be HOST:PORT with a port in [1, 65535], got {address!r}")
    return address.strip()


def _detected(processes: Processes) -> Processes:
    """Fill what is missing from the scheduler's environment, as ``jax.distributed.initialize`` would."""
    try:  # JAX's own detection (SLURM, Open MPI, ...); private, so a missing one only skips this
        from jax._src.clusters import ClusterEnv

        coordinator, num, rank, _ = ClusterEnv.auto_detect_unset_distributed_params(
            processes.coordinator, processes.num_processes, processes.process_id, None, None, int(processes.timeout)
        )
    except (ImportError, AttributeError, KeyError, ValueError, TypeError):
        return processes
    return dataclasses.replace(processes, coordinator=coordinator, num_processes=num, process_id=rank)


def distributed_settings(args: argparse.Namespace) -> Processes | None:
    """The process options checked (ValueError naming the option), or None for one process."""
    given = {name: getattr(args, name, None) for name in _OPTIONS}
    timeout = args.distributed_timeout
    if not (isinstance(timeout, float | int) and math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"--distributed-timeout must be a finite number of seconds > 0, got {timeout!r}")
    if not args.distributed and all(value is None for value in given.values()):
        slurm_tasks = os.environ.get("SLURM_NTASKS")
        if os.environ.get("SLURM_PROCID") is not None and slurm_tasks not in (None, "1"):
            print(f"{PROG}: note: SLURM started {slurm_tasks} tasks; without --distributed (or --coordinator, "
                  "--num-processes, --process-id) each runs the whole sweep by itself", file=sys.stderr)  # fmt: skip
        return None
    if getattr(args, "stick_slip_map", False):
        raise ValueError(
            "--coordinator, --num-processes, --process-id and --distributed run the (V, tau) sweep over several "
            "processes, not --stick-slip-map"
        )
    if given["num_processes"] is not None and given["num_processes"] < 1:
        raise ValueError(f"--num-processes must be an integer >= 1, got {given['num_processes']}")
    coordinator = given["coordinator"]
    if coordinator is not None:
        coordinator = _check_coordinator(coordinator, "--coordinator")
    elif os.environ.get("JAX_COORDINATOR_ADDRESS"):
        coordinator = _check_coordinator(os.environ["JAX_COORDINATOR_ADDRESS"], "JAX_COORDINATOR_ADDRESS")
    processes = Processes(coordinator, given["num_processes"], given["process_id"], float(timeout))
    if args.distributed:
        processes = _detected(processes)
    for name, option in zip(_OPTIONS, ("--coordinator", "--num-processes", "--process-id"), strict=True):
        if getattr(processes, name) is None:
            raise ValueError(
                f"{option} is needed to run over several processes (give --coordinator HOST:PORT, --num-processes N "
                "and --process-id I, or --distributed under SLURM's srun)"
            )
    if not 0 <= processes.process_id < processes.num_processes:
        raise ValueError(
            f"--process-id must be in [0, {processes.num_processes - 1}] (--num-processes {processes.num_processes}), "
            f"got {processes.process_id}"
        )
    if processes.num_processes == 1:
        return None  # one process: nothing to join
    return processes


def _reachable(coordinator: str) -> bool:
    host, _, port = coordinator.rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=2):
            return True
    except OSError:
        return False


def _give_up(processes: Processes) -> None:
    """The watchdog's end: one message, exit 2 (the main thread is blocked inside JAX's C++ client)."""
    if processes.process_id != 0 and not _reachable(processes.coordinator):
        why = (
            f"nothing answers at {processes.coordinator}: is process 0 running there, and is the address reachable "
            "from this host?"
        )
    else:
        why = f"not all {processes.num_processes} processes joined (is every one started, with the same --coordinator?)"
    print(
        f"{PROG}: error: {processes.describe()}: could not join within --distributed-timeout "
        f"{processes.timeout:g} s: {why}",
        file=sys.stderr,
        flush=True,
    )
    os._exit(2)


def join_processes(processes: Processes | None, args: argparse.Namespace) -> int | None:
    """``jax.distributed.initialize`` for ``processes`` (nothing for None): None once joined, else
    the exit status after a message. A process that cannot join within the timeout exits 2 itself."""
    if processes is None:
        return None
    import jax

    try:  # CPU collectives (the gather): gloo, where this JAX's default is none
        if jax.config.jax_cpu_collectives_implementation in (None, "none"):
            jax.config.update("jax_cpu_collectives_implementation", "gloo")
    except AttributeError:
        pass
    watchdog = threading.Timer(processes.timeout, _give_up, args=(processes,))
    watchdog.daemon = True
    watchdog.start()
    try:
        jax.distributed.initialize(
            coordinator_address=processes.coordinator,
            num_processes=processes.num_processes,
            process_id=processes.process_id,
            # JAX's own limit also bounds each later rendezvous (the gather's first, after each
            # process compiled on its own): keep its default unless the user asked for more.
            initialization_timeout=max(300, math.ceil(processes.timeout)),
        )
    except (RuntimeError, ValueError) as error:
        print(f"{PROG}: error: {processes.describe()}: could not join ({error})", file=sys.stderr)
        return 2
    finally:
        watchdog.cancel()
    _quiet_stdout(keep=processes.process_id == 0)
    if processes.process_id != 0:  # process 0 reports; the others compute their share only
        args.plot = None
    return None


def _quiet_stdout(keep: bool) -> None:
    """Send what the runtime's C++ prints on stdout (gloo's "Rank 0 is connected to 1 peer ranks") to stderr, so that
    stdout carries only peeljax's report (one JSON object with --json); keep that report only in process 0."""
    sys.stdout.flush()
    report = os.dup(1)
    os.dup2(2, 1)  # file descriptor 1, which C++ writes to, is now stderr
    sys.stdout = os.fdopen(report, "w") if keep else open(os.devnull, "w")  # noqa: SIM115 (the process's life)
    if not keep:
        os.close(report)
