"""A sweep over several processes (JAX's distributed runtime): what the processes must agree on.

After ``jax.distributed.initialize`` every process calls :func:`peeljax.sweep` with the same
arguments. The lanes then run on every process's devices (:mod:`.devices`: one mesh over
``jax.devices()``, each process supplying its own shards, results gathered with
``process_allgather``) and only process 0 writes files. Two things must hold before the first
chunk, or the processes would run different collectives and wait on each other until a
timeout:

* every process sweeps the same settings (:func:`check_same_settings`);
* every process skips the same finished chunks of ``out`` (:func:`open_shared_store`):
  process 0 alone creates or checks the chunk folder (several processes creating it at once
  race), tells the others which chunks it found, and the others load those from the file
  system they share.

None of this runs in a one-process sweep (``jax.process_count() == 1``).

Joining comes first: :func:`processes` checks where this process stands among the others
(filling what is not given from the scheduler's environment with ``detect``, as
``jax.distributed.initialize`` would: SLURM's ``srun``, Open MPI, ...), and :func:`join` joins
the runtime, waiting at most ``timeout`` seconds for every process to reach the coordinator
(JAX itself would wait minutes, then abort with a C++ stack trace).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import socket
import sys
import threading
from collections.abc import Callable

import jax
import numpy as np

from .storage import ChunkStore

__all__ = [
    "DEFAULT_TIMEOUT",
    "Processes",
    "check_same_settings",
    "is_multiprocess",
    "join",
    "open_shared_store",
    "processes",
]

DEFAULT_TIMEOUT = 60.0  # seconds every process has to reach the coordinator

# What process 0 found in ``out`` (the first entry of its broadcast).
_OPEN, _FINISHED, _REFUSED = 0, 1, 2


def is_multiprocess() -> bool:
    """Whether JAX's distributed runtime joined this process to others."""
    return jax.process_count() > 1


def _allgather(values: np.ndarray) -> np.ndarray:
    """Every process's ``values`` (int64, same shape everywhere), stacked: (process_count, ...)."""
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(np.asarray(values, np.int64)))


def _digest(settings: dict) -> int:
    text = json.dumps(settings, sort_keys=True, default=str).encode()
    return int.from_bytes(hashlib.sha256(text).digest()[:8], "little", signed=True)


def check_same_settings(settings: dict) -> None:
    """Raise ValueError in every process unless all processes sweep the same settings."""
    digests = _allgather(np.asarray([_digest(settings)]))[:, 0]
    differ = [int(i) for i in np.flatnonzero(digests != digests[0])]
    if differ:
        raise ValueError(
            f"the {len(digests)} processes were given different sweeps: process(es) {differ} differ from "
            "process 0 (V, tau, params, t_final, tolerances, chunk, ...); start every process with the same arguments"
        )


def open_shared_store(store: ChunkStore, n_chunks: int) -> tuple[dict | None, list]:
    """Open ``store`` for every process: (the finished output or None, each chunk's arrays or None).

    Process 0 reads or creates the folder (:meth:`ChunkStore.open`) and broadcasts what it
    found; the others then read the same files. A refusal (other settings, a malformed file)
    is raised in every process; so is a file process 0 found that another cannot read (``out``
    not on a shared file system).
    """
    from jax.experimental import multihost_utils

    rank = jax.process_index()
    merged, chunks, error = None, [None] * n_chunks, None
    found = np.zeros(n_chunks + 1, np.int64)
    if rank == 0:
        try:
            merged = store.finished_output()
            if merged is None:
                store.open()
                chunks = [store.load(i) for i in range(n_chunks)]
                found[1:] = [c is not None for c in chunks]
            else:
                found[0] = _FINISHED
        except (ValueError, OSError) as caught:
            error, found[0] = caught, _REFUSED
    found = np.asarray(multihost_utils.broadcast_one_to_all(found))
    if rank != 0 and found[0] != _REFUSED:
        try:
            if found[0] == _FINISHED:
                merged = store.finished_output()
                if merged is None:
                    raise FileNotFoundError(store.out)
            else:
                chunks = [store.load(i) if found[1 + i] else None for i in range(n_chunks)]
                if any(chunks[i] is None for i in range(n_chunks) if found[1 + i]):
                    raise FileNotFoundError(store.folder)
        except (ValueError, OSError) as caught:
            error = caught
    failed = np.flatnonzero(_allgather(np.asarray([error is not None]))[:, 0])
    if found[0] == _REFUSED:
        if rank == 0:
            raise error
        raise ValueError(f"out={str(store.out)!r}: process 0 refused it (its message says why)")
    if failed.size:
        raise ValueError(
            f"out={str(store.out)!r}: process(es) {failed.tolist()} cannot read the files process 0 found there"
            f"{f' ({error})' if error is not None else ''}; out must be on a file system every process shares"
        )
    return merged, chunks


# ---------------------------------------------------------------------------- joining the runtime
@dataclasses.dataclass(frozen=True)
class Processes:
    """Where this process stands among the others: ``jax.distributed.initialize``'s arguments."""

    coordinator: str
    num_processes: int
    process_id: int
    timeout: float = DEFAULT_TIMEOUT

    def describe(self) -> str:
        return f"process {self.process_id} of {self.num_processes}, coordinator {self.coordinator}"


def _check_coordinator(address: str, source: str) -> str:
    host, colon, port = address.strip().rpartition(":")
    if not colon or not host.strip("[]") or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{source} must be HOST:PORT with a port in [1, 65535], got {address!r}")
    return address.strip()


def _detected(coordinator, num_processes, process_id, timeout) -> tuple:
    """What is not given, from the scheduler's environment, as ``jax.distributed.initialize`` would fill it."""
    try:  # JAX's own detection (SLURM, Open MPI, ...); private, so a missing one only skips this
        from jax._src.clusters import ClusterEnv

        return ClusterEnv.auto_detect_unset_distributed_params(
            coordinator, num_processes, process_id, None, None, int(timeout)
        )[:3]
    except (ImportError, AttributeError, KeyError, ValueError, TypeError):
        return coordinator, num_processes, process_id


def processes(
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    join_timeout: float = DEFAULT_TIMEOUT,
    detect: bool = False,
) -> Processes | None:
    """The processes of a sweep, checked before anything is joined; None for one process (nothing
    given, or ``num_processes`` 1).

    ``coordinator`` (``HOST:PORT`` of process 0; default ``$JAX_COORDINATOR_ADDRESS``),
    ``num_processes`` and ``process_id`` as ``jax.distributed.initialize`` takes them; with
    ``detect`` what is not given comes from the scheduler's environment (SLURM's ``srun``).
    ``join_timeout``: seconds :func:`join` waits for every process to reach the coordinator.
    """
    if not (isinstance(join_timeout, float | int) and math.isfinite(join_timeout) and join_timeout > 0):
        raise ValueError(f"join_timeout must be a finite number of seconds > 0, got {join_timeout!r}")
    if coordinator is None and num_processes is None and process_id is None and not detect:
        return None  # nothing asks for several processes
    if num_processes is not None and num_processes < 1:
        raise ValueError(f"num_processes must be an integer >= 1, got {num_processes}")
    if coordinator is not None:
        coordinator = _check_coordinator(coordinator, "coordinator")
    elif os.environ.get("JAX_COORDINATOR_ADDRESS"):
        coordinator = _check_coordinator(os.environ["JAX_COORDINATOR_ADDRESS"], "JAX_COORDINATOR_ADDRESS")
    if detect:
        coordinator, num_processes, process_id = _detected(coordinator, num_processes, process_id, join_timeout)
    for name, value in (("coordinator", coordinator), ("num_processes", num_processes), ("process_id", process_id)):
        if value is None:
            raise ValueError(
                f"{name} is needed to run over several processes (give coordinator HOST:PORT, num_processes N and "
                "process_id I, or detect them under SLURM's srun)"
            )
    if not 0 <= process_id < num_processes:
        raise ValueError(
            f"process_id must be in [0, {num_processes - 1}] (num_processes {num_processes}), got {process_id}"
        )
    return None if num_processes == 1 else Processes(coordinator, num_processes, process_id, float(join_timeout))


def _reachable(coordinator: str) -> bool:
    host, _, port = coordinator.rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=2):
            return True
    except OSError:
        return False


def _not_joined(processes: Processes) -> str:
    """Why ``processes`` could not join within its timeout, in one line."""
    if processes.process_id != 0 and not _reachable(processes.coordinator):
        why = (
            f"nothing answers at {processes.coordinator}: is process 0 running there, and is the address reachable "
            "from this host?"
        )
    else:
        why = f"not all {processes.num_processes} processes joined (is every one started, with the same coordinator?)"
    return f"{processes.describe()}: could not join within join_timeout={processes.timeout:g} s: {why}"


def _exit_with(message: str) -> None:
    print(f"error: {message}", file=sys.stderr, flush=True)
    os._exit(2)


def join(processes: Processes, on_timeout: Callable[[str], None] = _exit_with) -> None:
    """``jax.distributed.initialize`` for ``processes`` (CPU collectives: gloo, where this JAX has none).

    A process that has not joined within ``processes.timeout`` seconds is ended by
    ``on_timeout(message)`` (the main thread is blocked inside JAX's C++ client: it cannot
    raise); by default the message goes to stderr and the process exits with status 2.
    Raises RuntimeError or ValueError where JAX refuses to join.
    """
    try:
        if jax.config.jax_cpu_collectives_implementation in (None, "none"):
            jax.config.update("jax_cpu_collectives_implementation", "gloo")
    except AttributeError:
        pass
    watchdog = threading.Timer(processes.timeout, lambda: on_timeout(_not_joined(processes)))
    watchdog.daemon = True
    watchdog.start()
    try:
        jax.distributed.initialize(
            coordinator_address=processes.coordinator,
            num_processes=processes.num_processes,
            process_id=processes.process_id,
            # JAX's own limit also bounds each later rendezvous (the gather's first, after each
            # process compiled on its own): keep its default unless more was asked for.
            initialization_timeout=max(300, math.ceil(processes.timeout)),
        )
    finally:
        watchdog.cancel()
