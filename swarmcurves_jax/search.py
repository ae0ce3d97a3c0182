"""The search stage: every swarm of every curve of a call, as one compiled program.

:func:`swarm_program` runs a chunk of PSO iterations (:mod:`swarmcurves_jax.pso`) for every
(degree, count) swarm of every curve, each particle scored by :mod:`.objective`, from each
swarm's random stream (:mod:`.draws`: its curve's key, its degree and its count alone).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from . import pso
from .fitness import kept
from .objective import (
    CPU_COMPILER_OPTIONS,
    by_degree,
    distances,
    excursion_term,
    foot_starts,
    masked_mean,
    over_curves,
    paired,
    search_apart,
)

__all__ = ["SWARM_COMPILER_OPTIONS", "swarm_program"]


#: The swarm program's: also ``min``/``max`` (and so ``clip``) as single instructions,
#: not NaN-propagating, which on x86 costs a compare and a blend more each (measured:
#: W1's fitness 12 % less CPU time, its search has four per pair).  Its values are finite
#: by construction (positions in their box, validated points, weights ``exp`` of bounded
#: logs), and a non-finite fitness is caught by ``isfinite`` (:func:`pso.update`).
SWARM_COMPILER_OPTIONS = CPU_COMPILER_OPTIONS | {"xla_cpu_enable_fast_min_max": True}


@functools.partial(
    jax.jit,
    static_argnames=(
        "space",
        "num_steps",
        "seeded",
        "groups",
        "search_every",
        "mesh",
        "batch",
    ),
    compiler_options=SWARM_COMPILER_OPTIONS,
)
def swarm_program(
    keys,
    draws,
    state,
    feet,
    first,
    boxes,
    seeds,
    points,
    mask,
    polyline,
    shared,
    *,
    space,
    num_steps,
    seeded,
    groups,
    search_every=1,
    mesh=None,
    batch=1,
):
    """Run ``num_steps`` PSO steps of every swarm of every curve; swarms whose ``step`` is 0
    start fresh.  Per curve (leading axis): ``keys`` and ``draws``, each swarm's run key
    data and initial draws (:func:`~swarmcurves_jax.draws.initial_draws`), ``state``, ``feet`` (the
    last search's starts, (swarms, P, N) floats; ``()`` when ``search_every`` is 1),
    ``boxes``, ``seeds``, ``points`` (padded to a bucket length), ``mask`` (1 on real
    points) and their ``polyline`` (:func:`~swarmcurves_jax.excursions.data_segments`);
    ``shared``: ``(pairs, params, bases, tol, max_steps)``; ``first``: the
    iteration this chunk starts at (the searches fall on multiples of ``search_every``).
    """

    def one_curve(shared, key_data, draws, state, feet, boxes, seeds, points, mask, polyline):
        (pairs, params, bases, tol, max_steps), first = shared
        count = jnp.sum(mask)

        def start(draw, state, box, seed):
            """The swarm's state, fresh where it has not started."""
            fresh = pso.init_from_uniforms(draw, box, seed)
            return jax.tree_util.tree_map(
                lambda a, b: jnp.where(state.step == 0, a, b), fresh, state
            )

        state = jax.vmap(start)(draws, state, boxes, seeds if seeded else None)
        run_keys = jax.random.wrap_key_data(key_data)

        def group_fitness(pair, positions, feet, basis, k, search):
            """The group's fitness (P,) and feet.  A polygon's search is its exact distance,
            run inside each evaluation (no Newton steps).  Otherwise the search runs in a
            branch of its own (every ``search_every`` iterations, or every iteration where
            :func:`~swarmcurves_jax.objective.search_apart`), so that its result is stored
            once, not recomputed by each reader (XLA:CPU fuses cheap producers into each);
            else it is fused, behind a barrier.  Its feet also give the order in which the
            curve passes the points (:func:`~swarmcurves_jax.excursions.runs_back`)."""

            def mean(q, foot, parts=1):  # a bucket length is a multiple of 16: 2 parts fit
                def at(cut):
                    found = None if foot is None else foot[cut]
                    return distances(q, basis, points[cut], space, pair, k, found, search_every > 1)

                # read twice, so behind the barrier: else XLA:CPU fuses the mean into each
                # reader, rounding it one way in one program and another in another
                near = kept(masked_mean(at, mask, count, parts))
                order = None if foot is None else (foot, mask, count, near, polyline.scatter)
                return near + excursion_term(q, basis, polyline, space, pair, k, order)

            if k == 1:
                return jax.vmap(lambda q: mean(q, None))(positions), feet
            if search_every == 1 and not search_apart(space):

                def fused(q):
                    return mean(q, kept(foot_starts(q, basis, points, space, pair, k)))

                return jax.vmap(fused)(positions), feet

            def searched():
                return jax.vmap(lambda q: foot_starts(q, basis, points, space, pair, k))(positions)

            stored = (
                feet if search_every > 1 else jnp.zeros((len(positions), *mask.shape), points.dtype)
            )
            found = jax.lax.cond(search, searched, lambda: stored)
            read = functools.partial(mean, parts=2 if paired(space, k) else 1)
            return jax.vmap(read)(positions, found), found if search_every > 1 else feet

        def fitness(positions, feet, iteration):  # (swarms, P, dim) -> (swarms, P), feet
            # With search_every 1 every iteration searches, by `iteration >= 0`: a constant
            # true would dissolve the branch (and fuse the search again), and XLA cannot
            # fold this one (`first` is a runtime value).
            search = iteration % search_every == 0 if search_every > 1 else iteration >= 0
            search = functools.partial(group_fitness, search=search)
            return by_degree(search, groups, bases, pairs, positions, feet)

        (state, feet), info = pso.run_swarms(
            run_keys, state, params, boxes, fitness, num_steps, tol, max_steps, feet, first
        )
        return state, feet, jax.tree_util.tree_map(lambda a: a.T, info)  # (swarms, steps)

    per_curve = (keys, draws, state, feet, boxes, seeds, points, mask, polyline)
    return over_curves(one_curve, per_curve, (shared, first), mesh, batch)
