"""Each swarm's basis as a table of polynomial pieces, and the curve samples it gives.

Between two knots a B-spline (or the numerator and denominator of a NURBS) is one
polynomial, so each swarm's basis is precomputed as a table: per knot span, the matrix
that maps control points to that span's power coefficients in a local parameter
``tau in [0, 1]``.  Adjacent spans of a degree-``k`` spline differ by a multiple of
``(tau - knot)**k``, so two more rows per span (those jumps) extend a span's polynomial
exactly into both neighbours.  Free knots build the same table per particle
(:func:`free_knot_basis`).
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
    "PRECISION",
    "SpanBasis",
    "make_span_basis",
    "free_knot_basis",
    "curve_samples",
    "float32_matmul",
    "homogeneous",
]


#: The precision of every matrix product here: float32 on every backend.  XLA:GPU's
#: default for a float32 product is TF32 (a 10-bit mantissa), which moved the curve by
#: about 1e-3 of its size, so that the fitness undercut the true distance (measured on an
#: H100: ``tests/test_fitness.py`` failed, W1's cubic ended 2.7x worse); XLA:CPU ignores it.
PRECISION = jax.lax.Precision.HIGHEST


def float32_matmul(a, b, xp=jnp):
    """``a @ b``, in float32 (:data:`PRECISION`) where ``xp`` is ``jax.numpy``."""
    return a @ b if xp is np else jnp.matmul(a, b, precision=PRECISION)


def float32_sum(a: jax.Array) -> jax.Array:
    """``sum(a)`` of a vector as a product with ones.  XLA:CPU rewrites a sum of more than
    32 values as a pass of partial sums over the stored values, which took longer (W1,
    warm: 3.10 against 3.05 s), and rewrites it one way in one program and another in
    another, so that swarms dealt over several devices differed from one program's in the
    last bit; the product is taken alike everywhere."""
    return jnp.dot(a, jnp.ones_like(a), precision=PRECISION)


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
    inv = 1.0 / per  # then products: see span_and_start
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


def homogeneous(ctrl: jax.Array, weights: jax.Array | None) -> jax.Array:
    """Control points as the columns the polynomials act on: ``(w P, w)`` when rational."""
    if weights is None:
        return ctrl
    return jnp.concatenate([ctrl * weights[:, None], weights[:, None]], axis=1)


def curve_samples(ctrl: jax.Array, weights: jax.Array | None, basis: SpanBasis):
    """The search samples (M, D) and their tangent segments' half vectors (M, D)."""
    if weights is None:
        return float32_matmul(basis.sample_value, ctrl), float32_matmul(basis.sample_tangent, ctrl)
    hom = homogeneous(ctrl, weights)
    a, da = float32_matmul(basis.sample_value, hom), float32_matmul(basis.sample_tangent, hom)
    value = a[:, :-1] / a[:, -1:]
    return value, (da[:, :-1] - value * da[:, -1:]) / a[:, -1:]
