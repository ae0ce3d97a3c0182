"""What the swarm and the polish both minimise, per particle and over swarms and curves.

A particle's objective is the mean distance of the data to its curve
(:mod:`swarmcurves_jax.fitness`) plus how far the curve strays from the data polyline
(:mod:`swarmcurves_jax.excursions`).  Here: those terms read off a flat position
(:class:`~swarmcurves_jax.layout.Layout`), and the maps that run them over the swarms of
each degree and over the curves of a batch, shared by the search and the polish programs.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from .excursions import Polyline, excursion, sample_excursions
from .fitness import dense_starts, foot_samples, nearest_segments, point_distances
from .layout import Layout, geometry
from .span_basis import SpanBasis, curve_samples, float32_sum, make_span_basis

__all__ = [
    "CPU_COMPILER_OPTIONS",
    "distances",
    "foot_starts",
    "excursion_term",
    "polish_search",
    "search_apart",
    "paired",
    "by_degree",
    "masked_mean",
    "over_curves",
    "stack_bases",
]


#: XLA:CPU settings of the swarm program (other backends ignore them), measured on W1
#: (``benchmarks/bench_w1.py``): 512-bit vectors where the CPU has them (the search runs
#: 1.5x faster on AVX-512), and no YNNPACK fusions, which split the fitness into loops
#: that each re-read their inputs (1.5x slower).
CPU_COMPILER_OPTIONS = {
    "xla_cpu_prefer_vector_width": 512,
    "xla_cpu_experimental_ynn_fusion_type": "",
}


def distances(q, basis, points, space, pair, k, foot=None, stale=False, gather=False):
    """Estimated distance of every point to the curve of position ``q``: shape (N,).
    A ``foot`` given here is stored (a branch's result, the dense search's),
    never fused from a search in the same loop, so it needs no barrier; ``stale``: it may
    be an earlier position's (:func:`~swarmcurves_jax.fitness.point_distances`)."""
    uniform = not space.num_knots
    basis = space.basis(q, pair, k, basis)
    return point_distances(
        *geometry(q, space),
        basis,
        points,
        foot,
        degree=k,
        barrier=foot is None,
        uniform=uniform,
        stale=stale,
        gather=gather,
    )


def foot_starts(q, basis, points, space, pair, k):
    """The swarm's search: where each point's Newton steps start on the curve of position
    ``q``, in samples, shape (N,) float (:func:`~swarmcurves_jax.fitness.search_starts`;
    the polish searches by :func:`polish_search`)."""
    basis = space.basis(q, pair, k, basis)
    return foot_samples(*geometry(q, space), basis, points, dense=False)


def excursion_term(q, basis, polyline: Polyline, space, pair, k, order=None, segment=None):
    """How far the curve of position ``q`` strays from the data polyline: the arc-length
    mean excess (:func:`~swarmcurves_jax.excursions.excursion`) plus, given ``order`` (the
    points' feet, mask, count and mean distance, the data's scatter), how far it runs back
    against the data's order (:func:`~swarmcurves_jax.excursions.runs_back`), the
    swarm's; or, given each sample's nearest ``segment`` (:func:`polish_search`), each
    sample's excess, arc length and fold (:func:`~swarmcurves_jax.excursions.sample_folds`),
    the polish's residuals."""
    basis = space.basis(q, pair, k, basis)
    samples, tangents = curve_samples(*geometry(q, space), basis)
    if segment is not None:
        return sample_excursions(samples, tangents, basis, polyline, segment)
    return excursion(samples, tangents, basis, polyline, order, space.closed)


def polish_search(q, basis, points, polyline: Polyline, space, pair, k):
    """The polish's search on the curve of position ``q``, from one sampling of it: where
    each point's Newton steps start (N,) (for :func:`distances`) and the data segment
    each curve sample is measured against (M,) (for :func:`excursion_term`); both
    piecewise constant in ``q``, so kept out of every differentiation."""
    basis = space.basis(q, pair, k, basis)
    samples, tangents = curve_samples(*geometry(q, space), basis)
    return dense_starts(points, samples, tangents), nearest_segments(samples, *polyline.segments)


def search_apart(space: Layout) -> bool:
    """Whether the swarm's search runs in a branch of its own every iteration, its result
    stored and read by the Newton steps: on the CPU, with fixed knots.

    After the search, each point's span selects, Newton steps and divisions form one chain
    of dependent operations, and XLA:CPU's fused loop over the points waits on it (measured
    on W1: leaving one exact ``sqrt`` out of the chain made it 4 % faster, with as many
    instructions).  With the search apart, the chain needs no ``sqrt`` barrier and can run
    two points per loop trip (:func:`paired`).  Measured on a 2-core AVX2 EPYC: W1 (warm,
    interleaved in one process) 3.87 s fused -> 3.63 s apart -> 3.45 s paired; the swarm
    stage of 2D degrees 4-5 (300 iterations) 0.86 -> 0.76 -> 0.71 s; 3D cubics and 3D
    quintics within 4 % either way.  Free knots keep the fused search (each particle's
    basis would be built twice: 1.7x slower paired), and other backends too (a branch per
    iteration there is not measured).
    """
    return jax.default_backend() == "cpu" and not space.num_knots


def paired(space: Layout, k: int) -> bool:
    """Whether the Newton steps run two points per loop trip (the points in two halves):
    where a point's span coefficients, ``(k + 3) x (dim [+ 1 if rational])`` values, are at
    most 16.  Two chains of more spill AVX2's 16 registers: 3D quintics (24 values) ran
    15 % slower paired, a 2D rational cubic (18) 3 %; three or four parts of W1's points
    ran slower than one (4.25 and 4.40 against 3.63 s)."""
    return search_apart(space) and (k + 3) * (space.dim + space.rational) <= 16


def by_degree(fn, groups, bases, *args):
    """``fn(*args_of_one_swarm, basis, k=degree)`` vmapped over the swarms of each degree
    group, concatenated: a group's basis has its own shapes (spans, samples) and its
    degree is static, so its fitness is specialised (a polygon's is a fraction of a
    cubic's).  ``groups``: :func:`~swarmcurves_jax.prepare.degree_groups`; ``bases`` one per group.
    """
    parts = [
        jax.vmap(functools.partial(fn, k=k))(
            *(jax.tree_util.tree_map(lambda a, i=i, j=j: a[i:j], x) for x in args), basis
        )
        for (k, i, j, _), basis in zip(groups, bases, strict=True)
    ]
    return jax.tree_util.tree_map(lambda *p: jnp.concatenate(p), *parts)


def masked_mean(distances, mask, count, parts: int = 1):
    """Mean of ``distances(cut)`` over the real points: the padding (``mask`` 0) adds
    nothing.  The points are cut into ``parts`` equal slices whose distances are summed
    elementwise, so that each loop trip runs ``parts`` independent chains (:func:`paired`).
    The sum is :func:`~swarmcurves_jax.span_basis.float32_sum`.  Times the reciprocal,
    not ``/ count``: see :func:`swarmcurves_jax.fitness.span_and_start`."""
    size = mask.shape[0] // parts
    d = [distances(c) * mask[c] for c in (slice(i * size, (i + 1) * size) for i in range(parts))]
    return float32_sum(sum(d[1:], d[0])) * (1.0 / count)


def over_curves(fn, per_curve, shared, mesh, batch, out_like=None):
    """``fn(shared, *one_curve)`` for every curve along the leading axis of ``per_curve``.

    A loop (``lax.map``), ``batch`` curves vmapped per trip: with ``batch`` 1 every curve
    runs exactly the program a lone fit runs, so results do not depend on the batch (on
    XLA:CPU a vmapped curve axis also makes the work 10-70 % slower).  With a ``mesh`` the
    curves are split over its devices by ``shard_map``, each looping over its own share.
    ``out_like``: one curve's outputs (``jax.ShapeDtypeStruct``); given, one curve at a
    time runs through :func:`_opaque_map`, so that a lone curve runs the very loop body a
    batch's curves run.
    """

    def local(per_curve, shared):
        size = jax.tree_util.tree_leaves(per_curve)[0].shape[0]
        step = min(batch, size)
        if out_like is not None and step == 1:
            return _opaque_map(lambda c: fn(shared, *c), per_curve, size, out_like)
        return jax.lax.map(
            lambda c: fn(shared, *c), per_curve, batch_size=step if step > 1 else None
        )

    if mesh is None:
        return local(per_curve, shared)
    spec = P(mesh.axis_names[0])
    # No collectives inside: each device's loop is independent, so the varying-axis
    # checks (which would want every replicated loop carry cast) are off.
    split = jax.shard_map(local, mesh=mesh, in_specs=(spec, P()), out_specs=spec, check_vma=False)
    return split(per_curve, shared)


def _opaque_map(fn, xs, size: int, out_like):
    """``lax.map(fn, xs)`` whose loop XLA cannot see the length of, over arrays of at
    least two rows (one curve: a copy beside it, never run).  XLA removes a loop of one
    trip and turns a slice of a one-row array into a reshape, and the program it then
    fuses rounds differently: a lone fit's polish differed from the same curve's in a
    batch (6.7e-8 against 8.4e-8 in a near-exact fitness)."""
    if size == 1:
        xs = jax.tree_util.tree_map(lambda a: jnp.concatenate([a, a]), xs)
    rows = max(size, 2)
    out = jax.tree_util.tree_map(lambda s: jnp.zeros((rows, *s.shape), s.dtype), out_like)

    def body(i, out):
        one = fn(jax.tree_util.tree_map(lambda a: a[i], xs))
        return jax.tree_util.tree_map(lambda o, x: o.at[i].set(x), out, one)

    count = jax.lax.optimization_barrier(jnp.int32(size))
    out = jax.lax.fori_loop(0, count, body, out)
    return jax.tree_util.tree_map(lambda o: o[:size], out)


def stack_bases(pairs, closed, num_samples, n_pad, dtype) -> SpanBasis:
    """The precomputed span bases (fixed knots) of swarms, stacked and padded alike;
    read-only, made once per shape (W1's three groups: 10 ms a call)."""
    key = tuple((int(k), int(n)) for k, n in pairs)
    return _stacked_bases(key, bool(closed), int(num_samples), int(n_pad), np.dtype(dtype))


@functools.lru_cache(maxsize=64)
def _stacked_bases(pairs, closed, num_samples, n_pad, dtype) -> SpanBasis:
    spans = max(n if closed else n - k for k, n in pairs)
    top = max(k for k, _ in pairs)
    per = [make_span_basis(n, k, closed, num_samples, n_pad, spans, top) for k, n in pairs]
    stacked = SpanBasis(
        *(
            np.stack(parts).astype(np.int32 if name in ("per_span", "num_spans") else dtype)
            for name, parts in zip(SpanBasis._fields, zip(*per))
        )
    )
    for a in stacked:
        a.setflags(write=False)
    return stacked
