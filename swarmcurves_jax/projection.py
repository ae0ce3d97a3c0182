"""True point-to-curve distances (the reported errors), in float64 NumPy.

Each point is projected on the curve: a dense sampling that contains every knot gives a
polyline; the three chords nearest to the point (the true foot lies on an arc whose chord is
within the chord error of the true distance) are refined by projected Newton on
``|C(u) - p|^2`` inside their parameter intervals.  Every interval lies inside one knot
span, where the curve is a smooth polynomial (or rational) arc, so Newton converges to
machine precision there.  Ranking chords rather than sample points keeps a point on its own
branch where the curve moves fast and passes near itself.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
from scipy.spatial import cKDTree

from .basis import design_matrices, design_matrix, find_span
from .knots import breakpoints

__all__ = ["curve_derivatives", "dense_parameters", "distance_to_polyline", "project_points"]

_NEWTON_STEPS = 30


def curve_derivatives(u, ctrl, weights, t, k, closed, max_nu=2, span=None):
    """Curve points and derivatives ``[C, C', ...]`` at ``u`` (rational quotient rule);
    ``span``: each parameter's knot span, if not the one ``u`` lies in
    (:func:`~swarmcurves_jax.basis.design_matrices`)."""
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    return _rational(design_matrices(u, t, k, max_nu, closed=closed, span=span), ctrl, weights)


def _rational(a, ctrl, weights):
    """``[C, C', ...]`` from the design matrices ``a`` ``[B, B', ...]`` (at most three)."""
    wp = ctrl * weights[:, None]
    num = [b @ wp for b in a]
    den = [b @ weights for b in a]
    c0 = num[0] / den[0][:, None]
    out = [c0]
    if len(a) > 1:
        c1 = (num[1] - c0 * den[1][:, None]) / den[0][:, None]
        out.append(c1)
    if len(a) > 2:
        c2 = (num[2] - 2 * c1 * den[1][:, None] - c0 * den[2][:, None]) / den[0][:, None]
        out.append(c2)
    return out


def dense_parameters(t: np.ndarray, per_span: int) -> np.ndarray:
    """Sorted parameters in ``[0, 1]``: ``per_span`` equal steps in every non-empty span."""
    breaks = breakpoints(t)
    steps = np.linspace(0.0, 1.0, per_span + 1)[:-1]
    u = (breaks[:-1, None] + steps[None, :] * np.diff(breaks)[:, None]).ravel()
    return np.append(u, 1.0)


@functools.lru_cache(maxsize=32)
def _dense_design(knots: bytes, k: int, closed: bool, per_span: int):
    """:func:`dense_parameters` of the knots (float64 bytes) and their design matrix,
    read-only: the same for every curve on the same knots (fixed knots: every curve of a
    shape), so made once (W1's 21 projections: 20 ms of 130, serial); by
    :func:`project_points` up to 32 control points (the cache then holds at most 33 MB)."""
    t = np.frombuffer(knots)
    grid = dense_parameters(t, per_span)
    design = design_matrix(grid, t, k, closed=closed)
    grid.setflags(write=False)
    design.setflags(write=False)
    return grid, design


def _chord_d2(points, a, ab, inv, idx):
    """Squared distances from each point to chords ``idx`` (N, C) of ``a + s ab``."""
    coords = range(points.shape[1])
    ap = [points[:, d, None] - a[idx, d] for d in coords]
    return _d2(ap, [ab[idx, d] for d in coords], inv[idx])


def _d2(ap, ab, inv):
    """Squared distances from points to chords, given per coordinate: ``ap[d]`` each
    point's offset from a chord's start, ``ab[d]`` the chord, ``inv`` its inverse squared
    length (arrays that broadcast together).  The coordinates are summed in order: one
    arithmetic for the chords a search picked and for every chord (:func:`_every_chord_d2`),
    so both give the same distance bit for bit."""
    s = ap[0] * ab[0]
    for x, y in zip(ap[1:], ab[1:], strict=True):
        s += x * y
    s *= inv
    np.clip(s, 0.0, 1.0, out=s)
    d2 = None
    for x, y in zip(ap, ab):
        e = np.subtract(x, s * y, out=x)  # in place: the offsets are made for this call
        e *= e
        d2 = e if d2 is None else np.add(d2, e, out=d2)
    return d2


def _every_chord_d2(points, a, ab, inv):
    """Squared distances (N, M) from every point (N, D) to every chord of ``a + s ab``
    (M, D): :func:`_d2` per coordinate, broadcast without gathering by index."""
    coords = range(points.shape[1])
    return _d2([points[:, d, None] - a[:, d] for d in coords], [ab[:, d] for d in coords], inv)


def _chords(starts, ends):
    """``(a, ab, inv)`` of the chords from ``starts`` to ``ends`` (M, D): start, direction
    and inverse squared length (a point-like chord's kept finite)."""
    ab = ends - starts
    return starts, ab, 1.0 / np.maximum(np.sum(ab * ab, axis=1), 1e-300)


#: :func:`distance_to_polyline` measures every chord of a polyline with at most this many
#: chords per sample the k-d tree search would start from (:func:`_samples_to_settle`: 4
#: for even chords, up to 16 where long chords lie among short ones).  Measured on the
#: curve -> data distances of fits to the outlines, f4 and random B-splines: every chord
#: costs about 9 ns a (point, chord) pair, the tree 1-1.5 us a point from 4 samples and
#: 2.3-4 us from 14-16 (more where a long chord leaves many points unsure).
EVERY_CHORD_PER_SAMPLE = 20


def _nearest_chords(points, samples, top=3, chords=None, near=None):
    """Indices of the ``top`` chords ``[samples[i], samples[i+1]]`` nearest to each point,
    (N, top), nearest first, and each one's squared distance to it, (N, top).
    ``chords`` (:func:`_chords` of the samples) and ``near`` (:func:`_samples_to_settle`):
    passed where the caller made them already, else made here.

    A chord whose two ends lie at least ``R`` from a point is at least
    ``sqrt(R^2 - L^2/4)`` from it (``L``: the longest chord), and a chord within ``r`` has
    an end within ``sqrt(r^2 + L^2/4)``.  So the chords at a point's nearest samples (a
    k-d tree; how many: :func:`_samples_to_settle`) hold the answer whenever the farthest
    of those samples lies that far, with ``r`` the ``top``-th nearest chord's distance
    among them.  A point they leave unsure asks the tree for every sample within that reach
    and ranks the chords there (:func:`_rank_chords_at`).  Exact either way, and, against a
    curve's dense samples, about 10x quicker than searching every chord for every point
    (measured on W1's solutions, from 16 samples; 16 rather than 32, and an unbalanced tree:
    115 -> 98 ms, the same chords).  The bound by ``r + L/2`` instead left 98 % of a far
    curve's samples unsure (``R`` hardly exceeds ``r`` there).  Asking unsure points again
    for 8 times as many samples, until sure, took 2.6 s against 0.74 s for the curve -> data
    distances of a curve's 98,000 samples to a 20,000-point polyline.  scipy's tree, not
    pykdtree's (the seeds'): pykdtree's 16-neighbour queries were 5 % quicker on idle cores
    but 4x slower with both cores busy elsewhere (its OpenMP query waits for its descheduled
    threads).
    """
    chords = _chords(samples[:-1], samples[1:]) if chords is None else chords
    len2 = np.sum(chords[1] ** 2, axis=1)
    out = np.empty((len(points), top), dtype=np.int64)
    out_d2 = np.empty((len(points), top))
    tree = cKDTree(samples, balanced_tree=False, compact_nodes=False)
    quarter = 0.25 * np.max(len2) * (1.0 + 1e-9)  # (L/2)^2, rounded up
    near = min(_samples_to_settle(len2, top) if near is None else near, len(samples))
    chunk = max(1, 8192 * 32 // near)  # bounded temporaries for huge scans
    unsure = [np.arange(0)]
    for lo in range(0, len(points), chunk):
        at = np.arange(lo, min(lo + chunk, len(points)))
        dist, vert = (x.reshape(len(at), near) for x in tree.query(points[at], k=near))
        cand = np.sort(np.clip(np.c_[vert - 1, vert], 0, len(len2) - 1), axis=1)
        d2 = _chord_d2(points[at], *chords, cand)
        d2[:, 1:][cand[:, 1:] == cand[:, :-1]] = np.inf  # each chord once
        pick = np.argpartition(d2, top - 1, axis=1)[:, :top]
        rank = np.argsort(np.take_along_axis(d2, pick, axis=1), axis=1, kind="stable")
        pick = np.take_along_axis(pick, rank, axis=1)  # nearest first
        within = np.arange(len(at))[:, None]
        out[at], out_d2[at] = cand[within, pick], d2[within, pick]
        if near < len(samples):
            unsure.append(at[dist[:, -1] ** 2 <= out_d2[at].max(axis=1) + quarter])
    unsure = np.concatenate(unsure)
    reach = np.sqrt(out_d2[unsure].max(axis=1) + quarter)
    # about 2**14 samples a query (a long chord's reach can hold them all; measured: 2**14,
    # 2**16 and 2**19 took 0.66-0.77, 0.76-0.80 and 0.97-1.02 s on the polyline above)
    counts = np.cumsum(tree.query_ball_point(points[unsure], reach, return_length=True))
    cuts = np.searchsorted(counts, np.arange(1 << 14, counts[-1] if len(counts) else 0, 1 << 14))
    for rows, within in zip(np.split(unsure, cuts), np.split(reach, cuts)):
        if len(rows):  # (a row past 2**14 samples makes an empty part)
            found = tree.query_ball_point(points[rows], within, return_sorted=True)
            out[rows], out_d2[rows] = _rank_chords_at(points, rows, found, chords, top)
    return out, out_d2


def _samples_to_settle(len2: np.ndarray, top: int) -> int:
    """How many nearest samples :func:`_nearest_chords` starts from: ``k`` consecutive
    samples ``s`` apart reach ``(k - 1) s / 2`` along the polyline either side of a
    point's foot, which settles its ``top`` nearest chords once that passes half the
    longest chord ``L`` and the ``top``-th chord: ``top + 1 + ceil(L / s)``, ``s`` the
    short chords' length (their 10th percentile), from 4 to 16.  Measured, serial, on a
    warm ``fit`` of f4 at 20,000 points (its longest chord 5.3 times the short ones, so
    8): its curves' samples against the data took 12.6, 6.5, 6.1 and 8.4 s from 4, 6, 8
    and 12 vertices, the ball query settling 65, 10, 0.03 and 0.01 % of them; at 100,000
    points, its points' three nearest chords 7.8, 4.7 and 4.4 s from 16, 8 and 6 samples."""
    ratio = np.sqrt(np.max(len2) / max(float(np.percentile(len2, 10)), 1e-300))
    return int(np.clip(top + 1 + np.ceil(ratio), 4, 16)) if np.isfinite(ratio) else 16


def _rank_chords_at(points, rows, found, chords, top):
    """The ``top`` chords nearest to each of the points ``rows`` among the
    chords at the samples ``found`` for it (sorted index lists: a sample's chord to the
    next, and the chord before each run of consecutive samples, each chord once), and
    their squared distances, nearest first."""
    counts = np.fromiter(map(len, found), np.int64, len(found))
    ends = np.fromiter(itertools.chain.from_iterable(found), np.int64, counts.sum())
    run = np.r_[True, np.diff(ends) != 1]
    run[np.cumsum(counts)[:-1]] = True  # a row's first sample starts a run
    own, before = ends < len(chords[0]), run & (ends > 0)
    row = np.repeat(np.arange(len(rows)), counts)
    row, index = np.r_[row[own], row[before]], np.r_[ends[own], ends[before] - 1]
    d2 = _chord_d2(points[rows[row]], *chords, index[:, None])[:, 0]
    out, out_d2 = np.zeros((len(rows), top), np.int64), np.full((len(rows), top), np.inf)
    for j in range(top):  # the nearest left, then the next: a pass each, no sort
        np.minimum.at(out_d2[:, j], row, d2)
        hit = np.flatnonzero(d2 == out_d2[row, j])
        first = np.full(len(rows), len(d2))
        np.minimum.at(first, row[hit], hit)  # each row's first chord at its least
        out[:, j] = index[first]
        d2[first] = np.inf
    return out, out_d2


def segment_distances(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, idx=None):
    """Distance from each point (N, D) to segments ``idx`` (N, C) of those from ``starts``
    to ``ends`` (M, D); to every segment, (N, M), if ``idx`` is None."""
    chords = _chords(starts, ends)
    if idx is None:
        return np.sqrt(_every_chord_d2(points, *chords))
    return np.sqrt(_chord_d2(points, *chords, idx))


def distance_to_polyline(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Exact distance (N,) from every point (N, D) to the polyline through ``vertices``
    (M, D; one vertex: the distance to it): the curve -> data side of the two-sided
    measures.  Every chord is measured where that is the quicker search
    (:data:`EVERY_CHORD_PER_SAMPLE`), the nearest ones found by :func:`_nearest_chords`
    elsewhere: the same distances bit for bit."""
    if len(vertices) < 2:
        return np.linalg.norm(points - vertices[:1], axis=1)
    chords = _chords(vertices[:-1], vertices[1:])
    near = _samples_to_settle(np.sum(chords[1] ** 2, axis=1), 1)
    if len(vertices) - 1 > EVERY_CHORD_PER_SAMPLE * near:
        return np.sqrt(_nearest_chords(points, vertices, 1, chords, near)[1][:, 0])
    rows = max(1, 32768 // (len(vertices) - 1))  # temporaries of 32,768 pairs stay cached
    out = np.empty(len(points))
    for lo in range(0, len(points), rows):
        out[lo : lo + rows] = np.min(_every_chord_d2(points[lo : lo + rows], *chords), axis=1)
    return np.sqrt(out)


def _newton(u, lo, hi, span, points, curve):
    """Projected Newton on ``|C(u) - p|^2`` inside ``[lo, hi]``, until no parameter moves
    by more than 1e-15 (at most ``_NEWTON_STEPS``).  Each parameter's step depends on its
    own row alone, so a parameter that did not move at all is at its fixed point and
    leaves the loop: the numbers of stepping every parameter every time (to the rounding
    of the matrix products, whose blocking follows the row count), for a fraction of the
    evaluations (100,000 points near a cubic: 891,000 rows instead of 3,000,000)."""
    u = u.copy()
    at = np.arange(len(u))
    for _ in range(_NEWTON_STEPS):
        now = u[at]
        c0, c1, c2 = curve_derivatives(now, *curve, span=span[at])
        r = c0 - points[at]
        g = np.sum(c1 * r, axis=1)
        h = np.sum(c1 * c1, axis=1) + np.sum(c2 * r, axis=1)
        step = np.where(h > 0, -g / np.where(h > 0, h, 1.0), np.where(g > 0, -np.inf, np.inf))
        new = np.clip(now + step, lo[at], hi[at])
        u[at] = new
        if np.all(np.abs(new - now) <= 1e-15):
            break
        at = at[new != now]
    return u


def project_points(points, ctrl, weights, t, k, closed, *, min_samples=4096):
    """Distance from every point to the curve, and the foot-point parameter.

    Parameters
    ----------
    points : ndarray, shape (N, D)
    ctrl : ndarray, shape (n, D)
    weights : ndarray, shape (n,)
    t : ndarray
        Full knot vector (see :func:`swarmcurves_jax.knots.make_knots`).
    k : int
    closed : bool
    min_samples : int
        Size of the initial dense sampling of a curve.  A polygon's (``k`` 1) is its
        corners: its segments are its own chords, and Newton on a segment is exact.

    Returns
    -------
    dist : ndarray, shape (N,)
    u : ndarray, shape (N,)
    """
    points, t = np.asarray(points, dtype=np.float64), np.asarray(t, dtype=np.float64)
    num_spans = len(breakpoints(t)) - 1
    # At least the three chords ranked (W1's seven polygons: 24 -> 11 ms, the same
    # distances to 1e-16)
    per_span = -(-3 // num_spans) if k == 1 else max(8, -(-min_samples // num_spans))
    design_of = _dense_design if len(ctrl) <= 32 else _dense_design.__wrapped__
    grid, design = design_of(t.tobytes(), k, closed, per_span)
    samples = _rational([design], ctrl, weights)[0]
    cand, cand_d2 = _nearest_chords(points, samples)  # intervals [grid[i], grid[i+1]]
    curve = (ctrl, weights, t, k, closed)
    # the gaps cost two evaluations at every interval's ends: worth it for many points
    gaps = _arc_gaps(grid, *curve) if len(points) >= len(grid) else None
    if gaps is None:
        return _nearest_in(points, cand, grid, samples, curve)
    # Newton in the nearest chord's interval first; another ranked interval holds no
    # nearer point than its chord's distance less its arc's gap from the chord
    dist, foot = _nearest_in(points, cand[:, :1], grid, samples, curve)
    chord = np.sqrt(cand_d2[:, 1:])
    near = chord - gaps[cand[:, 1:]] <= dist[:, None] + 1e-9 * (dist[:, None] + chord)
    rows, cols = np.nonzero(near)
    d, u = _nearest_in(points[rows], cand[rows, cols + 1][:, None], grid, samples, curve)
    for col in range(near.shape[1]):  # in rank order, a tie keeping the earlier
        at = np.flatnonzero(cols == col)
        at = at[d[at] < dist[rows[at]]]
        dist[rows[at]], foot[rows[at]] = d[at], u[at]
    return dist, foot


def _nearest_in(points, cand, grid, samples, curve):
    """Each point's nearest point of the curve in its intervals ``[grid[i], grid[i+1]]``,
    ``i`` in ``cand`` (N, C): its distance and parameter, over Newton's point and each
    interval's ends (the ``samples`` at the grid)."""
    lo, hi = grid[cand], grid[cand + 1]
    p = np.repeat(points[:, None, :], cand.shape[1], axis=1).reshape(-1, points.shape[1])
    lo, hi = lo.ravel(), hi.ravel()
    u = 0.5 * (lo + hi)
    ctrl, weights, t, k, closed = curve
    # Every interval lies in one span: Newton runs on that span's polynomial, also at the
    # interval's right end, a knot, where find_span would give the next span (at a
    # polygon's corner its derivative sent Newton back and forth for all its steps).
    u = _newton(u, lo, hi, find_span(lo, t, k), p, curve)
    # The foot is Newton's point or an interval's end, whichever is nearest; the ends are
    # the dense samples themselves (the same evaluation, at the grid)
    newton = curve_derivatives(u, ctrl, weights, t, k, closed, max_nu=0)[0]
    c = np.stack([newton, samples[cand.ravel()], samples[cand.ravel() + 1]], axis=1)
    width = 3 * cand.shape[1]
    d = np.linalg.norm(c - p[:, None, :], axis=2).reshape(len(points), width)
    cands = np.stack([u, lo, hi], axis=1).reshape(len(points), width)
    best = np.argmin(d, axis=1)
    rows = np.arange(len(points))
    return d[rows, best], cands[rows, best]


def _arc_gaps(grid, ctrl, weights, t, k, closed):
    """How far the curve can stray from the chord of each interval ``[grid[i],
    grid[i+1]]`` (one span's polynomial): ``(hi - lo)^2 / 8`` times the largest
    ``|C''|`` there, which for a polynomial of degree 3 or less (``C''`` linear) is at an
    end; None for a rational curve or a higher degree.  Measured on a warm ``fit`` of f4
    at 100,000 points, its host work run serially: Newton 9.8 -> 4.5 s, the call 25.5 ->
    16.4 s (the same curves, their errors bit for bit)."""
    if k > 3 or np.any(np.asarray(weights) != weights[0]):
        return None
    lo, hi = grid[:-1], grid[1:]
    span = find_span(lo, t, k)
    ends = [curve_derivatives(u, ctrl, weights, t, k, closed, span=span)[2] for u in (lo, hi)]
    bend = np.maximum(*(np.linalg.norm(c2, axis=1) for c2 in ends))
    return (hi - lo) ** 2 / 8.0 * bend
