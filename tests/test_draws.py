"""The swarms' keys and initial draws, made on the host, are ``jax.random``'s bit for bit."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmcurves_jax import draws

uint32 = st.integers(0, 2**32 - 1)


@settings(max_examples=25, deadline=None)
@given(
    keys=st.lists(st.tuples(uint32, uint32), min_size=1, max_size=3),
    pairs=st.lists(st.tuples(st.integers(1, 5), st.integers(2, 400)), min_size=1, max_size=4),
    num_particles=st.integers(1, 9),
    size=st.integers(1, 11),
)
def test_host_draws_equal_jax_randoms(keys, pairs, num_particles, size):
    key_data, pairs = np.array(keys, np.uint32), np.array(pairs, np.int32)
    shapes = dict(num_particles=num_particles, size=size, dtype=np.float32)
    run_keys, u = draws.initial_draws(key_data, pairs, **shapes)
    want_keys, want_u = jax.device_get(draws.jax_draws(key_data, pairs, **shapes))
    assert run_keys.dtype == np.uint32 and u.dtype == np.float32
    assert u.shape == (len(keys), len(pairs), num_particles, size)
    np.testing.assert_array_equal(run_keys, want_keys)
    np.testing.assert_array_equal(u, want_u)
    assert np.all((u >= 0) & (u < 1))


def test_host_draws_in_float64_equal_jax_randoms():
    key_data = np.array([[0, 7], [2**32 - 1, 12345]], np.uint32)
    pairs = np.array([[3, 10], [1, 4], [5, 30]], np.int32)
    with jax.enable_x64(True):
        got = draws.initial_draws(key_data, pairs, num_particles=6, size=13, dtype=np.float64)
        want = jax.device_get(
            draws.jax_draws(key_data, pairs, num_particles=6, size=13, dtype=np.float64)
        )
    assert got[1].dtype == np.float64
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_the_threefry_hash_matches_its_known_answers():
    """The Threefry-2x32 (20 rounds) known-answer vectors of Salmon et al.'s Random123,
    which ``jax.random``'s own tests check too."""
    cases = [
        ((0, 0), (0, 0), (0x6B200159, 0x99BA4EFE)),
        ((0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF), (0x1CB996FC, 0xBB002BE7)),
        ((0x13198A2E, 0x03707344), (0x243F6A88, 0x85A308D3), (0xC4923A9C, 0x483DF7A0)),
    ]
    for key, count, want in cases:
        k0, k1, x0, x1 = (np.array([v], np.uint32) for v in (*key, *count))
        got = draws.threefry2x32(k0, k1, x0, x1)
        assert (int(got[0][0]), int(got[1][0])) == want


def test_jaxs_older_threefry_stream_draws_through_jax():
    """Under JAX's older threefry stream (``jax_threefry_partitionable`` off) the host's
    functions do not apply: the draws come from ``jax.random`` itself, as host arrays."""
    key_data, pairs = np.array([[1, 2]], np.uint32), np.array([[3, 5]], np.int32)
    shapes = dict(num_particles=4, size=6, dtype=np.float32)
    newer = draws.initial_draws(key_data, pairs, **shapes)
    with jax.threefry_partitionable(False):
        assert not draws._host_threefry()
        older = draws.initial_draws(key_data, pairs, **shapes)
        want = jax.device_get(draws.jax_draws(key_data, pairs, **shapes))
    assert isinstance(older[1], np.ndarray) and older[1].shape == (1, 1, 4, 6)
    np.testing.assert_array_equal(older[1], want[1])
    assert not np.array_equal(older[1], newer[1])  # another stream


def test_draws_refuse_a_dtype_of_another_width():
    with pytest.raises(ValueError, match="dtype must be float32 or float64, got float16"):
        draws.initial_draws(
            np.zeros((1, 2), np.uint32), np.array([[3, 5]], np.int32),
            num_particles=2, size=3, dtype=np.float16,
        )
