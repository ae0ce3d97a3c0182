"""The swarm's seeds: least-squares curves with parameter correction, one per swarm.

With ``init="lsq"`` one particle of every swarm starts on the least-squares fit of its
(degree, count): chord-length parameters, then Hoschek's correction (each point's
parameter moved to its nearest point on the current curve, and solved again).
"""

from __future__ import annotations

import functools

import numpy as np
from pykdtree.kdtree import KDTree

from .basis import design_matrix
from .devices import host_map
from .knots import curvature_widths, logits_from_widths, make_knots
from .layout import KNOT_LOGIT_BOUND, Layout, knot_vector

__all__ = ["chord_parameters", "least_squares_ctrl", "uniform_grid_design", "seed_positions"]


def chord_parameters(points: np.ndarray, closed: bool) -> np.ndarray:
    """Cumulative chord-length parameters in [0, 1] (closed: [0, 1), the seam at 0)."""
    pts = np.vstack([points, points[:1]]) if closed else points
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)])
    u = u / u[-1] if u[-1] > 0 else np.linspace(0, 1, len(pts))
    return u[:-1] if closed else u


def _lsq(b, points, ends):
    if ends is None:
        return np.linalg.lstsq(b, points, rcond=None)[0]
    rhs = points - np.outer(b[:, 0], ends[0]) - np.outer(b[:, -1], ends[1])
    inner = np.linalg.lstsq(b[:, 1:-1], rhs, rcond=None)[0]
    return np.vstack([ends[0], inner, ends[1]])


def least_squares_ctrl(points, n, k, closed, ends=None, rounds: int = 20, t=None) -> np.ndarray:
    """Linear least-squares control points with parameter correction (the swarm's seed).

    Starts from chord-length parameters, then ``rounds`` times moves every point's
    parameter to its nearest point on the current curve (a 2048-sample grid) and solves
    again (Hoschek's correction).  Chord lengths alone misplace the parameters of looping
    curves; measured on random closed cubics the correction lifts recovery from 4 to 6
    of 12 (``benchmarks/recovery_rates.py``).  With ``ends`` the first and last control
    points are fixed.  ``t``: the knot vector (default: the uniform one).
    """
    if t is None:
        t, dense = make_knots(n, k, closed), uniform_grid_design(n, k, closed)
    else:
        dense = design_matrix(_seed_grid(closed), t, k, closed=closed)
    ctrl = _lsq(design_matrix(chord_parameters(points, closed), t, k, closed=closed), points, ends)
    best, best_err, last = ctrl, np.inf, None
    for _ in range(rounds + 1):
        # each point's nearest grid sample, exact (pykdtree rather than scipy's cKDTree: W1's
        # seeds 0.18 -> 0.10 s on two threads; cKDTree spends three quarters of its build
        # in NumPy's slow min and max down the columns of a (2048, 2) array)
        dist, j = KDTree(dense @ ctrl).query(points)
        err = np.mean(dist)
        if err < best_err:  # a correction can also fold the parameters: keep the best
            best, best_err = ctrl, err
        if last is not None and np.array_equal(j, last):
            break  # a fixed point: every later round would give this same curve again
        ctrl, last = _lsq(dense[j], points, ends), j
    return best


def _seed_grid(closed: bool) -> np.ndarray:
    """The 2048 parameters whose curve points the seeds' correction searches."""
    return np.linspace(0.0, 1.0, 2048, endpoint=not closed)


def uniform_grid_design(n: int, k: int, closed: bool) -> np.ndarray:
    """:func:`_seed_grid`'s design matrix on the uniform knots (read-only): the same for
    every call of a shape, so made once (W1's 21 swarms: 9 ms a call), up to 64 control
    points (the cache then holds at most 32 MB)."""
    return (_grid_design if n <= 64 else _grid_design.__wrapped__)(n, k, closed)


@functools.lru_cache(maxsize=32)
def _grid_design(n: int, k: int, closed: bool) -> np.ndarray:
    dense = design_matrix(_seed_grid(closed), make_knots(n, k, closed), k, closed=closed)
    dense.setflags(write=False)
    return dense


def seed_positions(pairs, space: Layout, norm_pts, closed, ends, dtype) -> np.ndarray:
    """One least-squares position per swarm, laid out like a particle."""

    def one(pair):
        k, n = pair
        row, t = np.zeros(space.size), None
        if space.num_knots:  # free knots: start where the data turn (knots.curvature_widths)
            spans = n if closed else n - k
            logits = logits_from_widths(curvature_widths(norm_pts, spans, closed))
            first = space.size - space.num_knots
            row[first : first + spans] = np.clip(logits, -KNOT_LOGIT_BOUND, KNOT_LOGIT_BOUND)
            t = knot_vector(row, k, n, space)
        row[: n * space.dim] = least_squares_ctrl(norm_pts, n, k, closed, ends, t=t).ravel()
        return row

    return np.stack(host_map(one, pairs)).astype(dtype)
