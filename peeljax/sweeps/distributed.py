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
"""

from __future__ import annotations

import hashlib
import json

import jax
import numpy as np

from .storage import ChunkStore

__all__ = ["check_same_settings", "is_multiprocess", "open_shared_store"]

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
