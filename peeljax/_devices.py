"""The devices a batch of lanes runs on: the batch mesh, placing lanes, gathering results.

A sweep (and a batch of orbits) shards its lanes over a one-axis mesh ("batch") of all devices JAX sees (on
a CPU, one per core: see :mod:`peeljax`), deals neighbouring lanes to different devices, and
chooses how many lanes a device runs together under ``vmap`` (error control). After
``jax.distributed.initialize`` the devices are every process's: each supplies its own shards
and gets all results back (:mod:`.distributed` has what the processes must agree on).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["batch_mesh", "deal", "default_lane_batch", "over_devices", "put_lanes", "to_host"]


def batch_mesh(devices) -> jax.sharding.Mesh | None:
    """A 1-D mesh with axis ``"batch"`` over ``devices``; None for a single device."""
    if devices is None or len(devices) == 1:
        return None
    return jax.sharding.Mesh(np.asarray(devices), ("batch",))


def put_lanes(arrays, devices):
    """Shard the batch axis over ``devices`` (a 1-D mesh), or leave on the default device."""
    mesh = batch_mesh(devices)
    if mesh is None:
        return jax.tree_util.tree_map(jnp.asarray, arrays)
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    # make_array_from_callback also works across hosts (jax.distributed): each process holds
    # the whole (small) input and supplies the shards of its own devices.
    return jax.tree_util.tree_map(
        lambda a: jax.make_array_from_callback(a.shape, sharding, lambda index, a=a: a[index]), arrays
    )


def to_host(tree):
    """The (sharded) results as NumPy arrays; across processes (jax.distributed) every process
    gets every lane, by one ``process_allgather`` (gloo on CPUs)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return jax.tree_util.tree_map(np.asarray, multihost_utils.process_allgather(tree, tiled=True))
    return jax.tree_util.tree_map(np.asarray, tree)


def default_lane_batch(devices, chunk: int) -> int:
    """Lanes ``vmap``ped together by error control: 1 on CPUs, the whole chunk on accelerators.

    Measured (``benchmarks/studies/sweep_throughput.py`` (retired: ``benchmarks/studies/README.md``)): on a CPU a ``vmap``ped while loop runs every
    lane until the slowest is done and turns the kept-matrix ``cond`` into a select that
    computes the Jacobian at every step, so one lane at a time is fastest; a GPU's time is set
    by the number of loop iterations, not by the lanes, so it takes them all at once.
    """
    return 1 if devices[0].platform == "cpu" else max(1, chunk // len(devices))


def deal(lanes: np.ndarray, n_devices: int) -> np.ndarray:
    """Deal the lanes to the devices like cards (lane i to device i mod n_devices).

    Sharding gives each device a contiguous block of the batch; dealing spreads neighbouring
    (V, τ), which cost alike, over all devices, so no device gets all the hard ones.
    """
    if n_devices == 1:
        return lanes
    return lanes.reshape(-1, n_devices).T.reshape(-1)


def over_devices(lanes, mesh, shared, batched):
    """``lanes(*shared, *batched)``, with ``shard_map`` over ``mesh`` (axis "batch") if given.

    ``shared`` (pytrees of arrays and static fields) is replicated; ``batched`` is split along
    its leading axis; the result is split the same way.
    """
    if mesh is None:
        return lanes(*shared, *batched)
    P = jax.sharding.PartitionSpec
    arrays, static = eqx.partition(shared, eqx.is_array)

    def per_device(arrays, *batched):
        return lanes(*eqx.combine(arrays, static), *batched)

    sharded = jax.shard_map(
        per_device,
        mesh=mesh,
        in_specs=(P(), *(P("batch") for _ in batched)),
        out_specs=P("batch"),
        check_vma=False,
    )
    return sharded(arrays, *batched)
