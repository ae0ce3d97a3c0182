"""The swarm's fitness: mean point-to-curve distance, computed in JAX without gathers.

Per particle, the curve is sampled a few times per span (:mod:`.span_basis`); each data
point takes the sample whose tangent segment is nearest (:func:`nearest_sample`), which
fixes its span and a start parameter (in 2D, the foot on that segment: a Gauss-Newton
step taken by the search itself, :func:`search_starts`); then a few safeguarded Newton
steps on that span's exact polynomial (allowed one span either way) find the foot point.
The distance is to a true point of the curve, so the fitness never undercuts the true
mean distance; the reported errors are still recomputed on the host
(:mod:`swarmcurves_jax.projection`).  A polygon's samples are its segments, so its search
is its exact distance (:func:`polyline_distances`), with nothing to refine.

Written for XLA:CPU speed, measured on workload W1 (``benchmarks/bench_w1.py``): the
per-point span coefficients come from a chain of ``where`` over the spans rather than a
gather (about 2 ns per gathered element on XLA:CPU, the old fitness's largest cost), and
everything after the search fuses into one loop over the points.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .span_basis import PRECISION, SpanBasis, curve_samples, homogeneous

__all__ = [
    "nearest_sample",
    "nearest_sample_dense",
    "search_starts",
    "starts_on_segment",
    "polyline_distances",
    "foot_samples",
    "dense_starts",
    "point_distances",
    "min_excess2",
    "nearest_segments",
    "excess2_at",
    "first_min_index",
    "NEWTON_STEPS",
]


#: Newton steps from the searched sample's centre: measured on W1's least-squares curves,
#: three bring the mean distance within 1e-5 (relative, median) of the true projection.
#: One fewer where the search starts each point at its foot on the nearest tangent segment
#: (:func:`starts_on_segment`): that start is a Gauss-Newton step the search has already
#: paid for (measured, ``benchmarks/fitness_accuracy.py``: median over-estimate 1.7e-6
#: with it and two steps, 5.4e-6 from the centre with three).
NEWTON_STEPS = 3


#: Segment coordinates per unrolled block of :func:`min_excess2` (16 segments in 2D):
#: its loop runs over the data's segments, hundreds, where the search's runs over tens of
#: curve samples, and unrolling them all costs compile time more than it saves.
#: Measured on W1 (``benchmarks/bench_w1.py``, 2-core AVX-512 EPYC), cold / warm: 192
#: coordinates 9.8 / 2.73 s, 64: 8.2 / 2.70 s, 32: 7.1-7.3 / 2.70-2.76 s, 16: 7.0 /
#: 2.79 s, 8: 6.9 / 2.95 s; the broadcast (M, B) ``min`` it replaced: 8.4 / 4.62 s.
_EXCESS_COORDS = 32


#: Sample coordinates per unrolled block of the search (96 samples in 2D, 64 in 3D).
#: Past about 110 2D or 80 3D samples in one unrolled loop, XLA:CPU's code for the fused
#: loop runs 5-10x slower (measured: a 35-cp cubic's fitness, 128 samples, 5.5-6.1 ms
#: unrolled against 0.6 ms as two blocks of 64); beyond, a ``lax.scan`` runs equal blocks.
_BLOCK_COORDS = 192


def search_blocks(num: int, dim: int, per_block: int = _BLOCK_COORDS) -> tuple[int, int]:
    """(blocks, samples per block) of :func:`nearest_sample` for ``num`` samples in
    ``dim`` dimensions: as few blocks as ``per_block`` coordinates each allows
    (:data:`_BLOCK_COORDS`; :func:`min_excess2`'s segments: :data:`_EXCESS_COORDS`), of
    equal size so that padding stays under one sample per block."""
    blocks = -(-num // max(1, per_block // dim))
    return blocks, -(-num // blocks)


def starts_on_segment(num: int, dim: int) -> bool:
    """Whether the search of ``num`` samples in ``dim`` dimensions also finds each point's
    foot on its nearest tangent segment (:func:`search_starts`): in 2D where the samples
    fit one unrolled block, whose index is carried by a select with room for the foot
    beside it.  Elsewhere the index is packed into the distance's low bits, with no room,
    and Newton takes one step more, from the sample's centre (:data:`NEWTON_STEPS`)."""
    return dim == 2 and search_blocks(num, dim)[0] == 1


def _search(points, samples, tangents) -> tuple[jax.Array, jax.Array | None]:
    """The nearest tangent segment's index (N,) int32 (:func:`nearest_sample`) and, where
    :func:`starts_on_segment`, the point's foot on it, ``s`` in [-1, 1] (N,); else None."""
    num, dim = samples.shape
    num_blocks, size = search_blocks(num, dim)
    bits = max(1, (num_blocks * size - 1).bit_length())  # padded samples' indices too
    best = _min_over_segments(points, samples, tangents, bits)
    if starts_on_segment(num, dim):
        return best
    return jnp.minimum(best & ((1 << bits) - 1), num - 1), None


def nearest_sample(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """Index of the sample whose tangent segment ``samples[m] + s * tangents[m]``,
    ``|s| <= 1``, is nearest to each point: (N,) int32.

    Ranking by the tangent segment rather than the sample point keeps a point on its own
    branch where the curve moves fast and samples are sparse (measured: ranking by
    ``|s|**2 - 2 p.s``, two FMAs a pair, made W1's fitness 20 % faster but its
    over-estimate on random curves with loops 10-40x larger, ``fitness_accuracy.py``).
    Written for XLA:CPU speed:
    ``argmin`` is a variadic reduction the CPU backend does not vectorise (~40x slower),
    and a ``min`` over a broadcast (N, M) array goes to a library kernel that
    materialises it.  So the index is packed into the low mantissa bits of the
    (non-negative) squared distance and the minimum is an unrolled running ``minimum``
    over samples, which fuses into one loop (a ``lax.scan`` over blocks beyond 96 samples
    in 2D, 64 in 3D: :func:`search_blocks`).
    Ties break at a relative precision of ``2**(bits - 24)``; the caller refines anyway.
    The distance comes from the offset to the segment's foot (:func:`_segment_d2`), which
    costs fewer operations than ``|d|**2`` less the part along the tangent and does not
    cancel (measured: the search 10-13 % less CPU time at W1's shapes).
    In 2D, where the samples fit one unrolled block, the index is carried by a ``where``
    beside the distance instead (measured, the search's CPU time: 9 % less at 32 samples,
    5 % at 80, 3 % at 96; W1 1.5 % faster.  In 3D 15-30 % slower at 40 and 64 samples;
    carried through a scan of blocks, 10x slower at 128 samples for degrees 4 and 5), and
    the foot on the segment beside it (:func:`search_starts`).
    """
    return _search(points, samples, tangents)[0]


def search_starts(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """Where each point's Newton steps start, in samples: (N,) float, ``m + 1/2`` for
    sample ``m``'s centre (its tangent segment runs from ``m`` to ``m + 1``).

    Where :func:`starts_on_segment`, the point's foot on its nearest tangent segment,
    ``m + (1 + s) / 2``: the Gauss-Newton step from the sample (the tangents are the
    curve's derivative scaled to half the sample spacing), which the search has computed
    anyway, so Newton takes one step fewer (:data:`NEWTON_STEPS`).  Measured on W1 (warm,
    interleaved in one process): 3.11 against 3.20 s; the search alone 11-15 % more CPU
    time for the foot's select and the slopes' loads.
    """
    return _start(*_search(points, samples, tangents), points.dtype)


def _start(j: jax.Array, s: jax.Array | None, dtype) -> jax.Array:
    """Newton's start in samples from a search's index and foot (None: the centre)."""
    start = j.astype(dtype) + 0.5
    return start if s is None else start + 0.5 * s


def polyline_distances(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """Exact distance (N,) from each point to the nearest segment
    ``samples[m] + s * tangents[m]``, ``|s| <= 1``: a polygon's fitness, whose search
    samples are its segments (:func:`make_span_basis` with degree 1), with no index to
    keep and so nothing to refine after the search."""
    return jnp.sqrt(_min_over_segments(points, samples, tangents, 0) + 1e-30)


def min_excess2(
    points: jax.Array,
    centres: jax.Array,
    halves: jax.Array,
    allowance2: jax.Array,
) -> jax.Array:
    """The smallest ``d**2 - allowance2[m]`` (N,) over the segments
    ``centres[m] + s * halves[m]``, ``|s| <= 1`` (``d``: a point's distance to one): how
    far each curve sample strays beyond the data polyline's allowance
    (:func:`~swarmcurves_jax.excursions.sample_excursions`).

    By the search's fused running minimum over blocks of segments, for the swarm, which
    evaluates it every iteration.  The polish, which evaluates it a few dozen times, finds
    each sample's segment by one broadcast minimum (:func:`nearest_segments`), which
    XLA:CPU materialises but compiles in a fraction of the time (measured on ``fit``'s
    first call on f4: the polish compiled and ran in 6.4 s fused, 3.2 s broadcast)."""
    return _min_over_segments(points, centres, halves, 0, allowance2, _EXCESS_COORDS)


def nearest_segments(points, centres, halves, allowance2) -> jax.Array:
    """Which segment gives each point its smallest ``d**2 - allowance2`` (:func:`min_excess2`):
    (N,) int32, by one broadcast (N, M) minimum (:func:`first_min_index`; quick to compile).

    The polish's search: piecewise constant in the curve, so kept out of every
    differentiation, as the foot points are; the excess is then differentiated at the
    segment found (:func:`excess2_at`), not through the minimum over all of them, whose
    derivative costs a pass over every (sample, segment) pair per free coordinate
    (measured, warm: ``fit(f1, cps=range(4, 26), degrees=[2, 3], iterations=60)`` took
    4.7 s instead of 14.6 s, the same curves)."""
    d2 = _excess2(points[:, None, :], centres[None], halves[None], _slopes(halves)[None])
    return first_min_index(d2 - allowance2[None])


def excess2_at(points, centres, halves, allowance2, segment) -> jax.Array:
    """``d**2 - allowance2`` (N,) of each point to its own ``segment`` (N,) of the
    polyline: the :func:`min_excess2` of each point, where ``segment`` is
    :func:`nearest_segments`' (the same arithmetic, so the same values)."""
    slopes = _slopes(halves)
    d2 = _excess2(points, centres[segment], halves[segment], slopes[segment])
    return d2 - allowance2[segment]


def _excess2(points, centres, halves, slopes):
    """Squared distance from points to segments ``centres + s * halves``, ``|s| <= 1``
    (broadcast over any leading axes; coordinates last)."""
    diff = points - centres
    s = jnp.clip(jnp.sum(diff * slopes, axis=-1), -1.0, 1.0)
    off = diff - s[..., None] * halves
    return jnp.sum(off * off, axis=-1)


def _min_over_segments(
    points, samples, tangents, bits: int, offsets=None, per_block: int = _BLOCK_COORDS
):
    """The smallest squared point-to-segment distance (N,) over the segments, less each
    segment's ``offsets`` where given, in blocks of ``per_block`` coordinates
    (:func:`search_blocks`); with ``bits`` > 0, int32 whose low ``bits`` hold the nearest
    segment's index, and the distance's bits above them; or, where
    :func:`starts_on_segment` (``bits`` > 0), that index and the point's foot ``s`` on the
    segment, (N,) each, carried by selects beside the distance (:func:`nearest_sample`).

    The minimum of the tagged bits is taken as integers: non-negative floats order as
    their bits do, and no denormal is flushed (a float 0 tagged would be one)."""
    num, dim = samples.shape
    num_blocks, size = search_blocks(num, dim, per_block)
    keep = jnp.int32(~((1 << bits) - 1))  # the distance's bits above the tag
    carry = bits > 0 and starts_on_segment(num, dim)
    coords = [points[:, i] for i in range(dim)]

    def block_min(acc, blk):
        # The samples' scalars, broadcast over the points, are unstacked in one operation
        # per coordinate, not indexed one by one: tracing under the swarm's two vmaps costs
        # about 0.2 ms per operation, and the indexing was two thirds of the search's
        # operations.  (Offsets made for the whole block at once, (size, N), were
        # materialised: 3x slower.)
        first, block, tangent, slope, *offset = blk  # the offsets only where given
        shape = (block.shape[0], points.shape[0])
        rows = lambda a: jnp.unstack(jnp.broadcast_to(a[:, None], shape))  # noqa: E731
        sample = [rows(block[:, i]) for i in range(dim)]
        offset = rows(offset[0]) if offset else None
        tangent, slope = (
            [rows(tangent[:, i]) for i in range(dim)],
            [rows(slope[:, i]) for i in range(dim)],
        )
        if carry:  # the indices as values (plus a zero XLA cannot fold: NaN only if the
            # curve is), read in the loop like the samples, not a constant broadcast for
            # each sample (measured: W1 1.6 % faster)
            nan = (block[0, 0] != block[0, 0]).astype(jnp.int32)
            index = rows(jnp.arange(shape[0], dtype=jnp.int32) + nan)
        for m in range(shape[0]):
            diff = [p - c[m] for p, c in zip(coords, sample)]
            d2, s = _segment_d2(diff, [e[m] for e in slope], [e[m] for e in tangent])
            if offset is not None:
                d2 = d2 - offset[m]
            if carry:  # (distance, index, foot), the first of equal distances kept
                if acc is None:
                    acc = d2, jnp.zeros(d2.shape, jnp.int32), s
                else:
                    nearer = d2 < acc[0]
                    acc = (
                        jnp.minimum(acc[0], d2),
                        jnp.where(nearer, index[m], acc[1]),
                        jnp.where(nearer, s, acc[2]),
                    )
                continue
            if bits:  # in float32, whatever the points' precision: the tag is int32
                d2 = jax.lax.bitcast_convert_type(d2.astype(jnp.float32), jnp.int32)
                d2 = (d2 & keep) | (first + m)
            acc = d2 if acc is None else jnp.minimum(acc, d2)
        return acc

    arrays = (samples, tangents, _slopes(tangents)) + (() if offsets is None else (offsets,))
    if num_blocks == 1:
        best = block_min(None, (jnp.int32(0), *arrays))
        return best[1:] if carry else best
    blocks = [_in_blocks(a, num_blocks, size) for a in arrays]
    firsts = jnp.arange(num_blocks, dtype=jnp.int32) * size
    if bits:
        init = jnp.full(points.shape[:1], jnp.iinfo(jnp.int32).max, jnp.int32)
    else:
        init = jnp.full(points.shape[:1], jnp.inf, points.dtype)
    best, _ = jax.lax.scan(lambda a, b: (block_min(a, b), None), init, (firsts, *blocks))
    return best


def _in_blocks(a: jax.Array, num_blocks: int, size: int) -> jax.Array:
    """``a``'s rows as (num_blocks, size, ...), the last row repeated to fill: a repeated
    segment changes no minimum."""
    pad = num_blocks * size - a.shape[0]
    return jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]).reshape(
        num_blocks, size, *a.shape[1:]
    )


def _segment_d2(diff: list, slope: list, tangent: list) -> tuple[jax.Array, jax.Array]:
    """Squared distance (N,) from points to the segment ``sample + s * tangent``,
    ``|s| <= 1``, and the foot's ``s`` (N,), given the points' offsets ``diff`` from the
    sample, the segment's ``slope`` (:func:`_slopes`) and ``tangent``, as D arrays (N,)
    each: from the offset to its foot, so that no cancellation loses a point near the
    segment (unlike ``|d|**2 - along**2``)."""
    s = diff[0] * slope[0]
    for d, e in zip(diff[1:], slope[1:]):
        s = s + d * e
    s = jnp.minimum(1.0, jnp.maximum(-1.0, s))  # jnp.clip's order
    d2 = jnp.square(diff[0] - s * tangent[0])
    for d, e in zip(diff[1:], tangent[1:]):
        d2 = d2 + jnp.square(d - s * e)
    return d2, s


def _slopes(tangents: jax.Array) -> jax.Array:
    """Each tangent segment's ``tangent / |tangent|**2`` (M, D), which maps a point's
    offset to its foot's ``s``; zero for a segment of length 0, whose distance is then the
    point's own to the sample."""
    len2 = jnp.sum(tangents**2, axis=1, keepdims=True)
    return tangents / jnp.where(len2 > 0, len2, 1.0)


def _search_dense(points, samples, tangents) -> tuple[jax.Array, jax.Array]:
    """:func:`_search` as a plain (N, M) minimum (:func:`first_min_index`), the foot's
    ``s`` always given."""
    diff = points[:, None, :] - samples[None, :, :]
    along = jnp.sum(diff * tangents[None], axis=2)
    len2 = jnp.sum(tangents**2, axis=1)[None, :]
    s = jnp.clip(along / jnp.maximum(len2, 1e-30), -1.0, 1.0)
    d2 = jnp.sum(diff**2, axis=2) - s * (2.0 * along - s * len2)
    j = first_min_index(d2)
    return j, jnp.take_along_axis(s, j[:, None], axis=1)[:, 0]


def first_min_index(d2: jax.Array) -> jax.Array:
    """``jnp.argmin(d2, axis=1)`` (int32; the first NaN where a row has one) by two plain
    reductions, the minimum and then the least index that reaches it.  ``argmin`` is one
    reduction of (value, index) pairs, which the elemental emitters the polish compiles
    with (:data:`~swarmcurves_jax.polish.POLISH_COMPILER_OPTIONS`) do not vectorise: its
    searches ran 2x as long.  Needs a minimum that propagates NaN (not XLA:CPU's fast
    ``min``, ``xla_cpu_enable_fast_min_max``)."""
    low = jnp.min(d2, axis=1, keepdims=True)  # NaN where the row has one
    at = jax.lax.broadcasted_iota(jnp.int32, d2.shape, 1)
    return jnp.min(jnp.where((d2 == low) | jnp.isnan(d2), at, d2.shape[1]), axis=1)


def nearest_sample_dense(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """:func:`nearest_sample` as a plain (N, M) minimum: slower to run on XLA:CPU but
    about ten times quicker to compile, for code that searches only a few dozen times.
    Its own broadcast formula: :func:`_segment_d2` vmapped over the samples ranked the
    same but made W1's refinement 2.5x slower (0.54 against 0.22 s, measured)."""
    return _search_dense(points, samples, tangents)[0]


def foot_samples(
    ctrl: jax.Array,
    weights: jax.Array | None,
    basis: SpanBasis,
    points: jax.Array,
    dense: bool = True,
) -> jax.Array:
    """Where each point's Newton steps start (:func:`search_starts`): (N,) float.

    Piecewise constant in the curve, so it is not differentiated: a caller that
    differentiates :func:`point_distances` computes it once and passes it, keeping the
    search out of the differentiated graph; the swarm reuses it for a few iterations.
    ``dense``: with :func:`nearest_sample_dense` (quick to compile; always the foot on the
    segment), else :func:`nearest_sample` (quick to run).
    """
    if not dense:
        return search_starts(points, *curve_samples(ctrl, weights, basis))
    return dense_starts(points, *curve_samples(ctrl, weights, basis))


def dense_starts(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """:func:`search_starts` by :func:`nearest_sample_dense` (always the foot on the
    segment), from samples already made: for a caller that also measures them otherwise."""
    return _start(*_search_dense(points, samples, tangents), points.dtype)


def kept(u: jax.Array) -> jax.Array:
    """``u`` exactly, behind an operation XLA:CPU will not copy into each reader of ``u``
    (:func:`span_and_start`): a search fused into the same loop runs once."""
    return jnp.sqrt(jnp.maximum(u * u, 0.0))


def span_and_start(start: jax.Array, basis: SpanBasis, dtype, barrier: bool = True):
    """Each point's span (int32) and start parameter ``tau`` in it, from its search start
    ``u`` (:func:`search_starts`, in samples).

    ``barrier``: ``sqrt`` first.  XLA:CPU's fusion copies cheap elementwise producers into
    every consumer, so where the search is fused into the same loop, unless an op XLA
    counts as expensive stands between them, every later use of ``u`` recomputes the whole
    search.  ``sqrt(max(u*u, 0))`` is ``u`` exactly (the square root of a correctly
    rounded square is exact in binary floating point; checked for every float32 from 1e-18
    to 8192), and XLA keeps it (it folds ``sqrt(u*u)`` to ``abs``).  Measured without it:
    the fitness 5x slower at W1's shapes under JAX's default compiler options
    (``optimization_barrier`` does not help), a 2D rational swarm 5x slower under ``fit``'s.
    Where ``u`` is stored (a branch's result, an input) nothing can be recomputed, and the
    sqrt only lengthens each point's chain of dependent operations (W1 4 % slower with it).

    The span is sample ``floor(u)``'s, ``floor((floor(u) + 1/2) * (1/per))`` in floats,
    exact below 4096 (checked for every ``per`` in float32): XLA:CPU does not vectorise an
    integer division by a traced ``per`` (it took a quarter of W1's fitness: 5.0 against
    3.7 CPU ms per iteration).  Times the reciprocal, not ``/ per``: XLA rewrites
    ``x / c`` as ``x * (1/c)`` in some programs and not in others, and the sharded and the
    lone fit would differ.  A start at a segment's far end (``u = m + 1``) lies in the
    next sample's span if that begins there: the same point of the curve.
    """
    u = start.astype(dtype)
    if barrier:
        u = kept(u)
    per = basis.per_span.astype(dtype)
    inv = 1.0 / per
    span = jnp.minimum(jnp.floor((jnp.floor(u) + 0.5) * inv), (basis.num_spans - 1).astype(dtype))
    tau = jnp.clip((u - span * per) * inv, 0.0, 1.0)
    return span.astype(jnp.int32), tau


def _power_terms(e: jax.Array, degree, inside: jax.Array):
    """``e**k`` and its first two derivatives (zero where not ``inside``: the jump term is
    clamped off there, its derivatives with it).  ``degree``: the static ``k``, or its
    one-hot (K + 1,) when swarms of several degrees share a vmap."""
    if isinstance(degree, int):
        terms = [(1.0, degree)]  # (coefficient, power)
    else:
        terms = [(degree[p], p) for p in range(1, degree.shape[0])]
    powers = [jnp.ones_like(e)]
    for _ in range(max(p for _, p in terms)):
        powers.append(powers[-1] * e)
    val = sum(c * powers[p] for c, p in terms)
    der = sum(p * c * powers[p - 1] for c, p in terms)
    der2 = sum(p * (p - 1) * c * powers[p - 2] for c, p in terms if p > 1)
    zero = jnp.zeros_like(e)
    return val, jnp.where(inside, der, zero), jnp.where(inside, der2 + zero, zero)


def point_distances(
    ctrl: jax.Array,
    weights: jax.Array | None,
    basis: SpanBasis,
    points: jax.Array,
    foot: jax.Array | None = None,
    degree: int | None = None,
    *,
    barrier: bool = True,
    uniform: bool = False,
    stale: bool = False,
    gather: bool = False,
) -> jax.Array:
    """Distance from every point (N, D) to a point of the curve near its foot: shape (N,);
    differentiable in the control points, weights and (free) knots (used by
    :mod:`swarmcurves_jax.refine`).  ``foot``: where Newton starts, the search's result
    (:func:`foot_samples`), if already known.  ``degree``: the curve's degree if static
    (cheaper: a polygon's search is its exact distance, :func:`polyline_distances`,
    unless ``foot`` is given), else read from ``basis.degree``.  ``barrier``: keep a search
    fused into the same loop from being recomputed per reader of its result; False only
    where ``foot`` is stored, not computed in that loop (:func:`span_and_start`).  The
    same values either way.  ``uniform``: ``basis`` is on uniform knots
    (:func:`make_span_basis`), where a span's bounds are the first span's, the last's or
    (every middle span) the same as both neighbours', so two selects find them, not the
    chain over the spans (2 (spans - 1) selects fewer per point); the same values.
    ``stale``: ``foot`` may be an earlier curve's (``fit``'s ``search_every`` > 1), so
    Newton takes all :data:`NEWTON_STEPS` even from the segment's foot (measured: with two,
    a cubic reusing its search every 8th iteration ended 13 % worse than searching each
    time, ``tests/test_fit.py``).
    """
    if degree == 1 and weights is None and foot is None:  # a polygon: exact at once
        return polyline_distances(points, *curve_samples(ctrl, None, basis))
    u = search_starts(points, *curve_samples(ctrl, weights, basis)) if foot is None else foot
    span, tau = span_and_start(u, basis, points.dtype, barrier)
    coef = jnp.einsum(
        "srn,nc->src", basis.table, homogeneous(ctrl, weights), precision=PRECISION
    )  # (S, K+3, cols)
    if gather:
        sel, lo, hi = _gathered_rows(coef, basis, span)
    else:
        sel, lo, hi = _span_rows(coef, basis, span, tau, uniform)
    curve = _span_curve(sel, basis, degree, weights is not None, points.shape[1])
    on_segment = starts_on_segment(basis.sample_value.shape[-2], points.shape[1])
    steps = 1 if degree == 1 and weights is None else NEWTON_STEPS - (on_segment and not stale)
    return _newton_distances(curve, points, tau, lo, hi, steps)


def _span_rows(coef, basis: SpanBasis, span, tau, uniform: bool):
    """Each point's span coefficients by a chain of selects (no gather): ``rows`` lists of
    ``cols`` arrays (N,), and the span's bounds ``lo``, ``hi`` (N,).  The coefficients are
    unstacked in one operation, not indexed one by one: tracing under the swarm's two
    vmaps costs about 0.2 ms per operation."""
    num_spans, rows, cols = coef.shape
    width = rows * cols
    entries = jnp.unstack(coef.reshape(-1))
    span_lo, span_hi = jnp.unstack(basis.lo), jnp.unstack(basis.hi)

    def span_row(s):  # span s's coefficients (and bounds), broadcast over the points
        row = entries[s * width : (s + 1) * width]
        row = (*row, span_lo[s], span_hi[s]) if not uniform else row
        return [jnp.broadcast_to(e, tau.shape) for e in row]

    chosen = span_row(0)
    for s in range(1, num_spans):
        hit = span == s
        chosen = [jax.lax.select(hit, a, b) for a, b in zip(span_row(s), chosen)]
    if uniform:  # the spans past the last repeat it (make_span_basis)
        lo = jnp.where(span == 0, span_lo[0], span_lo[-1])
        hi = jnp.where(span == basis.num_spans - 1, span_hi[-1], span_hi[0])
        flat = chosen
    else:
        *flat, lo, hi = chosen
    return [flat[r * cols : (r + 1) * cols] for r in range(rows)], lo, hi


def _gathered_rows(coef, basis: SpanBasis, span):
    """:func:`_span_rows` by indexing: the same values in a handful of operations, for
    a caller that evaluates the fitness a few dozen times (the polish), where the chain
    of selects over every span costs more to trace and compile than it saves (measured:
    the polish of ``fit(f1, cps=range(4, 26), degrees=[2, 3])`` traced in 2.4 s instead
    of 4.7 s and compiled in 2.8 s instead of 4.7 s, and ran 12-20 % longer warm)."""
    rows = coef[span]  # (N, K + 3, cols)
    sel = [[rows[:, r, c] for c in range(coef.shape[2])] for r in range(coef.shape[1])]
    return sel, basis.lo[span], basis.hi[span]


def _span_curve(sel, basis: SpanBasis, degree, rational: bool, dim: int):
    """``curve(t, inside_span=False)``: the point, first and second derivatives (lists of
    ``dim`` arrays (N,)) of each point's span polynomial ``sel`` (:func:`_span_rows`),
    extended past either end by the jump terms (one span at a time)."""
    rows, cols = len(sel), len(sel[0])
    top = rows - 3  # the degree K of the table
    after, before = sel[top + 1], sel[top + 2]

    def curve(t, inside_span=False):
        """``inside_span``: ``t`` is known to lie in ``[0, 1]`` (the searched start), where
        the jump terms vanish exactly, so they are left out (measured: 3-4 % of a cubic
        group's fitness at W1's shapes, the same values)."""
        v, d1, d2 = [], [], []
        for c in range(cols):  # Horner with its derivatives, no products with zero
            a, da, dda = sel[top][c], None, None
            for r in range(top - 1, -1, -1):
                if da is not None:
                    dda = 2.0 * da if dda is None else dda * t + 2.0 * da
                da = a if da is None else da * t + a
                a = a * t + sel[r][c]
            zero = jnp.zeros_like(t)
            v.append(a)
            d1.append(zero if da is None else da)
            d2.append(zero if dda is None else dda)
        if degree != 1 and not inside_span:  # past either end (one at a time): the neighbour
            past, inside = t > 1.0, (t > 1.0) | (t < 0.0)
            e = jnp.where(past, t - 1.0, jnp.minimum(t, 0.0))
            pe, dpe, ddpe = _power_terms(e, basis.degree if degree is None else degree, inside)
            for c in range(cols):
                jump = jnp.where(past, after[c], before[c])
                v[c], d1[c], d2[c] = v[c] + jump * pe, d1[c] + jump * dpe, d2[c] + jump * ddpe
        if not rational:
            return v, d1, d2
        w, dw, ddw = v[dim], d1[dim], d2[dim]
        c0 = [v[i] / w for i in range(dim)]
        c1 = [(d1[i] - c0[i] * dw) / w for i in range(dim)]
        c2 = [(d2[i] - 2.0 * c1[i] * dw - c0[i] * ddw) / w for i in range(dim)]
        return c0, c1, c2

    return curve


def _newton_distances(curve, points, tau, lo, hi, steps: int):
    """``steps`` safeguarded Newton steps from ``tau`` inside ``[lo, hi]``, then each
    point's distance to the curve at its foot (or to the start, if Newton went astray)."""
    dim = points.shape[1]
    start = None
    for _ in range(steps):
        c0, c1, c2 = curve(tau, inside_span=start is None)
        q = [c0[i] - points[:, i] for i in range(dim)]
        start = q if start is None else start
        g = sum(q[i] * c1[i] for i in range(dim))
        gauss = sum(c1[i] * c1[i] for i in range(dim))
        # Newton's curvature term only where it shortens the step: where the distance
        # is not convex a Gauss-Newton step, and never more than half a span.
        h = jnp.maximum(gauss + sum(q[i] * c2[i] for i in range(dim)), gauss)
        # tau - clip(step, -1/2, 1/2) clipped to [lo, hi], exactly: tau lies in both, and
        # the bounds come off the chain of dependent operations (they wait for no step).
        low, high = jnp.maximum(lo, tau - 0.5), jnp.minimum(hi, tau + 0.5)
        tau = jnp.clip(tau - g / jnp.maximum(h, 1e-30), low, high)
    # The foot point is optimal, so by the envelope theorem the distance's derivative with
    # respect to the curve is its partial at a fixed foot: no gradient through Newton.
    c0 = curve(jax.lax.stop_gradient(tau))[0]
    q2 = sum((c0[i] - points[:, i]) ** 2 for i in range(dim))
    r2 = sum(x * x for x in start)  # the start sample itself, if Newton went astray
    return jnp.sqrt(jnp.minimum(q2, r2) + 1e-30)  # + a normal float: finite gradient at 0
