"""True point-to-curve distances: accurate to 1e-7 against a brute-force reference."""

import itertools

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from swarmcurves_jax import make_knots, projection
from swarmcurves_jax.projection import (
    _chord_d2,
    _dense_design,
    _nearest_chords,
    _rational,
    curve_derivatives,
    dense_parameters,
    distance_to_polyline,
    project_points,
)


def brute_force(points, ctrl, w, t, k, closed):
    u = np.linspace(0, 1, 200_001)
    c = curve_derivatives(u, ctrl, w, t, k, closed, max_nu=0)[0]
    out = []
    for p in points:
        d2 = np.sum((c - p) ** 2, axis=1)
        j = int(np.argmin(d2))
        lo, hi = u[max(j - 1, 0)], u[min(j + 1, len(u) - 1)]

        def f(x, p=p):
            return np.sum((curve_derivatives([x], ctrl, w, t, k, closed, 0)[0][0] - p) ** 2)

        res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-14})
        out.append(np.sqrt(min(res.fun, d2[j])))
    return np.array(out)


@given(st.integers(1, 5), st.booleans(), st.booleans(), st.integers(0, 10_000))
def test_projection_matches_brute_force(k, closed, rational, seed):
    rng = np.random.default_rng(seed)
    n = k + 1 + int(rng.integers(0, 5))
    ctrl = rng.uniform(-1, 1, (n, 2))
    w = rng.uniform(0.3, 3.0, n) if rational else np.ones(n)
    t = make_knots(n, k, closed)
    pts = rng.uniform(-1.2, 1.2, (6, 2))
    dist, u = project_points(pts, ctrl, w, t, k, closed)
    np.testing.assert_allclose(dist, brute_force(pts, ctrl, w, t, k, closed), atol=1e-7)
    foot = curve_derivatives(u, ctrl, w, t, k, closed, max_nu=0)[0]
    np.testing.assert_allclose(np.linalg.norm(foot - pts, axis=1), dist, atol=1e-12)


@given(st.integers(0, 10_000), st.sampled_from([1.2, 5.0, 50.0]))
def test_nearest_chords_are_those_of_every_chord(seed, spread):
    """The k-d tree's chords, asked again with more samples where unsure (far points: all
    16 nearest samples on one side), are the three a search of every chord ranks first."""
    rng = np.random.default_rng(seed)
    ctrl = rng.uniform(-1, 1, (7, 2))
    t = make_knots(7, 3, False)
    samples = curve_derivatives(dense_parameters(t, 100), ctrl, np.ones(7), t, 3, False, 0)[0]
    pts = rng.uniform(-spread, spread, (200, 2))
    _assert_top_chords(pts, samples)


def test_nearest_chords_reach_a_long_chord_past_dense_samples():
    """A point whose 16 nearest samples lie in a dense cluster while a long chord passes
    nearer: the first answer is unsure and the chord is found when asked again."""
    cluster = np.c_[1.0 + 1e-3 * np.arange(100), np.zeros(100)]
    samples = np.r_[cluster, [[-5.0, 0.5], [5.0, 0.5]]]
    pts = np.array([[0.0, 0.4], [0.3, 0.45], [1.05, 0.01]])
    _assert_top_chords(pts, samples)
    assert _nearest_chords(pts, samples)[0][0].tolist().count(100) == 1  # the long chord


def _segment_distances(pts, vertices):
    """Every point's distance to every segment (N, M - 1), written independently."""
    out = np.empty((len(pts), len(vertices) - 1))
    for j, (a, b) in enumerate(itertools.pairwise(vertices)):
        ab = b - a
        s = np.clip((pts - a) @ ab / (ab @ ab), 0, 1) if ab @ ab > 0 else np.zeros(len(pts))
        out[:, j] = np.hypot(*(pts - a - s[:, None] * ab).T)
    return out


@given(st.integers(0, 10_000), st.integers(2, 40), st.sampled_from([0.01, 1.0, 30.0]))
@example(642, 2, 0.01)  # a distance of 2.5e-5 whose round-off is 8e-12 of it
def test_distance_to_polyline_is_the_nearest_segments(seed, m, spread):
    """Exact against every segment, on random polylines that cross themselves, with long
    and short segments and repeated vertices, for points near and far."""
    rng = np.random.default_rng(seed)
    vertices = np.cumsum(rng.normal(size=(m, 2)) * rng.exponential(1.0, (m, 1)), axis=0)
    vertices[rng.random(m) < 0.2] = vertices[0]
    pts = vertices.mean(axis=0) + spread * rng.normal(size=(150, 2))
    got = distance_to_polyline(pts, vertices)
    # both compute the foot by subtracting coordinates, so their round-off is a few ulps of
    # the coordinates' size, not of the distance: a distance of 2.5e-5 at coordinates of
    # order 1 may differ by 2e-16 (relative 8e-12)
    scale = 1.0 + np.abs(np.r_[vertices, pts]).max()
    np.testing.assert_allclose(
        got, _segment_distances(pts, vertices).min(axis=1), rtol=1e-12, atol=1e-14 * scale
    )


@given(
    st.integers(0, 10_000),
    st.sampled_from([2, 3]),
    st.integers(2, 20 * projection.EVERY_CHORD_PER_SAMPLE),
    st.sampled_from([0.01, 1.0, 30.0]),
)
def test_short_polylines_measured_chord_by_chord_as_the_tree_search_measures(
    seed, dim, m, spread
):
    """A polyline is measured against every chord or through the k-d tree
    (``_nearest_chords``), whichever is quicker for it: the two give the same distances,
    bit for bit (one arithmetic), so where the switch falls moves no figure."""
    rng = np.random.default_rng(seed)
    vertices = np.cumsum(rng.normal(size=(m, dim)) * rng.exponential(1.0, (m, 1)), axis=0)
    vertices[rng.random(m) < 0.2] = vertices[0]
    pts = vertices.mean(axis=0) + spread * rng.normal(size=(300, dim))
    tree = np.sqrt(_nearest_chords(pts, vertices, top=1)[1][:, 0])
    np.testing.assert_array_equal(distance_to_polyline(pts, vertices), tree)
    every = projection.segment_distances(pts, vertices[:-1], vertices[1:])
    np.testing.assert_array_equal(np.min(every, axis=1), tree)


def test_distance_to_polyline_past_crowded_vertices():
    """The nearest segment's ends far away, five other vertices nearer: the segments beside
    a point's 4 nearest vertices (the paper suite's old metric) would give 0.2, not 0.1."""
    cluster = np.c_[np.linspace(0.02, -0.02, 5), np.full(5, 0.3)]
    vertices = np.r_[[[-1.0, 0.0], [1.0, 0.0]], cluster]
    got = distance_to_polyline(np.array([[0.0, 0.1]]), vertices)
    np.testing.assert_allclose(got, [0.1], rtol=1e-14)
    assert _segment_distances(np.array([[0.0, 0.1]]), vertices)[0, 1:].min() > 0.19


def test_distance_to_polyline_within_a_long_chords_reach_is_every_chords_least():
    """A dense polyline (3,000 vertices 1e-3 apart) with one chord 40 long: every vertex
    lies within the reach of a point 0.5 away (its nearest chord's distance plus half the
    longest chord), so the tree hands back about 1.2 million (point, vertex) pairs, read in
    parts; the distances are the least over every chord, bit for bit."""
    s = np.arange(3000) * 1e-3
    vertices = np.r_[np.c_[s, 0.1 * np.sin(4 * s)], [[3.0, 40.0]]]
    rng = np.random.default_rng(11)
    pts = vertices[rng.integers(0, 3000, 400)] + rng.normal(0, 0.5, (400, 2))
    every = _every_chord_d2(pts, vertices)
    np.testing.assert_array_equal(distance_to_polyline(pts, vertices), np.sqrt(every.min(1)))
    assert distance_to_polyline(np.zeros((0, 2)), vertices).shape == (0,)


def test_points_far_from_an_unevenly_spaced_polyline_are_settled_by_their_nearest_vertices(
    monkeypatch,
):
    """Points far from dense data (many times the data's spacing away), the data's
    chords 2.5e-4 to 2e-3 long (f4 sampled at 20,000 points: up to 5 times its short
    chords): their nearest vertices settle nearly every point (a chord whose ends both
    lie beyond ``R`` is at least ``sqrt(R^2 - L^2/4)`` away), so few ask the tree for a
    ball, and every distance is the least over every chord, bit for bit."""
    u = np.r_[np.linspace(0.0, 0.5, 2000), np.linspace(0.5, 1.0, 401)[1:]]
    vertices = np.c_[u, 0.2 * np.sin(6 * u)]
    rng = np.random.default_rng(5)
    pts = vertices[rng.integers(0, len(vertices), 3000)] + rng.normal(0, 0.05, (3000, 2))
    asked = []

    class Counting(projection.cKDTree):
        def query_ball_point(self, x, r, return_length=False, **kwargs):
            if return_length:  # once for every unsure point
                asked.append(len(x))
            return super().query_ball_point(x, r, return_length=return_length, **kwargs)

    monkeypatch.setattr(projection, "cKDTree", Counting)
    got = distance_to_polyline(pts, vertices)
    every = _every_chord_d2(pts, vertices)
    np.testing.assert_array_equal(got, np.sqrt(every.min(1)))
    assert sum(asked) < 0.05 * len(pts)  # by r + L/2 instead: 2,936 of the 3,000


def _every_chord_d2(pts, vertices):
    """Each point's squared distance to every chord of the polyline (N, M - 1), by the
    search's own formula (so that its least is the search's answer bit for bit)."""
    a, ab = vertices[:-1], np.diff(vertices, axis=0)
    inv = 1.0 / np.maximum(np.sum(ab**2, axis=1), 1e-300)
    return _chord_d2(pts, a, ab, inv, np.broadcast_to(np.arange(len(a)), (len(pts), len(a))))


def _assert_top_chords(pts, samples):
    got, got_d2 = _nearest_chords(pts, samples)
    every = _every_chord_d2(pts, samples)
    assert np.all(np.diff(got_d2, axis=1) >= 0)  # nearest first
    picked = np.sort(np.take_along_axis(every, got, axis=1), axis=1)
    np.testing.assert_array_equal(picked, np.sort(every, axis=1)[:, :3])
    np.testing.assert_allclose(np.sort(got_d2, axis=1), picked, rtol=1e-15)


def test_dense_design_is_made_once_and_read_only():
    """The dense sampling's design matrix is a constant of the knots (every curve of a
    shape on fixed knots shares it): made once, read-only, and the curve's samples through
    it are those of evaluating the curve at the dense parameters, bit for bit."""
    t = make_knots(9, 3, True)
    grid, design = _dense_design(t.tobytes(), 3, True, 40)
    assert _dense_design(t.tobytes(), 3, True, 40)[1] is design
    np.testing.assert_array_equal(grid, dense_parameters(t, 40))
    rng = np.random.default_rng(3)
    ctrl, w = rng.uniform(-1, 1, (9, 2)), rng.uniform(0.5, 2.0, 9)
    want = curve_derivatives(grid, ctrl, w, t, 3, True, max_nu=0)[0]
    np.testing.assert_array_equal(_rational([design], ctrl, w)[0], want)
    for a in (grid, design):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1.0
    kept = _dense_design.cache_info().currsize  # past 32 control points: not kept
    t40 = make_knots(40, 3, False)
    project_points(
        rng.uniform(-1, 1, (5, 2)), rng.uniform(-1, 1, (40, 2)), np.ones(40), t40, 3, False
    )
    assert _dense_design.cache_info().currsize == kept


def test_a_span_evaluates_its_own_polynomial_at_its_right_end():
    """At a polygon's corner (a knot) the default span is the next one; given the span
    before it, the same point and that span's derivative (projected Newton's interval)."""
    from swarmcurves_jax.basis import find_span

    ctrl, w, t = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), np.ones(3), make_knots(3, 1, False)
    at = curve_derivatives([0.5], ctrl, w, t, 1, False, max_nu=1)
    before = curve_derivatives([0.5], ctrl, w, t, 1, False, 1, find_span(np.array([0.25]), t, 1))
    np.testing.assert_allclose(at[0], [[1.0, 0.0]])
    np.testing.assert_allclose(before[0], [[1.0, 0.0]])
    np.testing.assert_allclose(at[1], [[0.0, 2.0]])
    np.testing.assert_allclose(before[1], [[2.0, 0.0]])


def test_polygon_distance_is_point_to_segment():
    ctrl = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    t = make_knots(3, 1, False)
    pts = np.array([[0.5, 0.3], [1.4, 0.5], [2.0, 2.0], [-1.0, 0.0]])
    dist, _ = project_points(pts, ctrl, np.ones(3), t, 1, False)
    np.testing.assert_allclose(dist, [0.3, 0.4, np.sqrt(2.0), 1.0], atol=1e-12)


@given(st.integers(2, 9), st.booleans(), st.booleans(), st.integers(0, 10_000))
def test_polygon_sampled_at_its_corners_projects_onto_its_segments(n, closed, rational, seed):
    """A polygon's projection samples only its corners (its segments are the chords, from
    one segment up): the distance and foot of each point are its nearest segment's."""
    rng = np.random.default_rng(seed)
    ctrl = rng.uniform(-1, 1, (n, 2))
    w = rng.uniform(0.3, 3.0, n) if rational else np.ones(n)
    t = make_knots(n, 1, closed)
    pts = rng.uniform(-1.5, 1.5, (50, 2))
    dist, u = project_points(pts, ctrl, w, t, 1, closed)
    a = ctrl
    b = np.roll(ctrl, -1, axis=0) if closed else ctrl[1:]
    a = a if closed else ctrl[:-1]
    ab, ap = b - a, pts[:, None, :] - a[None]
    s = np.clip(np.einsum("nsd,sd->ns", ap, ab) / np.sum(ab**2, axis=1), 0.0, 1.0)
    want = np.sqrt(np.min(np.sum((ap - s[..., None] * ab) ** 2, axis=2), axis=1))
    np.testing.assert_allclose(dist, want, atol=1e-12)
    foot = curve_derivatives(u, ctrl, w, t, 1, closed, max_nu=0)[0]
    np.testing.assert_allclose(np.linalg.norm(foot - pts, axis=1), dist, atol=1e-12)


def test_points_on_a_fast_self_approaching_curve_have_zero_distance():
    # A clamped quintic whose fast end passes within 1e-3 of its own middle: ranking sample
    # points (not chords) once projected some of these points onto the wrong branch.
    rng = np.random.default_rng(0)
    for k in (1, 2, 3, 5):  # the fourth draw of this generator is the case that failed
        n = k + 4
        ctrl = rng.uniform(-1, 1, (n, 2))
    t = make_knots(n, 5, False)
    u = np.linspace(0, 1, 400)
    pts = curve_derivatives(u, ctrl, np.ones(n), t, 5, False, max_nu=0)[0]
    dist, foot = project_points(pts, ctrl, np.ones(n), t, 5, False)
    assert dist.max() < 1e-9


def test_each_point_projects_as_if_alone_and_settled_points_leave_newton(monkeypatch):
    """A parameter that stopped moving leaves the Newton loop (its step depends on its own
    row alone, so it would not move again): every point's distance and foot are the ones
    it gets projected alone, to the rounding of the matrix products, and the loop
    evaluates fewer rows than every parameter at every step."""
    rng = np.random.default_rng(3)
    ctrl, w, t = rng.uniform(-1, 1, (8, 2)), rng.uniform(0.5, 2.0, 8), make_knots(8, 3, True)
    u = np.sort(rng.uniform(0, 1, 2000))
    pts = curve_derivatives(u, ctrl, w, t, 3, True, max_nu=0)[0] + rng.normal(0, 0.02, (2000, 2))
    rows = []
    plain = projection.curve_derivatives

    def counted(u, *args, **kwargs):
        rows.append((len(u), kwargs.get("max_nu", 2)))
        return plain(u, *args, **kwargs)

    monkeypatch.setattr(projection, "curve_derivatives", counted)
    dist, foot = project_points(pts, ctrl, w, t, 3, True)
    newton = [n for n, nu in rows if nu == 2]
    assert newton[0] == 3 * 2000  # three chords a point
    # measured: 6000, 6000, 2003 and 1806 rows, two thirds of four steps of every row
    assert len(newton) >= 3 and sum(newton) < 0.7 * len(newton) * newton[0]
    for i in rng.choice(2000, 25, replace=False):
        alone = project_points(pts[i : i + 1], ctrl, w, t, 3, True)
        np.testing.assert_allclose(alone[0], dist[i], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(alone[1], foot[i], rtol=0, atol=1e-13)


@pytest.mark.parametrize("k, closed", [(2, True), (3, False), (3, True)])
def test_many_points_search_the_other_intervals_only_where_their_chord_could_come_nearer(
    k, closed, monkeypatch
):
    """With at least as many points as dense samples, Newton runs first in the interval of
    each point's nearest chord, then in its next two only where that chord, less how far
    the arc can stray from it (``|C''| (hi - lo)^2 / 8``), could come nearer: the same
    distances and feet as searching all three, for under half of Newton's starts."""
    rng = np.random.default_rng(k + 2 * closed)
    ctrl, w, t = rng.uniform(-1, 1, (9, 2)), np.ones(9), make_knots(9, k, closed)
    u = rng.uniform(0, 1, 6000)
    pts = curve_derivatives(u, ctrl, w, t, k, closed, max_nu=0)[0] + rng.normal(0, 0.02, (6000, 2))
    rows = []
    plain = projection._newton

    def counted(u, *args):
        rows.append(len(u))
        return plain(u, *args)

    monkeypatch.setattr(projection, "_newton", counted)
    dist, foot = project_points(pts, ctrl, w, t, k, closed)
    ruled_out = sum(rows)
    monkeypatch.setattr(projection, "_arc_gaps", lambda *args: None)  # all three searched
    want = project_points(pts, ctrl, w, t, k, closed)
    np.testing.assert_allclose(dist, want[0], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(foot, want[1], rtol=0, atol=1e-12)
    # measured: 6,000 + 1,409 to 1,750 rows start Newton, against 18,000
    assert sum(rows) - ruled_out == 3 * 6000 and ruled_out < 0.5 * 3 * 6000


def test_points_whose_other_chords_are_all_ruled_out_search_no_more():
    """Points over the middles of a polygon's sides: every other side is farther than the
    nearest, so the second search is empty (it runs on no rows), and each distance is the
    offset."""
    ctrl = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 1.0]])
    t = make_knots(4, 1, False)
    mids = 0.5 * (ctrl[1:] + ctrl[:-1])
    normal = np.diff(ctrl, axis=0)[:, ::-1] * [1.0, -1.0]
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    offsets = np.array([0.01, 0.02, 0.05])
    pts = (mids[:, None, :] + offsets[None, :, None] * normal[:, None, :]).reshape(-1, 2)
    dist, _ = project_points(pts, ctrl, np.ones(4), t, 1, False)
    np.testing.assert_allclose(dist, np.tile(offsets, 3), rtol=1e-12)
