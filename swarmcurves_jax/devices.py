"""Where a batch of curves runs: one device, or split over every device JAX can see.

A :class:`Placement` says how the arrays of a batch reach the devices and come back.  The
batch axis (curves) is split over a one-axis ``Mesh`` of the devices; the programs run
``shard_map`` over it (:func:`swarmcurves_jax.objective.over_curves`), so the same call uses one
CPU, several GPUs or, after ``jax.distributed.initialize``, the devices of every host.
Multi-host: every process calls ``fit_many`` with the same inputs; each computes its own
devices' share and all of them return every result.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, SingleDeviceSharding
from jax.sharding import PartitionSpec as P

from .pystack import in_one_chunk

__all__ = ["Placement", "CURVES_AXIS", "cpu_devices", "host_map"]

#: The mesh axis the batch of curves is split along.
CURVES_AXIS = "curves"


def cpu_devices() -> list:
    """This process's CPU devices when the CPU is JAX's default backend, else ``[]``.

    XLA:CPU runs one program on all cores, but several independent programs on as many
    CPU devices use them better (measured on W1's fitness: 2.3 against 2.8 ms per
    iteration on 2 cores), so :func:`swarmcurves_jax.fit` splits its swarms over these
    devices.  JAX makes one CPU device unless told otherwise before it starts:
    ``jax.config.update("jax_num_cpu_devices", os.cpu_count())`` right after ``import jax``.
    """
    if jax.default_backend() != "cpu" or jax.process_count() > 1:
        return []
    return jax.local_devices(backend="cpu")


class Placement(NamedTuple):
    """``mesh``: None (one device) or a one-axis mesh named :data:`CURVES_AXIS`;
    ``batch``: curves vmapped together per trip of a device's loop (1: one at a time);
    ``device``: the one device without a mesh (None: JAX's default)."""

    mesh: Mesh | None = None
    batch: int = 1
    device: jax.Device | None = None

    @classmethod
    def over(cls, devices=None, batch: int = 1) -> Placement:
        """Split over ``devices`` (default: all of them, every host's); one device: no mesh."""
        devices = list(jax.devices() if devices is None else devices)
        if not devices:
            raise ValueError("devices must not be empty")
        if len(devices) == 1 and jax.process_count() == 1:
            return cls(None, batch)
        return cls(Mesh(np.array(devices), (CURVES_AXIS,)), batch)

    @property
    def multiple(self) -> int:
        """The batch is padded to a multiple of this (the devices), so each gets a share."""
        return 1 if self.mesh is None else self.mesh.size

    def curves(self, tree):
        """Host arrays with a leading curve axis, split over the devices."""
        return self._put(tree, P(CURVES_AXIS))

    def shared(self, tree):
        """Host arrays every device needs whole."""
        return self._put(tree, P())

    def abstract(self, shape, dtype) -> jax.ShapeDtypeStruct:
        """What :meth:`curves` makes of a host array of ``shape`` and ``dtype``, without the
        array: enough to trace and lower a program as the real call will (an array put on
        no device in particular is uncommitted: no sharding)."""
        if self.mesh is not None:
            sharding = NamedSharding(self.mesh, P(CURVES_AXIS))
        else:
            sharding = None if self.device is None else SingleDeviceSharding(self.device)
        return jax.ShapeDtypeStruct(shape, dtype, sharding=sharding)

    def _put(self, tree, spec):
        if self.mesh is None:
            return jax.device_put(tree, self.device)
        sharding = NamedSharding(self.mesh, spec)
        # Every process holds the whole host array; each places the parts its devices own.
        return jax.tree_util.tree_map(
            lambda a: jax.make_array_from_callback(
                np.shape(a), sharding, lambda index, a=np.asarray(a): a[index]
            ),
            tree,
        )

    def get(self, tree):
        """Device arrays back to NumPy, whole, on every process."""
        if jax.process_count() > 1:
            return multihost_utils.process_allgather(tree, tiled=True)
        return jax.device_get(tree)


def host_map(fn, items) -> list:
    """``[fn(x) for x in items]``, in order, on a thread per CPU: the true projections of
    every swarm's curves come after a lone fit's swarm program, and their k-d tree queries
    release Python's lock.  Measured on W1 (2 cores, warm): projections 0.18 -> 0.13 s, the
    same curves bit for bit.  The seeds do not use it
    (:func:`~swarmcurves_jax.seeds.seed_positions`): their rounds are many small NumPy
    calls that hold the lock."""
    items = list(items)
    workers = min(len(items), os.cpu_count() or 1)
    if workers < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(in_one_chunk(fn), items))
