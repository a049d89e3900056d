"""The devices a sweep runs on: the batch mesh, placing lanes, gathering results (the shared
utilities of :mod:`peeljax._devices`, which a batch of orbits uses too)."""

from __future__ import annotations

from .._devices import batch_mesh, deal, default_lane_batch, over_devices, put_lanes, to_host

__all__ = ["batch_mesh", "deal", "default_lane_batch", "over_devices", "put_lanes", "to_host"]
