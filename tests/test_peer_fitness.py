"""The speed benchmark's peers (``benchmarks/speed.py``) optimise exactly ``fit``'s fitness:
its NumPy port (the NumPy and pyswarms peers) and the same code run in ``jax.numpy``
(evosax's plain-JAX peer) agree with :func:`swarmcurves_jax.fitness.point_distances` on
W1's swarms, so that the peers' times compare like with like."""

import importlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swarmcurves_jax.seeds import least_squares_ctrl
from swarmcurves_jax.fitness import point_distances


@pytest.fixture(scope="module")
def speed():
    with pytest.MonkeyPatch.context() as mp:  # the benchmarks import their siblings
        mp.syspath_prepend(str(Path(__file__).resolve().parents[1] / "benchmarks"))
        yield importlib.import_module("speed")


def _particles(points, k, n, rng, count=16):
    """Positions near the least-squares curve (as the swarm's are) and anywhere in the
    box (as its first ones are), padded to W1's 10 control points."""
    seed = np.zeros((10, 2))
    seed[:n] = least_squares_ctrl(points.astype(np.float64), n, k, False)
    near = seed[None] + rng.normal(0, 0.02, (count, 10, 2))
    wild = rng.uniform(-1, 1, (count, 10, 2))
    return np.concatenate([near, wild]).reshape(2 * count, 20).astype(np.float32)


@pytest.mark.parametrize("where", [0.0, 0.5, 1.0])  # the first, middle and last of a group
def test_peers_compute_fits_fitness(speed, where):
    points, groups, bases = speed.w1_problem()
    rng = np.random.default_rng(int(10 * where))
    data = jnp.asarray(points)
    for (k, i, j, _), basis in zip(groups, bases):
        swarm = round(where * (j - i - 1))
        n = speed.W1_PAIRS[i + swarm][1]
        one = jax.tree_util.tree_map(lambda a: np.asarray(a)[swarm], basis)
        on_device = jax.tree_util.tree_map(jnp.asarray, one)
        q = _particles(points, k, n, rng)

        def kernel(x, k=k, b=on_device):
            return jnp.mean(point_distances(x.reshape(10, 2), None, b, data, None, k))

        def in_jax_numpy(x, b, k=k):
            return speed.numpy_fitness(x, b, data, k, xp=jnp)[0]

        ours = jax.jit(jax.vmap(kernel))(jnp.asarray(q))
        in_numpy, _ = speed.numpy_fitness(q[:, : 2 * n], one, points, k)
        in_jax = jax.jit(in_jax_numpy)(jnp.asarray(q), on_device)
        np.testing.assert_allclose(in_numpy, ours, rtol=1e-4, err_msg=f"NumPy, degree {k}")
        np.testing.assert_allclose(in_jax, ours, rtol=1e-4, err_msg=f"jax.numpy, degree {k}")


def test_report_keeps_the_peers_ratios_against_their_own_w1_run(speed):
    """Rerunning only W1 (``--only w1``) does not put the new time beside the peers' old
    ratios: their table shows the W1 time they were divided by."""
    w1 = dict(warm_s=3.0, cold_s=8.0, evals_per_s=9e5, best_cubic=2.8e-4, iterations=2000)
    peer = {"seconds": 300.0, "scaled_from": 63, "ratio": 100.0}
    report = dict(machine="test", repeats=3, w1=w1, peers={"NumPy (same fitness)": peer})
    report["peers_ours_s"] = 3.0
    row = "| **ours** (`fit`, refine=False) | 3.00 | 1 | warm |"
    assert row in speed.markdown(report)
    report["w1"] = dict(w1, warm_s=3.5)  # a later W1 run alone
    table = speed.markdown(report)
    assert "| warm (min of 3) | 3.50 s |" in table
    assert "| **ours** (`fit`, refine=False) | 3.00 | 1 | warm, the run the peers" in table
    assert "| NumPy (same fitness) | 300.0 | 100.0x |" in table
