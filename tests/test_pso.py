"""The swarm as pure functions: it optimises, it is deterministic, chunking changes nothing."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from swarmcurves_jax import pso


def box(dim, lo=-5.0, hi=5.0):
    return pso.Box(
        jnp.full(dim, lo),
        jnp.full(dim, hi),
        jnp.full(dim, -jnp.inf),
        jnp.full(dim, jnp.inf),
        jnp.ones(dim),
    )


def sphere(q):
    return jnp.sum((q - 1.5) ** 2, axis=-1)


def rosenbrock(q):
    return jnp.sum(100 * (q[:, 1:] - q[:, :-1] ** 2) ** 2 + (1 - q[:, :-1]) ** 2, axis=-1)


def solve(fn, dim, steps, key=0, params=None):
    params = params or pso.default_params()
    k = jax.random.key(key)
    state = pso.init(k, box(dim), 32)
    return pso.run(k, state, params, box(dim), fn, steps)


def test_init_is_init_from_its_uniform_draws():
    k, b = jax.random.key(4), box(5)
    seed = jnp.arange(5.0)
    u = jax.random.uniform(k, (16, 5))
    for s in (None, seed):
        want = pso.init(k, b, 16, s)
        got = pso.init_from_uniforms(u, b, s)
        for x, y in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
            np.testing.assert_array_equal(x, y)
    lo, hi = np.asarray(b.init_lower), np.asarray(b.init_upper)
    pos = np.asarray(pso.init_from_uniforms(u, b).position)
    np.testing.assert_allclose(pos, lo + np.asarray(u) * (hi - lo), rtol=1e-6)


def test_converges_on_sphere_and_rosenbrock():
    state, info = solve(sphere, 4, 600)
    np.testing.assert_allclose(state.best_position, 1.5, atol=1e-3)
    state, _ = solve(rosenbrock, 2, 1500)
    np.testing.assert_allclose(state.best_position, 1.0, atol=3e-2)
    assert np.all(np.diff(np.asarray(info.best_fitness)) <= 0)  # best ever never worsens


def test_run_swarms_equals_each_swarm_run_alone():
    """Swarms stepped in one loop, with one fitness call for all of them (a different
    function per swarm), end exactly where each ends alone, also when capped."""
    fns = [sphere, rosenbrock, lambda q: jnp.sum(jnp.abs(q), axis=-1)]
    keys = [jax.random.key(i) for i in (1, 2, 3)]
    boxes = [box(3), box(3, -2.0, 2.0), box(3, 0.0, 1.0)]
    params = pso.default_params()
    stack = lambda *xs: jax.tree_util.tree_map(lambda *a: jnp.stack(a), *xs)  # noqa: E731
    states = stack(*(pso.init(k, b, 16) for k, b in zip(keys, boxes)))

    def fitness(positions):  # (3, 16, 3) -> (3, 16)
        return jnp.stack([fn(q) for fn, q in zip(fns, positions)])

    for max_steps in (150, 40):
        together, info = pso.run_swarms(
            jnp.stack(keys), states, params, stack(*boxes), fitness, 150, max_steps=max_steps
        )
        assert info.best_fitness.shape == (150, 3)
        for i, (k, b, fn) in enumerate(zip(keys, boxes, fns)):
            state, alone = pso.run(k, pso.init(k, b, 16), params, b, fn, 150, max_steps=max_steps)
            assert int(together.step[i]) == max_steps
            for x, y in zip(state, together):
                np.testing.assert_array_equal(x, y[i])
            np.testing.assert_array_equal(alone.best_fitness, info.best_fitness[:, i])


def test_nan_fitness_counts_as_inf():
    def nan_left(q):
        return jnp.where(q[:, 0] < 0, jnp.nan, sphere(q))

    state, _ = solve(nan_left, 2, 300)
    assert np.isfinite(state.best_fitness) and state.best_position[0] >= 0
    assert not np.any(np.isnan(np.asarray(state.pbest_fitness)))


def test_chunked_equals_one_run_and_same_key_same_result():
    k = jax.random.key(3)
    params = pso.default_params()
    s0 = pso.init(k, box(3), 16)
    whole, _ = pso.run(k, s0, params, box(3), rosenbrock, 300)
    part, _ = pso.run(k, s0, params, box(3), rosenbrock, 120)
    part, _ = pso.run(k, part, params, box(3), rosenbrock, 180)
    for a, b in zip(whole, part):
        np.testing.assert_array_equal(a, b)
    again, _ = pso.run(k, s0, params, box(3), rosenbrock, 300)
    np.testing.assert_array_equal(whole.best_position, again.best_position)


def test_vmapped_swarms_equal_a_loop():
    keys = jax.random.split(jax.random.key(0), 3)
    params = pso.default_params()
    b = box(2)

    def one(key):
        return pso.run(key, pso.init(key, b, 8), params, b, rosenbrock, 100)[0].best_position

    batched = jax.vmap(one)(keys)
    for i in range(3):
        # equal up to float32 fusion order
        np.testing.assert_allclose(batched[i], one(keys[i]), rtol=1e-4, atol=1e-6)


def test_tol_and_max_steps_freeze_the_swarm():
    k = jax.random.key(0)
    b = box(2)
    s0 = pso.init(k, b, 16)
    frozen, _ = pso.run(k, s0, pso.default_params(), b, sphere, 400, tol=1e-2)
    assert frozen.best_fitness <= 1e-2 and frozen.step < 400
    capped, _ = pso.run(k, s0, pso.default_params(), b, sphere, 50, max_steps=20)
    assert int(capped.step) == 20


def test_restart_after_patience():
    params = pso.default_params()._replace(patience=10.0)
    k = jax.random.key(1)
    b = box(2)
    state, info = pso.run(k, pso.init(k, b, 8), params, b, lambda q: jnp.ones(q.shape[0]), 40)
    assert np.asarray(info.restarted).sum() >= 3  # a flat fitness never progresses


def test_uniform_draws_are_uniform_independent_and_deterministic():
    """pso.uniforms (the counter-based hash behind r_l, r_g): U[0, 1), no correlation
    between the two draws of a step, between steps, or between swarms' keys."""
    from scipy import stats

    key = jax.random.key(7)
    draws = np.asarray(pso.uniforms(key, 3, (2, 64, 800), jnp.float32))  # 102,400 numbers
    assert draws.min() >= 0.0 and draws.max() < 1.0
    assert stats.kstest(draws.ravel(), "uniform").pvalue > 1e-3
    assert abs(draws.mean() - 0.5) < 0.005 and abs(draws.var() - 1 / 12) < 0.003
    # about 1/sqrt(51,200) = 0.0044 is chance: 0.02 is over four of those
    r_l, r_g = draws.reshape(2, -1)
    assert abs(np.corrcoef(r_l, r_g)[0, 1]) < 0.02
    later = np.asarray(pso.uniforms(key, 4, (2, 64, 800), jnp.float32)).ravel()
    assert abs(np.corrcoef(draws.ravel(), later)[0, 1]) < 0.02
    other = np.asarray(pso.uniforms(jax.random.key(8), 3, (2, 64, 800), jnp.float32)).ravel()
    assert abs(np.corrcoef(draws.ravel(), other)[0, 1]) < 0.02
    # neighbours in the array are not correlated either (lag-1 along the coordinates)
    flat = draws.ravel()
    assert abs(np.corrcoef(flat[:-1], flat[1:])[0, 1]) < 0.02
    again = np.asarray(pso.uniforms(key, 3, (2, 64, 800), jnp.float32))
    np.testing.assert_array_equal(draws, again)


def test_run_swarms_carries_a_memory_across_steps_and_chunks():
    """A fitness with a memory sees every iteration once, in order, counted from ``first``
    (a run cut into chunks sees the same), and the swarm is the memoryless one's."""
    keys = jnp.stack([jax.random.key(4), jax.random.key(5)])
    boxes = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), box(3))
    states = jax.vmap(lambda k, b: pso.init(k, b, 8))(keys, boxes)
    params = pso.default_params()

    def fitness(positions, memory, iteration):  # memory: (evaluations, sum of iterations)
        return sphere(positions), (memory[0] + 1, memory[1] + iteration)

    start = (jnp.int32(0), jnp.int32(0))
    (whole, memory), info = pso.run_swarms(keys, states, params, boxes, fitness, 150, memory=start)
    assert (int(memory[0]), int(memory[1])) == (150, sum(range(150)))
    plain, plain_info = pso.run_swarms(keys, states, params, boxes, sphere, 150)
    (part, mem), _ = pso.run_swarms(keys, states, params, boxes, fitness, 60, memory=start)
    (part, mem), _ = pso.run_swarms(keys, part, params, boxes, fitness, 90, memory=mem, first=60)
    assert (int(mem[0]), int(mem[1])) == (150, sum(range(150)))
    for a, b, c in zip(whole, plain, part):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    np.testing.assert_array_equal(info.best_fitness, plain_info.best_fitness)


def test_run_swarms_skips_the_steps_past_max_steps():
    """A chunk longer than the steps left runs only those (the fitness is not evaluated
    past ``max_steps``) and ends where a chunk of exactly that length ends; the skipped
    rows of its info repeat the final best."""
    keys = jnp.stack([jax.random.key(2), jax.random.key(3)])
    boxes = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), box(3))
    states = jax.vmap(lambda k, b: pso.init(k, b, 8))(keys, boxes)
    params = pso.default_params()

    def fitness(positions, memory, iteration):
        return sphere(positions), memory + 1

    run = functools.partial(pso.run_swarms, keys, states, params, boxes, fitness)
    (exact, evaluations), info = run(70, memory=jnp.int32(0))
    (long, skipped), long_info = run(100, max_steps=70, memory=jnp.int32(0))
    assert (int(evaluations), int(skipped)) == (70, 70)
    for a, b in zip(exact, long):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(long_info.best_fitness[:70], info.best_fitness)
    np.testing.assert_array_equal(
        long_info.best_fitness[70:], np.broadcast_to(long.best_fitness, (30, 2))
    )
    assert np.isnan(long_info.mean_fitness[70:]).all() and not long_info.restarted[70:].any()
    # Started at 60 of 70, a chunk of 100 runs 10 steps.
    (_, ten), _ = run(100, max_steps=70, memory=jnp.int32(0), first=60)
    assert int(ten) == 10
