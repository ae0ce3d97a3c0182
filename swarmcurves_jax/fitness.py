"""The swarm's fitness: mean point-to-curve distance, computed in JAX without gathers.

Between two knots a B-spline (or the numerator and denominator of a NURBS) is one
polynomial, so each swarm's basis is precomputed as a table: per knot span, the matrix
that maps control points to that span's power coefficients in a local parameter
``tau in [0, 1]``.  Adjacent spans of a degree-``k`` spline differ by a multiple of
``(tau - knot)**k``, so two more rows per span (those jumps) extend a span's polynomial
exactly into both neighbours.

Per particle, the curve is sampled a few times per span; each data point takes the
sample whose tangent segment is nearest (:func:`nearest_sample`), which fixes its span
and a start parameter (in 2D, the foot on that segment: a Gauss-Newton step taken by the
search itself, :func:`search_starts`); then a few safeguarded Newton steps on that span's
exact polynomial (allowed one span either way) find the foot point.  The distance is to
a true point of the curve, so the fitness never undercuts the true mean distance; the reported
errors are still recomputed on the host (:mod:`swarmcurves_jax.projection`).  A polygon's
samples are its segments, so its search is its exact distance
(:func:`polyline_distances`), with nothing to refine.

Written for XLA:CPU speed, measured on workload W1 (``benchmarks/bench_w1.py``): the
per-point span coefficients come from a chain of ``where`` over the spans rather than a
gather (about 2 ns per gathered element on XLA:CPU, the old fitness's largest cost), and
everything after the search fuses into one loop over the points.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .basis import derivative_bases, design_matrices
from .knots import breakpoints, knots_from_widths, make_knots, span_widths

__all__ = [
    "SpanBasis",
    "make_span_basis",
    "free_knot_basis",
    "curve_samples",
    "nearest_sample",
    "nearest_sample_dense",
    "search_starts",
    "starts_on_segment",
    "polyline_distances",
    "foot_samples",
    "point_distances",
    "Polyline",
    "data_segments",
    "sample_excursions",
    "excursion",
    "NEWTON_STEPS",
]

#: The precision of every matrix product here: float32 on every backend.  XLA:GPU's
#: default for a float32 product is TF32 (a 10-bit mantissa), which moved the curve by
#: about 1e-3 of its size, so that the fitness undercut the true distance (measured on an
#: H100: ``tests/test_fitness.py`` failed, W1's cubic ended 2.7x worse); XLA:CPU ignores it.
PRECISION = jax.lax.Precision.HIGHEST


def float32_matmul(a, b, xp=jnp):
    """``a @ b``, in float32 (:data:`PRECISION`) where ``xp`` is ``jax.numpy``."""
    return a @ b if xp is np else jnp.matmul(a, b, precision=PRECISION)


#: Newton steps from the searched sample's centre: measured on W1's least-squares curves,
#: three bring the mean distance within 1e-5 (relative, median) of the true projection.
#: One fewer where the search starts each point at its foot on the nearest tangent segment
#: (:func:`starts_on_segment`): that start is a Gauss-Newton step the search has already
#: paid for (measured, ``benchmarks/fitness_accuracy.py``: median over-estimate 1.7e-6
#: with it and two steps, 5.4e-6 from the centre with three).
NEWTON_STEPS = 3


class SpanBasis(NamedTuple):
    """One swarm's basis as per-span polynomials, padded to ``S`` spans and ``n_pad``
    control points (a leading swarm axis when stacked).

    ``table`` (S, K + 3, n_pad): rows ``0..K`` map control points to the power
    coefficients of span ``s`` in ``tau``; row ``K+1`` to the jump added as
    ``(tau - 1)**k`` past the span's end, row ``K+2`` as ``tau**k`` before its start
    (``K``: the largest degree of the program, ``k`` this swarm's).
    ``lo, hi`` (S,): how far ``tau`` may go (into the neighbours, not past a curve end;
    a polygon stops at its corners).  ``degree`` (K + 1,): one-hot of ``k``.
    ``sample_value, sample_tangent`` (M, n_pad): the search samples (``per_span`` in each
    of the ``num_spans`` spans, the rest repeating the last) and their tangents scaled to
    half the sample spacing.
    """

    table: jax.Array
    lo: jax.Array
    hi: jax.Array
    degree: jax.Array
    sample_value: jax.Array
    sample_tangent: jax.Array
    per_span: jax.Array
    num_spans: jax.Array


def _span_basis(power, widths, num_spans, k: int, closed: bool, num_samples: int, xp):
    """A :class:`SpanBasis` from the power coefficients ``power`` (S, K + 1, n_pad) of
    each span and the spans' ``widths`` (S,); spans past ``num_spans`` repeat the last.
    Written against ``xp`` (NumPy on the host, ``jax.numpy`` for free knots)."""
    size, rows, _ = power.shape
    s = xp.arange(size)
    last = num_spans - 1
    own = xp.minimum(s, last)
    if closed:
        nxt, prv = (own + 1) % num_spans, (own - 1) % num_spans
        has_next = has_prev = s >= 0
    else:
        nxt, prv = xp.minimum(own + 1, last), xp.maximum(own - 1, 0)
        has_next, has_prev = own < last, own > 0
    w = widths[own]
    lead = power[:, k, :]
    jump_next = lead[nxt] * ((w / widths[nxt]) ** k)[:, None] - lead[own]
    jump_prev = lead[prv] * ((w / widths[prv]) ** k)[:, None] - lead[own]
    table = xp.concatenate(
        [
            power[own],
            (jump_next * has_next[:, None])[:, None, :],
            (jump_prev * has_prev[:, None])[:, None, :],
        ],
        axis=1,
    )
    if k == 1:  # a polygon's segments are searched exactly: its corners bound the step
        lo, hi = xp.zeros(size), xp.ones(size)
    else:
        lo = xp.where(has_prev, -widths[prv] / w, 0.0)
        hi = xp.where(has_next, 1.0 + widths[nxt] / w, 1.0)
    # Search samples: `per` in each span at tau = (i + 1/2) / per, as a one-hot matrix
    # over (span, power) so that free knots need no gather either.
    per = num_samples // num_spans
    m = xp.minimum(xp.arange(num_samples), num_spans * per - 1)
    span = m // per
    inv = 1.0 / per  # then products: see _span_and_start
    tau = (m - span * per + 0.5) * inv
    p = xp.arange(rows)[None, :]
    hot = (span[:, None] == s[None, :]).astype(power.dtype)  # (M, S)
    value = hot[:, :, None] * (tau[:, None] ** p)[:, None, :]
    slope = hot[:, :, None] * (p * tau[:, None] ** xp.maximum(p - 1, 0) * 0.5 * inv)[:, None, :]
    flat = power[own].reshape(size * rows, -1)
    return SpanBasis(
        table=table,
        lo=lo,
        hi=hi,
        degree=(p[0] == k).astype(power.dtype),
        sample_value=float32_matmul(value.reshape(num_samples, -1), flat, xp),
        sample_tangent=float32_matmul(slope.reshape(num_samples, -1), flat, xp),
        per_span=xp.asarray(per, dtype=xp.int32),
        num_spans=xp.asarray(num_spans, dtype=xp.int32),
    )


def make_span_basis(
    n: int,
    k: int,
    closed: bool,
    num_samples: int,
    n_pad: int | None = None,
    num_spans_pad: int | None = None,
    max_degree: int | None = None,
) -> SpanBasis:
    """Host-side (NumPy float64) :class:`SpanBasis` on the uniform knots
    (:func:`~swarmcurves_jax.knots.make_knots`), padded to ``n_pad`` control points,
    ``num_spans_pad`` spans and ``max_degree``."""
    n_pad = n if n_pad is None else n_pad
    t = make_knots(n, k, closed)
    breaks = breakpoints(t)
    spans = len(breaks) - 1
    size = spans if num_spans_pad is None else num_spans_pad
    rows = k + 1 if max_degree is None else max_degree + 1
    if num_samples < spans or size < spans or rows < k + 1:
        raise ValueError(
            f"num_samples must be >= the {spans} knot spans of n={n}, degree {k} "
            f"(got {num_samples}); padding must not be smaller than the basis"
        )
    widths = np.diff(breaks)
    power = np.zeros((size, rows, n_pad))
    for nu, b in enumerate(design_matrices(breaks[:-1], t, k, k, closed=closed)):  # span starts
        power[:spans, nu, :n] = b * (widths**nu / math.factorial(nu))[:, None]
    widths = np.r_[widths, np.ones(size - spans)]
    return _span_basis(power, widths, spans, k, closed, num_samples, np)


def free_knot_basis(
    logits: jax.Array,
    num_spans: jax.Array,
    k: int,
    closed: bool,
    num_samples: int,
    n_pad: int,
) -> SpanBasis:
    """:func:`make_span_basis` for free knots, in JAX, differentiable in ``logits``.

    ``logits`` (S_pad,) place the breakpoints (:func:`~swarmcurves_jax.knots.span_widths`);
    ``num_spans`` (traced) is ``n - k`` open, ``n`` closed.  Every span gets the samples a
    uniform span would, so narrow spans stay covered.
    """
    logits = logits[: n_pad if closed else n_pad - k]  # the most spans n_pad columns allow
    widths = span_widths(logits, num_spans, jnp)
    t = knots_from_widths(widths, num_spans, k, closed, jnp)
    size = logits.shape[0]
    own = jnp.minimum(jnp.arange(size), num_spans - 1)
    start = t[own + k]
    rows = []
    for nu, b in enumerate(derivative_bases(start, t, k, k, own + k, jnp)):
        if closed:  # basis function c drives control point c mod n
            cols = jnp.arange(b.shape[1]) % num_spans
            b = float32_matmul(b, (cols[:, None] == jnp.arange(n_pad)[None, :]).astype(b.dtype))
        rows.append(b[:, :n_pad] * (widths[own] ** nu / math.factorial(nu))[:, None])
    safe = jnp.where(jnp.arange(size) < num_spans, widths, 1.0)
    return _span_basis(jnp.stack(rows, axis=1), safe, num_spans, k, closed, num_samples, jnp)


def _homogeneous(ctrl: jax.Array, weights: jax.Array | None) -> jax.Array:
    """Control points as the columns the polynomials act on: ``(w P, w)`` when rational."""
    if weights is None:
        return ctrl
    return jnp.concatenate([ctrl * weights[:, None], weights[:, None]], axis=1)


def curve_samples(ctrl: jax.Array, weights: jax.Array | None, basis: SpanBasis):
    """The search samples (M, D) and their tangent segments' half vectors (M, D)."""
    if weights is None:
        return float32_matmul(basis.sample_value, ctrl), float32_matmul(basis.sample_tangent, ctrl)
    hom = _homogeneous(ctrl, weights)
    a, da = float32_matmul(basis.sample_value, hom), float32_matmul(basis.sample_tangent, hom)
    value = a[:, :-1] / a[:, -1:]
    return value, (da[:, :-1] - value * da[:, -1:]) / a[:, -1:]


#: Sample coordinates per unrolled block of the search (96 samples in 2D, 64 in 3D).
#: Past about 110 2D or 80 3D samples in one unrolled loop, XLA:CPU's code for the fused
#: loop runs 5-10x slower (measured: a 35-cp cubic's fitness, 128 samples, 5.5-6.1 ms
#: unrolled against 0.6 ms as two blocks of 64); beyond, a ``lax.scan`` runs equal blocks.
_BLOCK_COORDS = 192


def search_blocks(num: int, dim: int) -> tuple[int, int]:
    """(blocks, samples per block) of :func:`nearest_sample` for ``num`` samples in
    ``dim`` dimensions: as few blocks as :data:`_BLOCK_COORDS` allows, of equal size so
    that padding stays under one sample per block."""
    blocks = -(-num // max(1, _BLOCK_COORDS // dim))
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


def _min_over_segments(points, samples, tangents, bits: int):
    """The smallest squared point-to-segment distance (N,) over the segments; with
    ``bits`` > 0, int32 whose low ``bits`` hold the nearest segment's index, and the
    distance's bits above them; or, where :func:`starts_on_segment` (``bits`` > 0), that
    index and the point's foot ``s`` on the segment, (N,) each, carried by selects beside
    the distance (:func:`nearest_sample`).

    The minimum of the tagged bits is taken as integers: non-negative floats order as
    their bits do, and no denormal is flushed (a float 0 tagged would be one)."""
    num, dim = samples.shape
    num_blocks, size = search_blocks(num, dim)
    keep = jnp.int32(~((1 << bits) - 1))  # the distance's bits above the tag
    carry = bits > 0 and starts_on_segment(num, dim)
    coords = [points[:, i] for i in range(dim)]

    def block_min(acc, blk):
        # The samples' scalars, broadcast over the points, are unstacked in one operation
        # per coordinate, not indexed one by one: tracing under the swarm's two vmaps costs
        # about 0.2 ms per operation, and the indexing was two thirds of the search's
        # operations.  (Offsets made for the whole block at once, (size, N), were
        # materialised: 3x slower.)
        first, block, tangent, slope = blk
        shape = (block.shape[0], points.shape[0])
        rows = lambda a: jnp.unstack(jnp.broadcast_to(a[:, None], shape))  # noqa: E731
        sample = [rows(block[:, i]) for i in range(dim)]
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

    slopes = _slopes(tangents)
    if num_blocks == 1:
        best = block_min(None, (jnp.int32(0), samples, tangents, slopes))
        return best[1:] if carry else best
    pad = num_blocks * size - num
    blocks = [
        jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]).reshape(
            num_blocks, size, *a.shape[1:]
        )
        for a in (samples, tangents, slopes)
    ]
    firsts = jnp.arange(num_blocks, dtype=jnp.int32) * size
    if bits:
        init = jnp.full(points.shape[:1], jnp.iinfo(jnp.int32).max, jnp.int32)
    else:
        init = jnp.full(points.shape[:1], jnp.inf, points.dtype)
    best, _ = jax.lax.scan(lambda a, b: (block_min(a, b), None), init, (firsts, *blocks))
    return best


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
    """:func:`_search` as a plain (N, M) ``argmin``, the foot's ``s`` always given."""
    diff = points[:, None, :] - samples[None, :, :]
    along = jnp.sum(diff * tangents[None], axis=2)
    len2 = jnp.sum(tangents**2, axis=1)[None, :]
    s = jnp.clip(along / jnp.maximum(len2, 1e-30), -1.0, 1.0)
    d2 = jnp.sum(diff**2, axis=2) - s * (2.0 * along - s * len2)
    j = jnp.argmin(d2, axis=1).astype(jnp.int32)
    return j, jnp.take_along_axis(s, j[:, None], axis=1)[:, 0]


def nearest_sample_dense(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """:func:`nearest_sample` as a plain (N, M) ``argmin``: slower to run on XLA:CPU but
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
    return _start(*_search_dense(points, *curve_samples(ctrl, weights, basis)), points.dtype)


def _span_and_start(start: jax.Array, basis: SpanBasis, dtype, barrier: bool = True):
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
        u = jnp.sqrt(jnp.maximum(u * u, 0.0))
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
) -> jax.Array:
    """Distance from every point (N, D) to a point of the curve near its foot: shape (N,);
    differentiable in the control points, weights and (free) knots (used by
    :mod:`swarmcurves_jax.refine`).  ``foot``: where Newton starts, the search's result
    (:func:`foot_samples`), if already known.  ``degree``: the curve's degree if static
    (cheaper: a polygon's search is its exact distance, :func:`polyline_distances`,
    unless ``foot`` is given), else read from ``basis.degree``.  ``barrier``: keep a search
    fused into the same loop from being recomputed per reader of its result; False only
    where ``foot`` is stored, not computed in that loop (:func:`_span_and_start`).  The
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
    dim = points.shape[1]
    hom = _homogeneous(ctrl, weights)
    u = search_starts(points, *curve_samples(ctrl, weights, basis)) if foot is None else foot
    span, tau = _span_and_start(u, basis, points.dtype, barrier)
    coef = jnp.einsum("srn,nc->src", basis.table, hom, precision=PRECISION)  # (S, K+3, cols)
    num_spans, rows, cols = coef.shape
    # Each point's span rows by a chain of selects (no gather): (rows, cols) arrays (N,)
    # and the bounds.  The coefficients are unstacked in one operation, not indexed one by
    # one: tracing under the swarm's two vmaps costs about 0.2 ms per operation.
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
    sel = [flat[r * cols : (r + 1) * cols] for r in range(rows)]
    top = rows - 3  # the degree K of the table
    after, before = sel[top + 1], sel[top + 2]

    def curve(t, inside_span=False):
        """Curve point, first and second derivatives at ``t``: lists of D arrays (N,).
        ``inside_span``: ``t`` is known to lie in ``[0, 1]`` (the searched start), where
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
        if weights is None:
            return v, d1, d2
        w, dw, ddw = v[dim], d1[dim], d2[dim]
        c0 = [v[i] / w for i in range(dim)]
        c1 = [(d1[i] - c0[i] * dw) / w for i in range(dim)]
        c2 = [(d2[i] - 2.0 * c1[i] * dw - c0[i] * ddw) / w for i in range(dim)]
        return c0, c1, c2

    on_segment = starts_on_segment(basis.sample_value.shape[-2], dim)
    steps = NEWTON_STEPS - (on_segment and not stale)
    start = None
    for _ in range(1 if degree == 1 and weights is None else steps):  # a line: exact
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


class Polyline(NamedTuple):
    """The polyline through the ordered data as the fitness sees it, one row per segment
    (``B``: the padded point count): ``start`` (B, D), ``vec`` (B, D) to its end,
    ``slope`` (B, D) ``vec / |vec|**2`` and ``allowance2`` (B,), the square of how far a
    curve may stray from it unpenalised (``-inf`` on rows that are no segment, so that
    none of them is ever the nearest)."""

    start: jax.Array
    vec: jax.Array
    slope: jax.Array
    allowance2: jax.Array


#: A segment's allowance is ``h * (ALLOWANCE_BASE + tan(turn / 4) / 2) + rough``, ``h``
#: its length, ``turn`` the larger turning angle at its ends (at most 3 rad) and
#: ``rough`` the larger distance of an end from the chord of its two neighbours: the
#: sagitta ``h tan(turn / 4) / 2`` of a circular arc through its ends that turns as the
#: data do, a tenth of the segment, and the data's own scatter (noise zig-zags the
#: polyline about the curve).  So the smooth curve the data sample stays inside the
#: allowance, and a loop or a spike leaves it.
ALLOWANCE_BASE = 0.1


def data_segments(points: jax.Array, mask: jax.Array, closed: bool) -> Polyline:
    """The :class:`Polyline` through the real points (``mask`` 1; padding after them), in
    order, back to the first for a ``closed`` curve."""
    size = points.shape[0]
    count = jnp.sum(mask).astype(jnp.int32)
    idx = jnp.arange(size)
    segments = count if closed else count - 1
    nxt = jnp.where((idx + 1 < count)[:, None], jnp.roll(points, -1, axis=0), points[0])
    vec = nxt - points
    len2 = jnp.sum(vec * vec, axis=1)
    unit = vec / jnp.sqrt(jnp.maximum(len2, 1e-30))[:, None]
    last = segments - 1
    before = jnp.where(idx == 0, last if closed else 0, idx - 1)
    after = jnp.where(idx < last, idx + 1, 0 if closed else idx)

    def turn(other):  # the angle between each segment and another (0 with itself)
        return jnp.arccos(jnp.clip(jnp.sum(unit * unit[other], axis=1), -1.0, 1.0))

    bend = jnp.minimum(jnp.maximum(turn(before), turn(after)), 3.0)
    # each vertex's distance from the chord of its neighbours (the segment before it
    # and this one): its scatter; at an open curve's ends, none
    chord = vec + vec[before]
    along = jnp.clip(
        jnp.sum(vec[before] * chord, axis=1) / jnp.maximum(jnp.sum(chord * chord, axis=1), 1e-30),
        0.0,
        1.0,
    )
    off = vec[before] - along[:, None] * chord
    scatter = jnp.where(before != idx, jnp.sqrt(jnp.sum(off * off, axis=1)), 0.0)
    rough = jnp.maximum(scatter, scatter[after])
    allowance = jnp.sqrt(len2) * (ALLOWANCE_BASE + 0.5 * jnp.tan(0.25 * bend)) + rough
    allowance2 = jnp.where(idx < segments, allowance * allowance, -jnp.inf)
    return Polyline(points, vec, vec / jnp.maximum(len2, 1e-30)[:, None], allowance2)


def sample_excursions(
    samples: jax.Array, tangents: jax.Array, basis: SpanBasis, polyline: Polyline
) -> tuple[jax.Array, jax.Array]:
    """How far each curve sample strays beyond the data polyline's allowance, (M,), and
    the arc length it stands for, (M,) (0 on samples that repeat the last).

    The excess is ``sqrt(min over segments of max(0, d**2 - a**2))`` (``d``: the
    distance to a segment, ``a``: its allowance): zero inside the allowance, about ``d``
    far from it, and one square root per sample rather than per pair.
    """
    ap = samples[:, None, :] - polyline.start[None]
    along = jnp.clip(jnp.sum(ap * polyline.slope[None], axis=2), 0.0, 1.0)
    off = ap - along[..., None] * polyline.vec[None]
    over = jnp.sum(off * off, axis=2) - polyline.allowance2[None]
    excess = jnp.sqrt(jnp.maximum(jnp.min(over, axis=1), 0.0) + 1e-30)
    real = jnp.arange(samples.shape[0]) < basis.per_span * basis.num_spans
    return excess, jnp.sqrt(jnp.sum(tangents * tangents, axis=1)) * real


def excursion(samples, tangents, basis: SpanBasis, polyline: Polyline) -> jax.Array:
    """The arc-length mean of :func:`sample_excursions`: the swarm's penalty for a curve
    that leaves the data between or beyond the points, which the mean point-to-curve
    distance cannot see."""
    excess, arc = sample_excursions(samples, tangents, basis, polyline)
    return jnp.sum(excess * arc) / jnp.maximum(jnp.sum(arc), 1e-30)
