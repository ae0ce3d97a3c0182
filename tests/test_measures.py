"""The two-sided measures (host) and the excursion penalty (device) on curves whose answers
are known in closed form."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmcurves_jax import Curve
from swarmcurves_jax.datasets import random_bspline_points
from swarmcurves_jax.excursions import data_segments, excursion
from swarmcurves_jax.knots import make_knots
from swarmcurves_jax.measures import (
    corner_distances,
    corners,
    crossings,
    curve_polyline,
    deviations,
    excursions,
    median_spacing,
    order_gap,
    sample_excursions,
)
from swarmcurves_jax.projection import distance_to_polyline, project_points
from swarmcurves_jax.span_basis import curve_samples, make_span_basis


def _measure(curve: Curve, points):
    dist, _ = project_points(
        points, curve.control_points, curve.weights, curve.knots, curve.degree, curve.closed
    )
    return dist, deviations(
        points, curve.control_points, curve.weights, curve.knots, curve.degree, curve.closed, dist
    )


def test_a_spike_between_two_points_is_seen_only_both_ways():
    """A polygon through both data points with a corner 5 above the middle: the data error
    is 0, the largest deviation is the corner's height."""
    spike = Curve(1, [[0, 0], [0.5, 5], [1, 0]], np.ones(3), make_knots(3, 1, False))
    points = np.array([[0.0, 0.0], [1.0, 0.0]])
    dist, dev = _measure(spike, points)
    assert np.max(dist) < 1e-12
    assert dev.max_deviation == pytest.approx(5.0, abs=1e-9)
    assert dev.max_excursion == pytest.approx(5.0, abs=1e-9)
    # arc-length mean of the height along the two legs of the tent: half the corner's
    assert dev.mean_excursion == pytest.approx(2.5, rel=1e-6)
    assert dev.mean_deviation == pytest.approx(1.25, rel=1e-6)


def test_a_parabola_over_its_chord_has_the_exact_deviations():
    """The quadratic Bezier (0,0), (1/2,h), (1,0) over data on its chord: height y(x) =
    2h x (1 - x), largest h/2; its arc-length mean height by quadrature."""
    h = 0.2
    arc = Curve(2, [[0, 0], [0.5, h], [1, 0]], np.ones(3), make_knots(3, 2, False))
    points = np.c_[np.linspace(0, 1, 101), np.zeros(101)]
    dist, dev = _measure(arc, points)
    assert dev.max_deviation == pytest.approx(h / 2, rel=1e-6)
    t = np.linspace(0, 1, 400_001)
    xy = arc.evaluate(t)
    ds = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    mean_height = np.sum(0.5 * (xy[1:, 1] + xy[:-1, 1]) * ds) / np.sum(ds)
    # the measure's chords are at most a quarter of the data spacing: trapezoids to 1e-5
    assert dev.mean_excursion == pytest.approx(mean_height, rel=2e-5)
    assert dev.mean_deviation == pytest.approx(0.5 * (dist.mean() + mean_height), rel=2e-5)


def test_a_closed_curve_is_measured_against_the_closed_polygon():
    """A circle-like closed cubic on its own dense samples: the closing chord is part of
    the polygon, so the curve never strays more than the sagitta of one chord."""
    angles = np.linspace(0, 2 * np.pi, 9)[:-1]
    ctrl = np.c_[np.cos(angles), np.sin(angles)]
    ring = Curve(3, ctrl, np.ones(8), make_knots(8, 3, True), closed=True)
    points = ring.evaluate(np.linspace(0, 1, 400, endpoint=False))
    _, dev = _measure(ring, points)
    step = np.max(np.linalg.norm(np.diff(np.vstack([points, points[:1]]), axis=0), axis=1))
    assert dev.max_excursion < step**2  # sagitta h^2 / (8 r), r < 1
    # a tenth of the ring without data: the closing chord spans it, within its sagitta
    # (r (1 - cos 18 deg) < 0.05), where an open polyline would leave the arc bare
    gap = points[:-40]
    _, gap_dev = _measure(ring, gap)
    assert 0.02 < gap_dev.max_excursion < 0.05
    dense = curve_polyline(ring.control_points, ring.weights, ring.knots, 3, True, 0.01)
    assert np.max(distance_to_polyline(dense, gap)) > 0.1


def test_the_dense_sampling_follows_a_fast_stretch():
    """A curve whose middle control point is far away: the refinement splits the long
    chords, so no chord is longer than a quarter of the data's spacing."""
    far = Curve(2, [[0, 0], [0.5, 50], [1, 0]], np.ones(3), make_knots(3, 2, False))
    samples = curve_polyline(far.control_points, far.weights, far.knots, 2, False, 0.01)
    chords = np.linalg.norm(np.diff(samples, axis=0), axis=1)
    assert chords.max() <= 0.0025 * (1 + 1e-9)
    far_max, _, _ = excursions(np.array([[0.0, 0.0], [1.0, 0.0]]), far.control_points,
                               far.weights, far.knots, 2, False)
    assert far_max == pytest.approx(25.0, rel=1e-6)


def _penalty(curve: Curve, points, closed, pad=0):
    pts = np.vstack([points, np.repeat(points[-1:], pad, axis=0)])
    mask = np.r_[np.ones(len(points)), np.zeros(pad)]
    basis = make_span_basis(curve.n_ctrl, curve.degree, closed, 64)
    basis = type(basis)(*(jnp.asarray(a) for a in basis))
    line = data_segments(pts.astype(np.float32), mask, closed)
    return float(_excursion(jnp.asarray(curve.control_points), basis, line))


@jax.jit
def _excursion(ctrl, basis, line):
    samples, tangents = curve_samples(ctrl, None, basis)
    return excursion(samples, tangents, basis, line)


def test_the_penalty_is_zero_on_the_curve_the_data_sample_and_sees_a_spike():
    rng = np.random.default_rng(3)
    for closed in (False, True):
        n = 7
        truth = Curve(3, rng.uniform(-1, 1, (n, 2)), np.ones(n), make_knots(n, 3, closed), closed=closed)
        points = truth.evaluate(np.linspace(0, 1, 150, endpoint=not closed))
        assert _penalty(truth, points, closed) < 1e-12  # sqrt(0 + 1e-30)
        assert _penalty(truth, points, closed, pad=10) < 1e-12  # padding is no segment
        bent = truth.control_points.copy()
        bent[3] += [3.0, 3.0]
        spiked = Curve(3, bent, np.ones(n), truth.knots, closed=closed)
        assert _penalty(spiked, points, closed) > 0.1


def test_sample_excursions_of_a_peer_curve_are_arc_length_weighted():
    """Samples of any curve against any polyline: over the x axis, a path 3 units along
    y = 1, 1 unit down (mean distance 1/2) and 1 unit along y = 0, 5 units in all: max 1,
    arc mean (3 * 1 + 1 * 1/2 + 1 * 0) / 5, RMS by the same weights (the drop's mean
    square, by the trapezoid rule, also 1/2)."""
    samples = np.array([[0.0, 1.0], [3.0, 1.0], [3.0, 0.0], [4.0, 0.0]])
    polyline = np.array([[-1.0, 0.0], [5.0, 0.0]])
    far, mean, rms = sample_excursions(samples, polyline)
    assert far == 1.0
    assert mean == pytest.approx((3 * 1 + 1 * 0.5 + 1 * 0) / 5)
    assert rms == pytest.approx(np.sqrt((3 * 1 + 1 * 0.5 + 0) / 5))
    assert median_spacing(np.array([[0, 0], [1, 0], [3, 0], [6, 0]]), closed=False) == 2.0


def _every_crossing(vertices, closed) -> int:
    """Proper crossings of a polyline's non-adjacent chords, every pair tested."""
    pts = np.vstack([vertices, vertices[:1]]) if closed else vertices
    m = len(pts) - 1

    def side(a, b, c):
        return np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    count = 0
    for i in range(m):
        for j in range(i + 2, m - (closed and i == 0)):
            a, b, c, d = pts[i], pts[i + 1], pts[j], pts[j + 1]
            count += bool(side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0)
    return count


@given(st.integers(0, 2**32 - 1), st.integers(3, 40), st.booleans(), st.floats(1.0, 100.0))
def test_crossings_are_every_pair_of_chords_that_cross(seed, n, closed, spread):
    """Random walks whose steps differ in length by up to ``spread`` times (long chords
    are cut into pieces before the search): the count equals the pairs of non-adjacent
    chords that cross, every pair tested."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(n, 2)) * np.exp(rng.uniform(0, np.log(spread), size=(n, 1)))
    walk = np.cumsum(steps, axis=0)
    assert crossings(walk, closed) == _every_crossing(walk, closed)


def test_crossings_of_known_curves():
    """A figure of eight crosses itself once, a circle and a spiral's open arc never, a
    limacon with an inner loop once (at the origin); two chords that share an end do
    not cross, a 3D curve is not counted (a loop in space need not cross), nor a polyline
    with a non-finite vertex."""
    t = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    assert crossings(np.c_[np.sin(2 * t), np.sin(t)], True) == 1
    assert crossings(np.c_[np.cos(t), np.sin(t)], True) == 0
    u = np.linspace(0, 1, 20000)
    assert crossings(np.c_[u * np.cos(40 * u), u * np.sin(40 * u)], False) == 0
    r = 0.5 + np.cos(t)
    assert crossings(np.c_[r * np.cos(t), r * np.sin(t)], True) == 1
    assert crossings(np.array([[0, 0], [1, 0], [1, 1], [0, 0.0]]), False) == 0
    helix = np.c_[np.cos(t), np.sin(t), t]
    assert crossings(helix, False) == 0
    nan = np.array([[0.0, 0.0], [1.0, 1.0], [np.nan, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert crossings(nan, False) == 0


def test_crossings_of_a_pile_up_are_counted_in_bounded_memory():
    """A scan that dwells: 30,000 points creeping along 1e-4 between a figure of eight
    (4,000 points, one crossing) and a straight leg; and 100,000 copies of one point.
    Pairing every nearby piece would list 4.5e8 pairs at the dwell; each piece there is
    paired with its 16 nearest instead, and the eight's crossing is still found.  Copies
    of one point have no chord to cross."""
    assert crossings(np.zeros((100_000, 2)), False) == 0
    assert crossings(np.zeros((100_000, 2)), True) == 0
    t = np.linspace(0.3, 2 * np.pi + 0.2, 4000)
    eight = np.c_[np.sin(2 * t), np.sin(t)]
    dwell = eight[-1] + np.c_[np.linspace(0, 1e-4, 30_000), np.zeros(30_000)]
    leg = dwell[-1] + np.c_[np.linspace(0, 1, 2000)[1:], np.zeros(1999)]
    assert crossings(np.vstack([eight, dwell, leg]), False) == 1


def _segment_distance(p, a, b) -> float:
    ab = b - a
    s = np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(p - a - s * ab))


def _order_gap_by_enumeration(points, verts, closed) -> float:
    """Every assignment of points to chords in order, tried: the definition of the gap."""
    chords = len(verts) - 1
    cost = np.array(
        [[_segment_distance(p, verts[j], verts[j + 1]) for j in range(chords)] for p in points]
    )
    best = np.inf
    for table in (cost, cost[:, ::-1]):  # either way along the curve
        rounds = 2 * chords if closed else chords  # closed: at most twice round
        for seq in itertools.combinations_with_replacement(range(rounds), len(points)):
            if seq[0] < chords:  # starting in the first round
                best = min(best, sum(table[i, j % chords] for i, j in enumerate(seq)))
    return (best - np.sum(np.min(cost, axis=1))) / len(points)


@settings(max_examples=40, deadline=None)
@given(
    num=st.integers(1, 5),
    chords=st.integers(1, 5),
    closed=st.booleans(),
    seed=st.integers(0, 10_000),
)
def test_the_order_gap_is_the_least_cost_of_passing_the_points_in_order(num, chords, closed, seed):
    """Random points and polylines (closed: a polygon): the dynamic programme's gap equals
    the least over every assignment of points to chords in order, tried one by one."""
    rng = np.random.default_rng(seed)
    points, verts = rng.uniform(-1, 1, (num, 2)), rng.uniform(-1, 1, (chords + 1, 2))
    if closed:
        verts[-1] = verts[0]
    expected = _order_gap_by_enumeration(points, verts, closed)
    assert order_gap(points, verts, closed) == pytest.approx(expected, abs=1e-12)


@settings(max_examples=12, deadline=None)
@given(
    closed=st.booleans(),
    start=st.integers(0, 119),
    backwards=st.booleans(),
    seed=st.integers(0, 10_000),
)
def test_a_curve_through_its_points_in_order_has_no_order_gap(closed, start, backwards, seed):
    """Points of a random cubic in order, a closed one's from any start and either way
    round: the curve passes them in their order, so nothing is lost by asking it to, but
    for the chords' own error where the curve crosses itself (a point's nearest chord on
    the other branch): the chords, thinned to 100,000 point-chord pairs, lie up to 2e-4
    from the points; the gap 1.3e-6 at most over 400 such curves, where a fold costs a
    fraction of the curve's size."""
    points, ctrl = random_bspline_points(7, 3, closed, num_points=120, seed=seed)
    t = make_knots(7, 3, closed)
    samples = curve_polyline(ctrl, np.ones(7), t, 3, closed, median_spacing(points, closed))
    if closed:
        points = np.roll(points, -start, axis=0)
    if backwards:
        points = points[::-1]
    assert order_gap(points, samples, closed) < 1e-5


def test_a_z_across_noisy_points_along_a_line_pays_the_order_gap():
    """Points along a line, each 0.05 above or below it in turn; a polygon along the
    upper row, back, and along the lower row passes through every point (error 0), but
    in their order it can keep only one row: the other half lie 0.1 from it."""
    x = np.linspace(0.0, 1.0, 21)
    points = np.c_[x, np.where(np.arange(21) % 2, -0.05, 0.05)]
    z = np.array([[0.0, 0.05], [1.0, 0.05], [0.0, -0.05], [1.0, -0.05]])
    samples = curve_polyline(z, np.ones(4), make_knots(4, 1, False), 1, False, 0.05)
    assert np.max(distance_to_polyline(points, samples)) < 1e-12
    assert order_gap(points, samples, False) == pytest.approx(0.1 * 10 / 21, rel=1e-9)
    line = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert order_gap(points, line, False) == 0.0


def _tent(num=10):
    """Points on both flanks of the tent ``y = 1 - 2|x|``, none at its tip: the tip lies
    between the two middle samples, 0.21 above their chord."""
    x = np.linspace(-0.95, 0.95, num)
    return np.c_[x, 1.0 - 2.0 * np.abs(x)]


def test_a_peak_between_two_samples_is_a_corner_with_its_tip():
    chord, apex = corners(_tent(), closed=False)
    assert chord.tolist() == [4]  # the chord from the fifth point to the sixth
    np.testing.assert_allclose(apex, [[0.0, 1.0]], atol=1e-12)


def test_smooth_dense_data_and_sampled_corners_have_none():
    u = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    circle = np.c_[np.cos(u), np.sin(u)]
    assert len(corners(circle, closed=True)[0]) == 0
    assert len(corners(_tent(11), closed=False)[0]) == 0  # a sample at the tip
    square = np.array([[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1], [0, 1], [0, 0.5]])
    assert len(corners(square.astype(float), closed=True)[0]) == 0
    helix = np.c_[circle, u]
    assert len(corners(helix, closed=False)[0]) == 0  # 3D: none


def test_a_curve_up_to_the_tip_is_as_near_as_the_data_allow():
    """The tent's tip, a point between it and the chord, a point 0.2 above the tip and a
    point below the chord: zero, zero, 0.2 (to the tip) and the polyline's own distance."""
    points = _tent()
    polyline = points
    samples = np.array([[0.0, 1.0], [0.0, 0.9], [0.0, 1.2], [0.0, 0.7], [0.5, 0.0]])
    d = distance_to_polyline(samples, polyline)
    out = corner_distances(samples, polyline, d, corners(points, False))
    np.testing.assert_allclose(out, [0.0, 0.0, 0.2, d[3], d[4]], atol=1e-12)
    assert d[0] == pytest.approx(1.0 - (1 - 1.9 / 9), rel=1e-12)  # the polyline alone: 0.21


def _union_distance(x, polyline, found):
    """Brute force: the distance from ``x`` to the polyline's chords and the triangles."""
    best = np.min([_segment(x, a, b) for a, b in zip(polyline[:-1], polyline[1:])])
    for i, b in zip(*found):
        a, c = polyline[i], polyline[i + 1]
        sides = [_cross2(v - u, x - u) for u, v in ((a, b), (b, c), (c, a))]
        if min(sides) >= 0 or max(sides) <= 0:
            return 0.0
        best = min(best, _segment(x, a, b), _segment(x, b, c))
    return best


def _cross2(u, v):
    return u[0] * v[1] - u[1] * v[0]


def _segment(x, a, b):
    t = np.clip(np.dot(x - a, b - a) / max(np.dot(b - a, b - a), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(x - a - t * (b - a)))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(4, 30), st.booleans())
def test_corner_distances_are_the_distances_to_polyline_and_corners(seed, num, closed):
    """Zig-zag data (a corner at many chords) and samples scattered over them: the
    distance to the polyline and the corners' triangles together, by brute force."""
    rng = np.random.default_rng(seed)
    points = np.c_[np.linspace(0, 1, num), rng.normal(0, 0.3, num)]
    polyline = np.vstack([points, points[:1]]) if closed else points
    samples = rng.uniform([-0.2, -1.0], [1.2, 1.0], (300, 2))
    found = corners(points, closed)
    d = distance_to_polyline(samples, polyline)
    out = corner_distances(samples, polyline, d, found)
    expected = [_union_distance(x, polyline, found) for x in samples]
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert np.all(out <= d)
