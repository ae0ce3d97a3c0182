"""Knot vectors: clamped uniform (open) and uniform periodic (closed), and the
free (non-uniform) knots of ``fit(free_knots=True)``: the same two structures with
interior knots placed by span widths.

Vocabulary follows scipy: ``t`` knots, ``k`` degree, ``n`` control-point count.
All knot vectors live on the parameter domain ``[0, 1]``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "clamped_uniform_knots",
    "periodic_uniform_knots",
    "make_knots",
    "breakpoints",
    "check_degree_count",
    "check_knots",
    "span_widths",
    "knots_from_widths",
    "logits_from_widths",
    "curvature_widths",
    "MIN_SPAN_FRACTION",
]

#: With free knots no span is narrower than this fraction of a uniform span: the basis
#: stays well conditioned and every span keeps fitness samples.
MIN_SPAN_FRACTION = 0.1


def check_degree_count(k: int, n: int) -> None:
    """Raise ``ValueError`` unless ``k >= 1`` and ``n >= k + 1``."""
    if int(k) != k or k < 1:
        raise ValueError(f"degree must be an integer >= 1, got {k!r}")
    if int(n) != n or n < k + 1:
        raise ValueError(
            f"control-point count must be an integer >= degree + 1 = {k + 1} "
            f"for degree {k}, got {n!r}"
        )


def clamped_uniform_knots(n: int, k: int) -> np.ndarray:
    """Clamped uniform knots: ``k+1`` zeros, ``n-k-1`` equal interior knots, ``k+1`` ones.

    Returns
    -------
    t : ndarray, shape (n + k + 1,)
    """
    check_degree_count(k, n)
    interior = np.arange(1, n - k) / (n - k)
    return np.concatenate([np.zeros(k + 1), interior, np.ones(k + 1)])


def periodic_uniform_knots(n: int, k: int) -> np.ndarray:
    """Uniform knots of a closed curve with ``n`` distinct control points.

    The curve uses ``n + k`` basis functions on ``t[k] = 0 .. t[n + k] = 1``; control
    point ``i`` drives basis functions ``i`` and ``i + n`` (the first ``k`` wrap around).

    Returns
    -------
    t : ndarray, shape (n + 2k + 1,), ``t[j] = (j - k) / n``
    """
    check_degree_count(k, n)
    return (np.arange(n + 2 * k + 1) - k) / n


def make_knots(n: int, k: int, closed: bool) -> np.ndarray:
    """The uniform knot vector of an open (clamped) or closed (periodic) curve."""
    return periodic_uniform_knots(n, k) if closed else clamped_uniform_knots(n, k)


def breakpoints(t: np.ndarray) -> np.ndarray:
    """The distinct knot values in the domain ``[0, 1]``: the ends of the knot spans."""
    t = np.asarray(t, dtype=np.float64)
    return np.unique(t[(t >= 0.0) & (t <= 1.0)])


def span_widths(logits, num_spans, xp=np):
    """Span widths from free coordinates: ``logits[:num_spans]`` through a softmax, each
    at least ``MIN_SPAN_FRACTION / num_spans``, summing to 1; padding spans get 0.

    Any real logits give a valid, sorted knot vector, so a swarm or a gradient method can
    move them freely.  ``xp``: NumPy or ``jax.numpy``.
    """
    active = xp.arange(logits.shape[0]) < num_spans
    top = xp.max(xp.where(active, logits, -xp.inf))
    e = xp.where(active, xp.exp(xp.where(active, logits, top) - top), 0.0)
    floor = MIN_SPAN_FRACTION / num_spans
    return xp.where(active, floor + (1.0 - MIN_SPAN_FRACTION) * e / xp.sum(e), 0.0)


def knots_from_widths(widths, num_spans, k: int, closed: bool, xp=np):
    """Full knot vector, length ``len(widths) + 2k + 1``, from span widths (padding 0).

    Open: ``k+1`` zeros, the interior breakpoints, then ones (padding spans add more
    ones, with empty support).  Closed: the breakpoints extended with period 1, so
    ``t[k] = 0`` and ``t[num_spans + k] = 1``; ``num_spans`` is the count ``n``.
    """
    breaks = xp.concatenate([xp.zeros(1, dtype=widths.dtype), xp.cumsum(widths)])
    i = xp.arange(widths.shape[0] + 2 * k + 1) - k
    if closed:
        return breaks[i % num_spans] + i // num_spans
    return breaks[xp.clip(i, 0, widths.shape[0])]


def check_knots(t, n: int, k: int, closed: bool) -> np.ndarray:
    """``t`` as float64 if it is a clamped (open) or periodic (closed) knot vector for
    ``n`` control points of degree ``k`` (uniform or not), else ``ValueError`` saying what
    is wrong.

    Open: length ``n+k+1``, ``k+1`` zeros, ``k+1`` ones, non-decreasing interior knots of
    multiplicity at most ``k`` in (0, 1).  Closed: length ``n+2k+1``, ``t[k] = 0``,
    ``t[n+k] = 1``, non-decreasing, period 1 (``t[j+n] = t[j] + 1``).
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    kind = "periodic" if closed else "clamped"
    size = n + 2 * k + 1 if closed else n + k + 1
    if t.shape != (size,) or not np.all(np.isfinite(t)):
        raise ValueError(
            f"knots must be {size} finite numbers for a {kind} curve of degree {k} "
            f"with {n} control points, got shape {t.shape}"
        )
    if np.any(np.diff(t) < 0):
        raise ValueError("knots must be non-decreasing")
    if closed:
        ok = abs(t[k]) <= 1e-12 and abs(t[n + k] - 1) <= 1e-12
        ok = ok and np.allclose(t[n:] - t[:-n], 1.0, rtol=0, atol=1e-12)
        if not ok:
            raise ValueError(
                "knots of a closed curve must be periodic on [0, 1]: t[degree] = 0, "
                "t[n + degree] = 1 and t[j + n] = t[j] + 1"
            )
        return t
    if np.any(np.abs(t[: k + 1]) > 1e-12) or np.any(np.abs(t[-k - 1 :] - 1) > 1e-12):
        raise ValueError(
            f"knots of an open curve must start with {k + 1} zeros and end with "
            f"{k + 1} ones (clamped)"
        )
    t = t.copy()
    t[: k + 1], t[-k - 1 :] = 0.0, 1.0
    interior = t[k + 1 : -k - 1]
    if interior.size and (
        interior.min() <= 0
        or interior.max() >= 1
        or np.max(np.unique(interior, return_counts=True)[1]) > k
    ):
        raise ValueError(f"interior knots must lie in (0, 1) with multiplicity at most {k}")
    return t


def logits_from_widths(widths) -> np.ndarray:
    """Logits whose :func:`span_widths` are ``widths`` (clipped to the minimum span), up to
    a constant; the inverse used to seed a swarm with chosen knots."""
    widths = np.asarray(widths, dtype=np.float64)
    floor = MIN_SPAN_FRACTION / len(widths)
    excess = np.maximum(widths / widths.sum() - floor, 1e-3 * floor)
    logits = np.log(excess)
    return logits - logits.mean()


def curvature_widths(points, num_spans: int, closed: bool) -> np.ndarray:
    """Span widths (in chord-length parameter) that give every span an equal share of
    ``sqrt(turning angle) + its uniform share``: knots gather where the data turn fast,
    and no span gets much wider than uniform.  A seed for free knots, not an optimum.
    """
    pts = np.vstack([points, points[:1]]) if closed else np.asarray(points, dtype=np.float64)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    total = seg.sum()
    if not total > 0:
        return np.full(num_spans, 1.0 / num_spans)
    d = np.diff(pts, axis=0) / np.maximum(seg, 1e-300)[:, None]
    nxt = np.roll(d, -1, axis=0) if closed else d[1:]  # vertex j joins segments j and j+1
    half = np.sqrt(np.arccos(np.clip(np.sum(d[: len(nxt)] * nxt, axis=1), -1.0, 1.0))) / 2
    # mass per segment: half of each end vertex's sqrt(turn), plus the length share
    if closed:
        mass = half + np.roll(half, 1)
    else:
        mass = np.r_[half, 0.0] + np.r_[0.0, half]
    mass = mass / max(mass.sum(), 1e-300) + seg / total
    u = np.concatenate([[0.0], np.cumsum(seg)]) / total
    cum = np.concatenate([[0.0], np.cumsum(mass)]) / mass.sum()
    breaks = np.interp(np.linspace(0.0, 1.0, num_spans + 1), cum, u)
    return np.diff(breaks)
