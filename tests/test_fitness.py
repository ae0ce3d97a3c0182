"""The swarm's cheap fitness agrees with the true projection."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmcurves_jax import design_matrix, make_knots, normalise
from swarmcurves_jax.fitness import SampleBasis, make_sample_basis, nearest_sample, point_distances
from swarmcurves_jax.projection import project_points


def as_jax(basis):
    return SampleBasis(*(jnp.asarray(x, jnp.float32) for x in basis))


# Sample counts around the unrolled block of 128 and its scan; each count compiles once.
@given(st.integers(0, 1000), st.sampled_from([1, 2, 7, 48, 127, 128, 129, 255, 300]))
def test_nearest_sample_is_argmin_of_segment_distance(seed, num):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (40, 2)).astype(np.float32)
    s = rng.uniform(-1, 1, (num, 2)).astype(np.float32)
    tang = rng.uniform(-0.05, 0.05, (num, 2)).astype(np.float32)
    j = np.asarray(nearest_sample(jnp.asarray(pts), jnp.asarray(s), jnp.asarray(tang)))
    diff = pts[:, None] - s[None]
    along = np.sum(diff * tang[None], -1)
    sc = np.clip(along / np.sum(tang**2, -1)[None], -1, 1)
    d2 = np.sum((diff - sc[..., None] * tang[None]) ** 2, -1)
    # the packed search may break near-ties differently: compare distances, not indices
    np.testing.assert_allclose(d2[np.arange(len(pts)), j], d2.min(axis=1), rtol=1e-4, atol=1e-12)


@pytest.mark.parametrize("closed,n", [(False, 6), (True, 8)])
def test_fitness_near_exact_on_and_off_the_curve(closed, n):
    rng = np.random.default_rng(5)
    ctrl = rng.uniform(-1, 1, (n, 2))
    t = make_knots(n, 3, closed)
    x = design_matrix(np.linspace(0, 1, 200, endpoint=not closed), t, 3, closed=closed) @ ctrl
    xn, c, s = normalise(x)
    cn = (ctrl - c) / s
    basis = as_jax(make_sample_basis(n, 3, closed, 64))
    for eps, tol in [(0.0, 2e-4), (1e-2, 0.2), (1e-1, 0.05)]:
        trial = cn + eps * rng.standard_normal(cn.shape)
        est = np.asarray(
            point_distances(
                jnp.asarray(trial, jnp.float32), None, basis, jnp.asarray(xn, jnp.float32)
            )
        )
        exact, _ = project_points(xn, trial, np.ones(n), t, 3, closed)
        # the estimate never undercuts the true distance by more than float32 noise
        assert np.all(est >= exact - 1e-5)
        if eps == 0:
            assert est.mean() <= tol
        else:
            assert abs(est.mean() - exact.mean()) <= tol * exact.mean()
