"""The polish stage: every swarm's solution refined locally, as one compiled program.

After the search, :func:`polish_program` runs Levenberg–Marquardt (or L-BFGS,
:mod:`swarmcurves_jax.refine`) from a few starts per swarm on the same objective as the
swarm's, the data's distances and the curve's excursions from the data polyline, and a
fold term (a fold inside the allowance is a local method's shortcut to a lower data error).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from . import refine as local
from .excursions import own_segments
from .layout import Layout
from .objective import (
    CPU_COMPILER_OPTIONS,
    by_degree,
    distances,
    excursion_term,
    over_curves,
    polish_search,
    stack_bases,
)
from .prepare import default_num_samples

__all__ = [
    "POLISH_COMPILER_OPTIONS",
    "Polished",
    "REFINE_SAMPLES_PER_SPAN",
    "REFINE_STARTS",
    "polish_program",
    "polish_bases",
]


#: The refinement's samples per span: it runs a few dozen evaluations, not 2000 x 64,
#: and polishes to the limit of float32 only from starts near each foot point (measured:
#: a perturbed random cubic polishes to 4e-8 with 16, 1.2e-4 with 4).
REFINE_SAMPLES_PER_SPAN = 16

#: Starts refined per swarm: its best, its least-squares seed, its next best particles.
REFINE_STARTS = 4

#: The polish's XLA:CPU settings: the swarm's, with XLA:CPU's elemental emitters instead
#: of its fusion emitters, which cost about 5 ms of compiler time per fused kernel whatever
#: its size (the polish has about 200).  Measured on the polish of ``fit(f4)``
#: (``benchmarks/compile_cost.py``): compiled in 2.6 instead of 3.5 CPU-seconds, run in
#: 0.21 instead of 0.31 s (its searches by :func:`~swarmcurves_jax.fitness.first_min_index`).
#: The swarm keeps the fusion emitters, without which it ran 2.2x slower.  And without
#: XLA's tree reductions, which split every sum over more than 32 elements into a
#: windowed sum and a sum of the windows, kernels of their own: compiled in 0.3-0.5
#: CPU-seconds less and run a third quicker (the sums round otherwise, so the polish
#: lands elsewhere by rounding; the faithfulness figures held, docs/performance.md).
POLISH_COMPILER_OPTIONS = CPU_COMPILER_OPTIONS | {
    "xla_cpu_use_fusion_emitters": False,
    "xla_disable_hlo_passes": "tree_reduction_rewriter",
}


class Polished(NamedTuple):
    """:func:`polish_program`'s outputs, named on the host, each (curves, swarms, ...):
    the reported result (the best hold-out score) and its fitness, the last start's
    result (the polished seed where ``seeded``) and the reported start's last iterate."""

    position: object
    fitness: object
    seed: object
    last: object


@functools.partial(
    jax.jit,
    static_argnames=("space", "method", "seeded", "groups", "mesh", "batch"),
    compiler_options=POLISH_COMPILER_OPTIONS,
)
def polish_program(
    state,
    boxes,
    seeds,
    points,
    mask,
    polyline,
    shared,
    *,
    space,
    method,
    seeded,
    groups,
    mesh=None,
    batch=1,
):
    """Polish every swarm of every curve from ``REFINE_STARTS`` starts; per swarm
    (:class:`Polished`, a plain tuple here), the result with the best hold-out score
    (:data:`swarmcurves_jax.refine.HOLDOUT_EVERY`), its fitness, the last start's result,
    the polished seed where ``seeded`` (the host weighs it too: the hold-out mean, which
    picks the first, does not see a gap), and the first result's start's last iterate
    (the host's fallback where it refuses the first).
    Padded points (``mask`` 0) have zero residuals; ``polyline``: the points' own
    (:func:`~swarmcurves_jax.excursions.data_segments`), at the polish's padding."""

    def one_curve(shared, state, boxes, seeds, points, mask, polyline):
        pairs, bases = shared
        holdout = (jnp.arange(points.shape[0]) % local.HOLDOUT_EVERY == 2) * mask
        count = jnp.sum(mask)

        def one_swarm(pair, state, box, seed, basis, k):
            def residuals(q, found):
                """The points' distances, then each curve sample's excursion weighted by
                its share of the arc (times the point count: their sum per point is the
                swarm's excursion term), then each sample's fold weighted evenly (a fold
                is slow curve, and its share of the arc would hide it)."""
                foot, segment, own = found
                near = distances(q, basis, points, space, pair, k, foot, gather=True) * mask
                excess, arc, fold = excursion_term(
                    q, basis, polyline, space, pair, k, segment=segment
                )
                share = jax.lax.stop_gradient(arc * (count / jnp.maximum(jnp.sum(arc), 1e-30)))
                real = arc > 0
                even = count / jnp.maximum(jnp.sum(real), 1)
                return jnp.concatenate([near, excess * share, fold * even * (own * real)])

            def search(q):
                """Each point's foot, each sample's segment and whether it is its own:
                found once per step, outside the residuals' traces."""
                foot, segment = polish_search(q, basis, points, polyline, space, pair, k)
                return foot, segment, own_segments(segment, foot, mask, space.closed)

            free = box.mask * (box.lower != box.upper)  # pinned ends and padding stay
            others = min(REFINE_STARTS - 1 - int(seeded), state.pbest_fitness.shape[0])
            _, top = jax.lax.top_k(-state.pbest_fitness, others)
            starts = [state.best_position[None], state.pbest_position[top]]
            starts = jnp.concatenate(starts + ([seed[None]] if seeded else []))
            polish = local.levenberg_marquardt if method == "lm" else local.lbfgs
            extra = jnp.zeros(2 * basis.sample_value.shape[-2], mask.dtype)
            problem = local.Problem(
                residuals,
                search,
                free,
                box.lower,
                box.upper,
                jnp.concatenate([holdout, extra]),
                jnp.concatenate([mask, extra]),
                jnp.concatenate([jnp.zeros_like(mask), extra + 1.0]),
                (jnp.arange(free.shape[0]) < space.num_ctrl).astype(free.dtype),
            )
            xs, fs, scores, lasts = jax.vmap(lambda x0: polish(problem, x0))(starts)
            i = jnp.argmin(jnp.where(jnp.isnan(scores), jnp.inf, scores))
            return xs[i], fs[i], xs[-1], lasts[i]

        return by_degree(one_swarm, groups, bases, pairs, state, boxes, seeds)

    per_curve = (state, boxes, seeds, points, mask, polyline)
    # one curve's outputs are shaped alike
    best = (state.best_position, state.best_fitness, state.best_position, state.best_position)
    out_like = tuple(jax.ShapeDtypeStruct(a.shape[1:], a.dtype) for a in best)
    return over_curves(one_curve, per_curve, shared, mesh, batch, out_like)


def polish_bases(pairs, groups, space: Layout, dtype):
    """The polish's span bases per degree group: more samples per span than the search's
    (:data:`REFINE_SAMPLES_PER_SPAN`), read-only and cached like them."""
    return tuple(
        stack_bases(
            pairs[i:j],
            space.closed,
            max(samples, default_num_samples(pairs[i:j], space.closed, REFINE_SAMPLES_PER_SPAN)),
            space.n_pad,
            dtype,
        )
        for _, i, j, samples in groups
    )
