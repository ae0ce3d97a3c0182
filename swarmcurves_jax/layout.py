"""A particle's flat position: what each coordinate means, and the box it searches in.

A swarm's particles are flat vectors (:class:`Layout`): control points, then log-weights
(rational), then knot logits (free knots).  Every swarm of a call shares one layout, padded
to the call's largest count, so all of them run in one program.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from . import pso
from .knots import check_knots, knots_from_widths, make_knots, span_widths
from .span_basis import SpanBasis, free_knot_basis

__all__ = ["Layout", "KNOT_LOGIT_BOUND", "search_boxes", "knot_vector", "geometry"]


class Layout(NamedTuple):
    """Static layout of a particle's flat position: ``n_pad`` points of ``dim`` coords,
    then ``n_pad`` log-weights when rational, then ``num_knots`` knot logits (free knots:
    :func:`swarmcurves_jax.knots.span_widths`), and what the fitness needs to read them."""

    n_pad: int
    dim: int
    rational: bool
    num_knots: int = 0
    closed: bool = False

    @property
    def num_ctrl(self) -> int:
        return self.n_pad * self.dim

    @property
    def size(self) -> int:
        return self.num_ctrl + (self.n_pad if self.rational else 0) + self.num_knots

    def knot_logits(self, q):
        return q[self.size - self.num_knots :]

    def basis(self, q, pair, k, fixed: SpanBasis) -> SpanBasis:
        """The fitness's basis: ``fixed`` (precomputed), or from ``q``'s free knots (with
        as many search samples as ``fixed``)."""
        if not self.num_knots:
            return fixed
        spans = pair[1] if self.closed else pair[1] - pair[0]
        samples = fixed.sample_value.shape[0]
        return free_knot_basis(self.knot_logits(q), spans, k, self.closed, samples, self.n_pad)

    def split(self, q):
        """``(ctrl (n_pad, dim), log_weights (n_pad,) or None)`` of a position (JAX or NumPy)."""
        ctrl = q[: self.num_ctrl].reshape(self.n_pad, self.dim)
        return ctrl, (q[self.num_ctrl : self.num_ctrl + self.n_pad] if self.rational else None)


#: Knot logits stay in [-3, 3]: span widths then differ by up to e^6 ~ 400x before the
#: minimum span (MIN_SPAN_FRACTION of a uniform span) takes over.
KNOT_LOGIT_BOUND = 3.0


def search_boxes(pairs, space: Layout, weight_bounds, ends, dtype) -> pso.Box:
    """Per-swarm search boxes.

    Control points start in U[-1, 1] and are unbounded after; log-weights start in
    U[-1, 1] and stay inside log(weight_bounds); knot logits start in U[-0.1, 0.1] (near
    uniform knots) and stay inside +-KNOT_LOGIT_BOUND.  ``ends`` ((2, D) or None) pins the
    first and last control points of open curves to the data's end points (lower = upper).
    """
    num_ctrl, size = space.num_ctrl, space.size
    init_lo, init_hi = -np.ones(size), np.ones(size)
    lower, upper = np.full(size, -np.inf), np.full(size, np.inf)
    if space.rational:
        wlo, whi = np.log(weight_bounds[0]), np.log(weight_bounds[1])
        lower[num_ctrl:], upper[num_ctrl:] = wlo, whi
        init_lo[num_ctrl:] = np.maximum(-1.0, wlo)
        init_hi[num_ctrl:] = np.minimum(1.0, whi)
    if space.num_knots:
        init_lo[-space.num_knots :], init_hi[-space.num_knots :] = -0.1, 0.1
        lower[-space.num_knots :], upper[-space.num_knots :] = -KNOT_LOGIT_BOUND, KNOT_LOGIT_BOUND
    boxes = []
    for k, n in pairs:
        b = [init_lo.copy(), init_hi.copy(), lower.copy(), upper.copy(), np.zeros(size)]
        b[4][: n * space.dim] = 1
        if space.rational:
            b[4][num_ctrl : num_ctrl + n] = 1
        if space.num_knots:
            first = size - space.num_knots
            b[4][first : first + (n if space.closed else n - k)] = 1
        if ends is not None:
            for row, point in ((0, ends[0]), (n - 1, ends[1])):
                sl = slice(row * space.dim, (row + 1) * space.dim)
                for arr in b[:4]:
                    arr[sl] = point
        boxes.append(b)
    return pso.Box(*(np.array(parts, dtype) for parts in zip(*boxes)))


def knot_vector(q, k, n, space) -> np.ndarray:
    """The knot vector of a position: fixed uniform, or from its knot logits (float64)."""
    if not space.num_knots:
        return make_knots(n, k, space.closed)
    spans = n if space.closed else n - k
    logits = space.knot_logits(q)[: space.n_pad if space.closed else space.n_pad - k]
    t = knots_from_widths(span_widths(logits, spans), spans, k, space.closed)
    # Checked, with the clamped ends set exactly: the widths sum to 1 only to rounding,
    # and an end knot of 1 + 2e-16 left the last span out of the domain [0, 1] that the
    # measures sample (its points were projected onto the wrong span: errors 45x too large).
    return check_knots(t[: spans + 2 * k + 1], n, k, space.closed)


def geometry(q, space):
    ctrl, log_w = space.split(q)
    return ctrl, None if log_w is None else jnp.exp(log_w)
