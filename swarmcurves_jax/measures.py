"""Two-sided measures of a fit: does the curve stay with the data, both ways?

The one-sided ``error`` (data point -> curve) cannot see a stretch of curve that no data
point projects onto: a loop or a spike between two samples.  So every fit is also measured
the other way, every point of the curve -> the polyline ``L`` through the data in order (a
closed polygon for a closed curve), and judged by both:

* ``max_deviation``: the Hausdorff distance between the curve and ``L``,
  ``max(max_i dist(x_i, C), max_t dist(C(t), L))``;
* ``mean_deviation``: ``(error + arc-length mean over t of dist(C(t), L)) / 2``.

Neither sees a curve that doubles back and forth inside a band of noisy data: it passes
nearer the points than one that follows them, and near the polyline, which zig-zags across
the band.  The data's order does: ``order_gap`` (:func:`order_gap`).

``L``'s own chord error (the sagitta of the data between two samples) is part of the
curve -> polyline distance: small for dense data, but where the data turn sharply between
two samples (a cusp's tip) ``L`` cuts the corner, and a curve that follows the data there
is measured away from them.  ``corner_max`` and ``corner_mean`` allow for such corners
(:func:`corners`): the selection judges by them; the reported measures are ``L``'s.
Float64 NumPy, on the host.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from .projection import (
    curve_derivatives,
    dense_parameters,
    distance_to_polyline,
    segment_distances,
)

__all__ = [
    "Deviations",
    "corner_distances",
    "corners",
    "crossings",
    "curve_polyline",
    "data_polyline",
    "deviations",
    "excursions",
    "median_spacing",
    "order_gap",
    "scatter",
    "sample_excursions",
    "turning",
]

#: Initial samples per knot span of the curve; then refined where the curve bends or
#: runs fast (:func:`curve_polyline`).
SAMPLES_PER_SPAN = 64
#: The refined sampling's chords are at most this fraction of the data's median spacing
#: and turn by at most this many radians: the sampled maximum of a 1-Lipschitz distance
#: is then within an eighth of a data spacing of the true one (far less where it is smooth).
CHORD_FRACTION, MAX_TURN = 0.25, 0.05
#: Most samples of one curve (a huge excursion is still measured, only more coarsely).
MAX_SAMPLES = 200_000


class Deviations(NamedTuple):
    """Both directions of a fit's distance to its data (the frame of the inputs)."""

    max_deviation: float  # Hausdorff distance between curve and data polyline
    mean_deviation: float  # (mean data -> curve + arc-length mean curve -> polyline) / 2
    max_excursion: float  # max over the curve of its distance to the data polyline
    mean_excursion: float  # arc-length mean of the same
    rms_excursion: float  # arc-length root mean square of the same
    turning: float  # the curve's total turning, radians (a fold or a loop adds about pi)
    crossings: int  # how often the curve crosses itself (2D; a 3D curve: 0)
    corner_max: float  # max_deviation, the data's corners between samples allowed for
    corner_mean: float  # mean_deviation, the same
    order_gap: float  # mean data -> curve distance in the data's order, less error (0 unmeasured)


def data_polyline(points: np.ndarray, closed: bool) -> np.ndarray:
    """The vertices of the polyline through the data in order (closed: back to the first)."""
    points = np.asarray(points, dtype=np.float64)
    return np.vstack([points, points[:1]]) if closed else points


def median_spacing(points: np.ndarray, closed: bool) -> float:
    """The median length of the data polyline's segments (the unit of its sampling)."""
    seg = np.linalg.norm(np.diff(data_polyline(points, closed), axis=0), axis=1)
    seg = seg[seg > 0]
    return float(np.median(seg)) if len(seg) else 1.0


def curve_polyline(ctrl, weights, t, k, closed, spacing: float) -> np.ndarray:
    """The curve densely sampled, in order (M, D): :data:`SAMPLES_PER_SPAN` per knot span,
    then every interval whose chord is longer than ``CHORD_FRACTION * spacing`` or whose
    neighbouring chords turn by more than :data:`MAX_TURN` split, up to three rounds."""
    u = dense_parameters(np.asarray(t, dtype=np.float64), SAMPLES_PER_SPAN)
    pts = None
    for _ in range(4):
        pts = curve_derivatives(u, ctrl, weights, t, k, closed, max_nu=0)[0]
        chord = np.diff(pts, axis=0)
        length = np.linalg.norm(chord, axis=1)
        pieces = np.ceil(length / (CHORD_FRACTION * spacing))
        if len(chord) > 1:
            unit = chord / np.maximum(length, 1e-300)[:, None]
            turn = np.arccos(np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1.0, 1.0))
            bend = np.ceil(turn / MAX_TURN)
            pieces = np.maximum(pieces, np.maximum(np.r_[bend, 1.0], np.r_[1.0, bend]))
        pieces = np.clip(pieces, 1, 64).astype(np.int64)
        if np.all(pieces == 1) or len(u) + np.sum(pieces - 1) > MAX_SAMPLES:
            break
        steps = np.repeat(np.diff(u) / pieces, pieces)
        starts = np.repeat(u[:-1], pieces)
        offsets = np.arange(len(steps)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        u = np.append(starts + offsets * steps, u[-1])
    return pts


def excursions(points, ctrl, weights, t, k, closed) -> tuple[float, float, float]:
    """``(max, arc-length mean, arc-length RMS)`` over the curve of its distance to the
    data polyline."""
    samples = _dense(points, ctrl, weights, t, k, closed)
    return sample_excursions(samples, data_polyline(points, closed))


def _dense(points, ctrl, weights, t, k, closed) -> np.ndarray:
    """The curve sampled densely at the data's scale (:func:`curve_polyline`)."""
    points = np.asarray(points, dtype=np.float64)
    return curve_polyline(ctrl, weights, t, k, closed, median_spacing(points, closed))


def turning(vertices: np.ndarray, closed: bool) -> float:
    """The total turning of the polyline through ``vertices`` in order (closed: also at
    its first vertex), radians: the sum of the angles between consecutive chords,
    zero-length chords skipped.  A closed convex curve turns ``2 pi``; a loop, a fold
    or a cusp-like horn adds about ``pi`` or more, whatever its size."""
    chords = np.diff(data_polyline(vertices, closed), axis=0)
    length = np.linalg.norm(chords, axis=1)
    unit = chords[length > 0] / length[length > 0, None]
    if closed and len(unit):
        unit = np.vstack([unit, unit[:1]])
    cosines = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1.0, 1.0)
    return float(np.sum(np.arccos(cosines)))


def crossings(vertices: np.ndarray, closed: bool) -> int:
    """How often the polyline through ``vertices`` in order (closed: back to the first)
    crosses itself: pairs of non-adjacent chords that cross properly (touching and
    overlapping chords do not count).  A 3D polyline: 0 (a loop in space need not cross;
    the turning sees it).  A curve that crosses itself where its data do not has made a
    loop whose turning may replace the data's own, so the turning alone can miss it.

    The chords are cut into pieces about as long as the median chord (:func:`_pieces`; a
    piece's crossings are its chord's, a chord of length zero crosses nothing), and only
    pieces whose middles lie within one piece's length of each other are tested (a k-d
    tree, :func:`_near_pairs`): linear in the vertices for a curve that does not pile up
    on itself."""
    pts = data_polyline(vertices, closed)
    if pts.shape[1] != 2 or len(pts) < 4 or not np.all(np.isfinite(pts)):
        return 0  # a curve with non-finite samples: its other measures say so (nan)
    a, b, chord = _pieces(pts)
    if len(chord) < 2:
        return 0
    i, j = _near_pairs(0.5 * (a + b), float(np.max(np.linalg.norm(b - a, axis=1))))
    apart = chord[j] - chord[i] > 1  # pieces of one chord or of neighbours meet at ends
    if closed:
        apart &= (chord[i] != 0) | (chord[j] != len(pts) - 2)  # the seam's two chords meet
    i, j = i[apart], j[apart]
    d1, d2 = _side(a[i], b[i], a[j]), _side(a[i], b[i], b[j])
    d3, d4 = _side(a[j], b[j], a[i]), _side(a[j], b[j], b[i])
    return int(np.sum((d1 * d2 < 0) & (d3 * d4 < 0)))


#: More pairs than this per piece is a pile-up (a scan's dwell: thousands of points within
#: one chord's length); each piece is then paired with its :data:`NEAREST` nearest only.
MAX_PAIRS_PER_PIECE, NEAREST = 32, 16
#: How many pieces, evenly strided, :func:`_near_pairs` counts the neighbours of first;
#: up to this many pieces every pair within reach is listed (at most half a million).
PROBES = 1000


def _near_pairs(mid: np.ndarray, reach: float):
    """Index pairs ``i < j`` of the points ``mid`` within ``reach`` of each other; where
    they pile up (more than :data:`MAX_PAIRS_PER_PIECE` a point, judged on every
    ``n / PROBES``-th point), only the pairs among each point's :data:`NEAREST` nearest
    within ``reach``, so that the pairs never outgrow memory (the crossings counted
    there are a lower bound).  A pile-up the probes miss holds fewer than ``n / PROBES``
    points, and its pairs are few; up to :data:`PROBES` points, every pair is listed."""
    n = len(mid)
    tree = cKDTree(mid, balanced_tree=False, compact_nodes=False)  # quicker to build
    if n <= PROBES:
        return tree.query_pairs(reach, output_type="ndarray").T
    probes = cKDTree(mid[:: n // PROBES])
    # ordered pairs, each probe with itself included, counted without being listed
    if probes.count_neighbors(tree, reach) <= (2 * MAX_PAIRS_PER_PIECE + 1) * probes.n:
        return tree.query_pairs(reach, output_type="ndarray").T
    _, near = tree.query(mid, k=NEAREST, distance_upper_bound=reach)
    i, j = np.repeat(np.arange(n), NEAREST), near.ravel()
    keep = (j < n) & (j > i)  # j == n: fewer than NEAREST within reach
    return i[keep], j[keep]


def _pieces(pts: np.ndarray):
    """The chords of the polyline ``pts`` of non-zero length, cut into equal pieces of at
    most twice the median chord, or of a quarter of the mean chord where that is longer
    (at most five pieces a chord on average, however the chords' lengths spread):
    ``(starts, ends, chord index of each piece)``."""
    length = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    positive = length[length > 0]
    if not len(positive):
        return pts[:0], pts[:0], np.arange(0)
    longest = max(2.0 * float(np.median(positive)), float(np.mean(length)) / 4.0)
    cuts = np.ceil(length / longest).astype(np.int64)  # 0 for a chord of length zero
    if np.all(cuts == 1):
        return pts[:-1], pts[1:], np.arange(len(length))
    chord = np.repeat(np.arange(len(length)), cuts)
    step = np.arange(len(chord)) - np.repeat(np.cumsum(cuts) - cuts, cuts)
    frac = (step / cuts[chord])[:, None]
    span = (pts[1:] - pts[:-1])[chord]
    return pts[chord] + frac * span, pts[chord] + (frac + 1.0 / cuts[chord][:, None]) * span, chord


def _side(a, b, c) -> np.ndarray:
    """Which side of the line through ``a`` and ``b`` each ``c`` lies on (the sign of the
    2D cross product; 0 on the line)."""
    return np.sign(_cross(b - a, c - a))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The 2D cross products of the rows of ``a`` and ``b``."""
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def sample_excursions(samples, polyline) -> tuple[float, float, float]:
    """``(max, arc-length mean, arc-length RMS)`` of the distances from a densely sampled
    curve ``samples`` (M, D), in order, to the polyline with vertices ``polyline`` (a
    single vertex: the distance to that point)."""
    samples = np.asarray(samples, dtype=np.float64)
    return _along(samples, distance_to_polyline(samples, np.asarray(polyline, dtype=np.float64)))


def _along(samples: np.ndarray, d: np.ndarray) -> tuple[float, float, float]:
    """``(max, arc-length mean, arc-length RMS)`` of ``d`` (M,) over the sampled curve."""
    arc = np.linalg.norm(np.diff(samples, axis=0), axis=1)
    total = float(np.sum(arc))
    if total > 0:
        mean = float(np.sum(0.5 * (d[1:] + d[:-1]) * arc) / total)
        rms = math.sqrt(float(np.sum(0.5 * (d[1:] ** 2 + d[:-1] ** 2) * arc) / total))
    else:
        mean = rms = float(d[0])
    return float(np.max(d)), mean, rms


#: A corner between two samples (:func:`corners`) counts where the lines of the chords on
#: either side of a chord meet at least this many of its lengths off it: where the data
#: turn by about a right angle or more across one chord.
CORNER_HEIGHT = 0.5


def corners(points, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """The data's corners between two samples, ``(chord, apex)``: the index (T,) of the
    chord of the data polyline (:func:`data_polyline`) that cuts each, and where the lines
    of the chords before and after it meet (T, 2), each continued beyond the chord's ends
    by at most its own length, and at least :data:`CORNER_HEIGHT` of the chord's length
    off it.

    A sharp peak sampled on both sides of its tip (f3's cusp) has its tip there, beyond
    the chord between the two samples: a curve that follows the data's own slopes up to
    the tip leaves the polyline there (by 0.046 at f3's tip, normalised) and is no farther
    from the data for it.  Dense samples of a smooth curve, and corners that are sampled
    (the turn at a point), have none.  2D only (a 3D curve: none)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 4:
        return np.zeros(0, dtype=np.int64), pts[:0, :2]
    ext = np.vstack([pts[-1:], pts, pts[:2]]) if closed else pts
    before, p, q, after = ext[:-3], ext[1:-2], ext[2:-1], ext[3:]
    d1, d2, w = p - before, q - after, q - p
    det = _cross(d1, -d2)
    ok = np.abs(det) > 1e-300
    det = np.where(ok, det, 1.0)
    s, r = _cross(w, -d2) / det, _cross(d1, w) / det
    apex = p + s[:, None] * d1
    length = np.linalg.norm(w, axis=1)
    height = np.abs(_cross(w, apex - p)) / np.maximum(length, 1e-300)
    keep = ok & (s > 0) & (s <= 1) & (r > 0) & (r <= 1) & (height >= CORNER_HEIGHT * length)
    chord = np.flatnonzero(keep) + (0 if closed else 1)
    return chord, apex[keep]


def corner_distances(samples, polyline, d: np.ndarray, found) -> np.ndarray:
    """The distances ``d`` (M,) of the curve's ``samples`` (M, 2) to the data ``polyline``
    with the data's :func:`corners` ``found`` allowed for: the distance to the polyline and
    the corners' triangles together (zero inside a triangle).  Only the (sample, corner)
    pairs where the triangle could lie nearer than ``d`` are measured (a k-d tree of their
    centres)."""
    chord, apex = found
    if not len(chord):
        return d
    p, q = polyline[chord], polyline[chord + 1]
    centre = (p + apex + q) / 3.0
    reach = np.max(np.linalg.norm(np.stack([p, apex, q]) - centre, axis=2), axis=0)
    near = cKDTree(centre).query_ball_point(samples, reach.max() + d)
    sample = np.repeat(np.arange(len(samples)), [len(n) for n in near])
    corner = np.fromiter((j for n in near for j in n), dtype=np.int64, count=len(sample))
    x = samples[sample]
    keep = np.linalg.norm(x - centre[corner], axis=1) - reach[corner] < d[sample]
    sample, corner, x = sample[keep], corner[keep], x[keep]
    a, b, c = p[corner], apex[corner], q[corner]
    sides = np.stack([_side(a, b, x), _side(b, c, x), _side(c, a, x)])
    inside = np.all(sides >= 0, axis=0) | np.all(sides <= 0, axis=0)
    pairs = np.stack([corner, corner + len(p)], axis=1)  # its two outer sides
    outer = np.min(segment_distances(x, np.vstack([p, apex]), np.vstack([apex, q]), pairs), 1)
    out = d.copy()
    np.minimum.at(out, sample, np.where(inside, 0.0, outer))
    return out


def deviations(points, ctrl, weights, t, k, closed, data_distances, feet=None) -> Deviations:
    """The two-sided measures of a curve (``ctrl`` in the frame of ``points``), given its
    data -> curve distances ``data_distances`` (N,) (:func:`~.projection.project_points`);
    given the points' foot parameters ``feet`` (N,) too, also its :func:`order_gap`."""
    samples = _dense(points, ctrl, weights, t, k, closed)
    polyline = data_polyline(points, closed)
    d = distance_to_polyline(samples, polyline)
    far, mean, rms = _along(samples, d)
    allowed = corner_distances(samples, polyline, d, corners(points, closed))
    far_c, mean_c, _ = _along(samples, allowed)
    dist = np.asarray(data_distances, dtype=np.float64)
    vertices = samples[:-1] if closed else samples  # a closed curve's last sample repeats
    gap = 0.0 if feet is None else order_gap(points, samples, closed, feet)
    return Deviations(
        max_deviation=max(float(np.max(dist)), far),
        mean_deviation=0.5 * (float(np.mean(dist)) + mean),
        max_excursion=far,
        mean_excursion=mean,
        rms_excursion=rms,
        turning=turning(vertices, closed),
        crossings=crossings(vertices, closed),
        corner_max=max(float(np.max(dist)), far_c),
        corner_mean=0.5 * (float(np.mean(dist)) + mean_c),
        order_gap=gap,
    )


#: The most points and (point, chord) pairs :func:`order_gap` aligns; beyond them the
#: points and the curve's chords are thinned evenly (order survives thinning).
ORDER_POINTS, ORDER_PAIRS = 300, 100_000


def order_gap(points, samples, closed: bool, feet=None) -> float:
    """How much farther, on average, the data lie from the curve when it must pass them in
    their order (either way along it; round a closed curve from wherever they start on it,
    at most twice round) than when each point takes its nearest point of the curve: zero
    for a curve that follows the data.

    A curve that runs back and forth across a band of noisy points passes nearer them than
    one that follows them, so its error and both deviations are the smaller (100 points
    along a line, noise twice their spacing, 6 control points: a Z the line's length, mean
    deviation 0.0179 against 0.0190 for a curve that follows them), and its gap exceeds
    its error (0.019 against 0.015).  ``samples``: the curve densely sampled in
    order (:func:`curve_polyline`); ``feet``, if given: the points' foot parameters,
    which settle the common case, feet already in order (no alignment needed).
    Otherwise the least sum of point-to-chord distances over the assignments of points
    to the curve's chords in order, by dynamic programming, less the sum of each point's
    nearest chord distance, over the point count (at most :data:`ORDER_POINTS` points)."""
    if feet is not None and _in_order(np.asarray(feet, dtype=np.float64), closed):
        return 0.0
    points = np.asarray(points, dtype=np.float64)
    pts = points[:: -(-len(points) // ORDER_POINTS)]
    verts = np.asarray(samples, dtype=np.float64)
    stride = -(-(len(verts) - 1) * len(pts) // ORDER_PAIRS)
    verts = np.vstack([verts[:-1:stride], verts[-1:]]) if stride > 1 else verts
    cost = segment_distances(pts, verts[:-1], verts[1:])
    free = float(np.sum(np.min(cost, axis=1)))
    ordered = min(_aligned(cost, closed), _aligned(cost[:, ::-1], closed))
    return max(ordered - free, 0.0) / len(pts)


def scatter(points: np.ndarray, closed: bool) -> float:
    """How far the data zig-zag: the mean distance of each point from the chord of its two
    neighbours (an open polyline's ends have none).  Noise makes it about the noise's
    size; dense points of a smooth outline leave only their sagitta, a few thousandths of
    the frame or less."""
    pts = data_polyline(points, closed)
    if closed:
        pts = np.vstack([pts[-2:-1], pts])  # the first point's neighbours: last and second
    if len(pts) < 3:
        return 0.0
    own = np.arange(len(pts) - 2)[:, None]  # each point against its neighbours' chord
    return float(np.mean(segment_distances(pts[1:-1], pts[:-2], pts[2:], own)))


def _in_order(feet: np.ndarray, closed: bool) -> bool:
    """Whether the foot parameters (in [0, 1]) never step back along the curve (either way
    along it; closed: once round, each step the shorter way)."""
    steps = np.diff(np.append(feet, feet[:1]) if closed else feet)
    if closed:
        steps = (steps + 0.5) % 1.0 - 0.5
        once = abs(abs(np.sum(steps)) - 1.0) < 1e-6
        return bool(once and (np.all(steps >= 0) or np.all(steps <= 0)))
    return bool(np.all(steps >= 0) or np.all(steps <= 0))


def _aligned(cost: np.ndarray, closed: bool) -> float:
    """The least sum of ``cost[i, j_i]`` over chords ``j_0 <= j_1 <= ...``; closed: the
    chords twice round, starting in the first round (so wherever the data start on the
    curve; a curve that runs back may step forward round the curve instead, once)."""
    run = cost[0]
    if closed:
        run = np.concatenate([run, np.full_like(run, np.inf)])
        cost = np.tile(cost, 2)
    for row in cost[1:]:
        run = row + np.minimum.accumulate(run)
    return float(np.min(run))
