"""The swarm's fitness: mean point-to-curve distance, estimated cheaply in JAX.

A curve is sampled at ``M`` fixed parameters (precomputed basis matrices for the values and
three derivatives).  Each data point takes its nearest sample, then a few Newton steps on
the third-order Taylor model of the curve there, kept inside the sample's knot span.  Inside
a span a B-spline of degree <= 3 *is* that cubic, so the distance is then exact up to the
choice of span; for higher degrees and rational curves the model is trusted only ``reach``
sample spacings away.  This removes the sampling floor of a nearest-sample distance for a
few flops per point; the reported errors are recomputed exactly on the host
(:mod:`swarmcurves_jax.projection`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .basis import basis_functions, design_matrix
from .knots import breakpoints, knots_from_widths, make_knots, span_widths

__all__ = [
    "SampleBasis",
    "make_sample_basis",
    "free_knot_basis",
    "curve_samples",
    "nearest_sample",
    "nearest_sample_dense",
    "foot_samples",
    "point_distances",
    "mean_distance",
]


class SampleBasis(NamedTuple):
    """Basis matrices at the fitness's sample parameters for one (degree, n, knots).

    ``b0 .. b3``: shape (M, n_pad), values and three derivatives (zero columns pad ``n``);
    ``lo, hi``: shape (M,), how far the parameter may move from each sample;
    ``half_step``: shape (M,), half the parameter distance to the neighbouring samples
    (the tangent segments of the nearest-sample search span it).
    """

    b0: jax.Array
    b1: jax.Array
    b2: jax.Array
    b3: jax.Array
    lo: jax.Array
    hi: jax.Array
    half_step: jax.Array


def make_sample_basis(
    n: int,
    k: int,
    closed: bool,
    num_samples: int,
    n_pad: int | None = None,
    reach: float | None = None,
) -> SampleBasis:
    """Host-side (NumPy float64) sample basis, zero-padded to ``n_pad`` columns.

    ``reach``: how many sample spacings the Newton search may move from its sample (always
    inside the knot span); ``None`` means the whole span, exact for degree <= 3.
    """
    n_pad = n if n_pad is None else n_pad
    t = make_knots(n, k, closed)
    h = 1.0 / num_samples
    u = (np.arange(num_samples) + 0.5) * h
    mats = []
    for nu in range(4):
        b = design_matrix(u, t, k, nu=nu, closed=closed)
        mats.append(np.pad(b, ((0, 0), (0, n_pad - n))))
    breaks = breakpoints(t)
    span = np.clip(np.searchsorted(breaks, u, side="right") - 1, 0, len(breaks) - 2)
    lo, hi = breaks[span] - u, breaks[span + 1] - u
    if reach is not None:
        lo, hi = np.maximum(lo, -reach * h), np.minimum(hi, reach * h)
    return SampleBasis(*mats, lo, hi, np.full(num_samples, 0.5 * h))


def free_knot_basis(
    logits: jax.Array,
    num_spans: jax.Array,
    k: int,
    closed: bool,
    num_samples: int,
    n_pad: int,
    reach: float | None = None,
) -> SampleBasis:
    """:func:`make_sample_basis` for free knots, in JAX, differentiable in ``logits``.

    ``logits`` (S_pad,) place the breakpoints (:func:`~swarmcurves_jax.knots.span_widths`);
    ``num_spans`` (traced) is ``n - k`` open, ``n`` closed.  Every span gets the samples a
    uniform span would: sample ``m`` sits at the same fraction of its span as on uniform
    knots, so narrow spans stay covered.
    """
    logits = logits[: n_pad if closed else n_pad - k]  # the most spans n_pad columns allow
    widths = span_widths(logits, num_spans, jnp)
    t = knots_from_widths(widths, num_spans, k, closed, jnp)
    v = (jnp.arange(num_samples) + 0.5) / num_samples * num_spans
    span = jnp.minimum(jnp.floor(v).astype(jnp.int32), num_spans - 1)
    start = t[span + k]
    u = start + (v - span) * widths[span]
    mats = [basis_functions(u, t, k, nu, span + k, jnp) for nu in range(4)]
    if closed:  # basis function c drives control point c mod n
        cols = jnp.arange(mats[0].shape[1]) % num_spans
        fold = (cols[:, None] == jnp.arange(n_pad)[None, :]).astype(u.dtype)
        mats = [b @ fold for b in mats]
    lo, hi = start - u, t[span + k + 1] - u
    step = widths[span] * num_spans / num_samples  # the samples' spacing in their span
    if reach is not None:
        lo, hi = jnp.maximum(lo, -reach * step), jnp.minimum(hi, reach * step)
    return SampleBasis(*mats, lo, hi, 0.5 * step)


def curve_samples(ctrl: jax.Array, weights: jax.Array | None, basis: SampleBasis):
    """Samples of the curve and its first three derivatives, each (M, D).

    ``weights=None`` is the non-rational curve; otherwise the quotient rule applies.
    """
    mats = (basis.b0, basis.b1, basis.b2, basis.b3)
    if weights is None:
        return tuple(b @ ctrl for b in mats)
    wp = ctrl * weights[:, None]
    a0, a1, a2, a3 = (b @ wp for b in mats)
    w0, w1, w2, w3 = ((b @ weights)[:, None] for b in mats)
    c0 = a0 / w0
    c1 = (a1 - c0 * w1) / w0
    c2 = (a2 - 2.0 * c1 * w1 - c0 * w2) / w0
    c3 = (a3 - 3.0 * c2 * w1 - 3.0 * c1 * w2 - c0 * w3) / w0
    return c0, c1, c2, c3


_BLOCK = 128  # samples per unrolled block: larger fusions stop fusing on XLA:CPU


def nearest_sample(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """Index of the sample whose tangent segment ``samples[m] + s * tangents[m]``,
    ``|s| <= 1``, is nearest to each point: (N,) int32.

    Ranking by the tangent segment rather than the sample point keeps a point on its own
    branch where the curve moves fast and samples are sparse.  Written for XLA:CPU speed
    (measured on W1, ``benchmarks/bench_w1.py``): ``argmin`` is a variadic reduction the CPU
    backend does not vectorise (~40x slower), and a ``min`` over a broadcast (N, M) array
    goes to a library kernel that materialises it.  So the index is packed into the low
    mantissa bits of the (non-negative) squared distance and the minimum is an unrolled
    running ``minimum`` over samples, which fuses into one loop (a ``lax.scan`` over blocks
    of 128 beyond that).
    Ties break at a relative precision of ``2**(bits - 24)``; the caller refines anyway.
    """
    num, dim = samples.shape
    bits = max(1, (num - 1).bit_length())
    low = jnp.int32((1 << bits) - 1)
    len2 = jnp.sum(tangents**2, axis=1)
    inv_len2 = 1.0 / jnp.maximum(len2, 1e-30)

    def block_min(acc, blk):
        first, block, tang, inv, sq = blk
        for m in range(block.shape[0]):
            diff = [points[:, i] - block[m, i] for i in range(dim)]
            d2 = sum(x * x for x in diff)
            along = sum(diff[i] * tang[m, i] for i in range(dim))
            s = jnp.clip(along * inv[m], -1.0, 1.0)
            # Floor at a normal float: a tagged 0 would be a denormal, flushed to 0 by
            # XLA:CPU, and its index lost.
            d2 = jnp.maximum(d2 - s * (2.0 * along - s * sq[m]), 1e-30).astype(jnp.float32)
            tagged = (jax.lax.bitcast_convert_type(d2, jnp.int32) & ~low) | (first + m)
            tagged = jax.lax.bitcast_convert_type(tagged, jnp.float32)
            acc = tagged if acc is None else jnp.minimum(acc, tagged)
        return acc

    if num <= _BLOCK:
        best = block_min(None, (jnp.int32(0), samples, tangents, inv_len2, len2))
    else:
        num_blocks = -(-num // _BLOCK)
        pad = num_blocks * _BLOCK - num
        blocks = [
            jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]).reshape(
                num_blocks, _BLOCK, *a.shape[1:]
            )
            for a in (samples, tangents, inv_len2, len2)
        ]
        firsts = jnp.arange(num_blocks, dtype=jnp.int32) * _BLOCK
        init = jnp.full(points.shape[:1], jnp.inf, jnp.float32)
        best, _ = jax.lax.scan(lambda a, b: (block_min(a, b), None), init, (firsts, *blocks))
    return jnp.minimum(jax.lax.bitcast_convert_type(best, jnp.int32) & low, num - 1)


def nearest_sample_dense(points: jax.Array, samples: jax.Array, tangents: jax.Array) -> jax.Array:
    """:func:`nearest_sample` as a plain (N, M) ``argmin``: slower to run on XLA:CPU but
    about ten times quicker to compile, for code that searches only a few dozen times."""
    diff = points[:, None, :] - samples[None, :, :]
    along = jnp.sum(diff * tangents[None], axis=2)
    len2 = jnp.sum(tangents**2, axis=1)[None, :]
    s = jnp.clip(along / jnp.maximum(len2, 1e-30), -1.0, 1.0)
    d2 = jnp.sum(diff**2, axis=2) - s * (2.0 * along - s * len2)
    return jnp.argmin(d2, axis=1).astype(jnp.int32)


_NEWTON_STEPS = 3


def foot_samples(
    ctrl: jax.Array, weights: jax.Array | None, basis: SampleBasis, points: jax.Array
) -> jax.Array:
    """Index of the sample each point's Newton search starts from: (N,) int32.

    Piecewise constant in the curve, so it has no derivative: a caller that differentiates
    :func:`point_distances` computes it once and passes it, keeping the search out of the
    differentiated graph.  Uses :func:`nearest_sample_dense` (quick to compile).
    """
    c0, c1 = curve_samples(ctrl, weights, basis)[:2]
    return nearest_sample_dense(points, c0, c1 * basis.half_step[:, None])


def point_distances(
    ctrl: jax.Array,
    weights: jax.Array | None,
    basis: SampleBasis,
    points: jax.Array,
    foot: jax.Array | None = None,
) -> jax.Array:
    """Estimated distance from every point (N, D) to the curve: shape (N,); differentiable
    in the control points and weights (used by :mod:`swarmcurves_jax.refine`).
    ``foot``: the search's result (:func:`foot_samples`), if already known.

    After the search everything is component-major, one 1-D gather per component: on
    XLA:CPU a trailing axis of 2 or 3 vectorises badly and a 2-D gather under ``vmap`` is
    about ten times slower.  The barrier keeps XLA from fusing the search loop into them.
    """
    dim = points.shape[1]
    c = curve_samples(ctrl, weights, basis)
    j = nearest_sample(points, c[0], c[1] * basis.half_step[:, None]) if foot is None else foot
    table = [x[:, i] for x in c for i in range(dim)] + [basis.lo, basis.hi]
    table, j = jax.lax.optimization_barrier((table, j))
    near = [col[j] for col in table]  # 4 D + 2 arrays of shape (N,)
    r = [near[i] - points[:, i] for i in range(dim)]
    d1, d2, d3 = ([near[o * dim + i] for i in range(dim)] for o in (1, 2, 3))
    lo, hi = near[4 * dim], near[4 * dim + 1]

    def model(delta):
        """Taylor model of ``C(u_j + delta) - p`` and its two derivatives, per component."""
        q = [r[i] + delta * (d1[i] + delta * (d2[i] / 2 + delta * d3[i] / 6)) for i in range(dim)]
        dq = [d1[i] + delta * (d2[i] + delta * d3[i] / 2) for i in range(dim)]
        ddq = [d2[i] + delta * d3[i] for i in range(dim)]
        return q, dq, ddq

    delta = jnp.zeros_like(lo)
    for _ in range(_NEWTON_STEPS):
        q, dq, ddq = model(delta)
        g = sum(q[i] * dq[i] for i in range(dim))
        h = sum(dq[i] * dq[i] + q[i] * ddq[i] for i in range(dim))
        to_bound = jnp.where(g > 0, lo, hi) - delta
        delta = jnp.clip(delta + jnp.where(h > 0, -g / jnp.where(h > 0, h, 1.0), to_bound), lo, hi)
    # The foot point is optimal, so by the envelope theorem the distance's derivative with
    # respect to the curve is its partial at a fixed foot: no gradient through Newton.
    delta = jax.lax.stop_gradient(delta)
    q2 = sum(x * x for x in model(delta)[0])
    r2 = sum(x * x for x in r)
    return jnp.sqrt(jnp.minimum(q2, r2) + 1e-30)  # + a normal float: finite gradient at 0


def mean_distance(
    ctrl: jax.Array, weights: jax.Array | None, basis: SampleBasis, points: jax.Array
) -> jax.Array:
    """The fitness: mean estimated point-to-curve distance (a scalar)."""
    return jnp.mean(point_distances(ctrl, weights, basis, points))
