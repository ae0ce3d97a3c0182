"""Each swarm's random stream: its run key and its initial positions' draws.

A swarm's key is its curve's key folded with its degree and control-point count, so its
stream depends neither on the other swarms nor on the other curves of the call; the key is
then split into the key of its initial draws and the key its run hashes each step's draws
from (:func:`~swarmcurves_jax.pso.uniforms`).

These are ``jax.random``'s ``fold_in``, ``split`` and ``uniform`` under its default
threefry2x32 keys, computed here with NumPy on the host, bit for bit: as an XLA program of
their own they cost every new shape of call about half a CPU-second of compilation, for
work done once per call that NumPy does in milliseconds.  Under another key implementation
(``jax_default_prng_impl``) or JAX's older threefry stream (``jax_threefry_partitionable``
off) the same functions run as the jitted :func:`jax_draws` instead.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

__all__ = ["initial_draws", "jax_draws", "threefry2x32"]

#: Threefry-2x32's rotation distances, alternating every four rounds (20 rounds in all).
_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
#: Threefry's key-schedule parity constant.
_PARITY = np.uint32(0x1BD11BDA)


def initial_draws(key_data, pairs, *, num_particles: int, size: int, dtype):
    """Every swarm's run key data and its initial positions' U[0, 1) draws, per curve:
    ``(curves, swarms, 2)`` uint32 and ``(curves, swarms, num_particles, size)`` in ``dtype``,
    from ``key_data`` (curves, 2) and ``pairs`` (swarms, 2): each swarm's (degree, count)."""
    if not _host_threefry():
        return jax.device_get(
            jax_draws(key_data, pairs, num_particles=num_particles, size=size, dtype=dtype)
        )
    keys = np.asarray(key_data, np.uint32)[:, None, :]  # (curves, 1, 2)
    pairs = np.asarray(pairs).astype(np.uint32)
    keys = _fold_in(_fold_in(keys, pairs[:, 0]), pairs[:, 1])  # (curves, swarms, 2)
    # split in two: JAX's key i is the key hashed at the counter (0, i), as fold_in hashes
    init_keys, run_keys = (_fold_in(keys, np.full(keys.shape[:-1], i, np.uint32)) for i in (0, 1))
    return run_keys, _uniform(init_keys, (num_particles, size), np.dtype(dtype))


def _host_threefry() -> bool:
    return (
        jax.config.jax_default_prng_impl == "threefry2x32"
        and jax.config.jax_threefry_partitionable
    )


def threefry2x32(k0, k1, x0, x1):
    """The Threefry-2x32 hash (20 rounds) of the counters ``(x0, x1)`` under the key words
    ``(k0, k1)``: uint32 arrays, broadcast together; the two output words."""
    ks = (k0, k1, k0 ^ k1 ^ _PARITY)
    x0, x1 = x0 + ks[0], x1 + ks[1]
    for block in range(5):
        for r in _ROTATIONS[block % 2]:
            x0 = x0 + x1
            x1 = x0 ^ ((x1 << np.uint32(r)) | (x1 >> np.uint32(32 - r)))
        x0 = x0 + ks[(block + 1) % 3]
        x1 = x1 + ks[(block + 2) % 3] + np.uint32(block + 1)
    return x0, x1


def _fold_in(keys, data):
    """``jax.random.fold_in`` of ``keys`` (..., 2) with uint32 ``data``, broadcast: the key
    hashed at the counter ``(0, data)``."""
    x0, x1 = threefry2x32(keys[..., 0], keys[..., 1], np.zeros_like(data), data)
    return np.stack([x0, x1], -1)


def _uniform(keys, shape: tuple, dtype: np.dtype):
    """``jax.random.uniform(key, shape, dtype)`` for each of ``keys`` (..., 2): random bits
    at the counters ``0, 1, ...`` (row-major), their top mantissa bits under the exponent of
    1.0, less 1.0."""
    count = int(np.prod(shape))
    if count >= 2**32:
        raise ValueError(f"initial draws of {count} values per swarm: at most 2**32 - 1")
    x0, x1 = threefry2x32(
        keys[..., :1], keys[..., 1:], np.zeros(count, np.uint32), np.arange(count, dtype=np.uint32)
    )
    finfo = np.finfo(dtype)
    if finfo.bits == 32:
        bits, uint = x0 ^ x1, np.uint32
    elif finfo.bits == 64:
        bits, uint = (x0.astype(np.uint64) << np.uint64(32)) | x1.astype(np.uint64), np.uint64
    else:
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    one = np.array(1.0, dtype).view(uint)
    floats = ((bits >> uint(finfo.bits - finfo.nmant)) | one).view(dtype) - dtype.type(1.0)
    return floats.reshape(*keys.shape[:-1], *shape)


@functools.partial(
    jax.jit,
    static_argnames=("num_particles", "size", "dtype"),
    compiler_options={"xla_backend_optimization_level": 1},
)
def jax_draws(key_data, pairs, *, num_particles, size, dtype):
    """:func:`initial_draws` by ``jax.random`` itself, for any key implementation: the
    reference the host's functions equal under threefry (integer hashing and exact
    conversions, so LLVM's level 1 gives the same bits)."""

    def one(key_data, pair):
        key = jax.random.fold_in(
            jax.random.fold_in(jax.random.wrap_key_data(key_data), pair[0]), pair[1]
        )
        init_key, run_key = jax.random.split(key)
        u = jax.random.uniform(init_key, (num_particles, size), dtype=dtype)
        return jax.random.key_data(run_key), u

    return jax.vmap(jax.vmap(one, (None, 0)), (0, None))(key_data, pairs)
