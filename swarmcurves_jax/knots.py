"""Knot vectors of SPEC §1: clamped uniform (open) and uniform periodic (closed).

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
]


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
    """The knot vector SPEC §1 fixes for an open (clamped) or closed (periodic) curve."""
    return periodic_uniform_knots(n, k) if closed else clamped_uniform_knots(n, k)


def breakpoints(t: np.ndarray) -> np.ndarray:
    """The distinct knot values in the domain ``[0, 1]``: the ends of the knot spans."""
    t = np.asarray(t, dtype=np.float64)
    return np.unique(t[(t >= 0.0) & (t <= 1.0)])
