"""Fits stay with the data both ways: no loops, spikes or excursions between the points."""

from types import SimpleNamespace
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from swarmcurves_jax import fit, make_knots, normalise
from swarmcurves_jax.datasets import analytic_points, normal_noise, random_bspline_points
from swarmcurves_jax.excursions import data_segments, own_segments, runs_back, sample_folds
from swarmcurves_jax.fitness import excess2_at
from swarmcurves_jax.measures import Deviations, crossings, deviations, turning
from swarmcurves_jax.paper import hausdorff_distance
from swarmcurves_jax.projection import project_points
from swarmcurves_jax.seeds import least_squares_ctrl, uniform_grid_design
from swarmcurves_jax.selection import Candidate, DataShape, select


def largest_allowance(points: np.ndarray, closed: bool) -> float:
    """The most the fitness lets a curve stray from any segment of the data polyline
    unpenalised: the sagitta its turning allows, three tenths of the segment
    (:data:`swarmcurves_jax.excursions.ALLOWANCE_BASE`) and the data's scatter."""
    a2 = data_segments(points, np.ones(len(points)), closed).allowance2
    return float(np.sqrt(np.max(a2[np.isfinite(a2)])))


@settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))
@example(n=5, closed=True, dim=2, sigma=0.0, seed=46)  # 4 cp: the excursion 1.11 max_error + A
@given(
    n=st.integers(5, 8),
    closed=st.booleans(),
    dim=st.sampled_from([2, 3]),
    sigma=st.sampled_from([0.0, 0.01]),
    seed=st.integers(0, 10_000),
)
def test_every_solution_stays_within_its_error_plus_the_polylines_allowance(
    n, closed, dim, sigma, seed
):
    """The bound: every point of every solution lies within ``3 max_error + A`` of the
    data polyline, ``A`` its largest allowance.  A curve through every point within
    ``max_error`` that runs along the data in order lies within ``max_error`` of the
    curve the data sample, which lies within ``A`` of the polyline; the rest leaves room
    for a curve that crosses between two points, and for one with fewer control points
    than the data's curve, which cuts across its turns (closed, 5 control points fitted
    with 4: 1.11 max_error + A, the example pinned above, and 1.95 when fitted at 4-6
    control points alone, whose rounding differs).  A loop or a spike exceeds it
    by orders of magnitude (the polish's spikes: 0.28 and 6.8 half-extents at errors
    below 1e-3)."""
    pts, _ = random_bspline_points(n, 3, closed, num_points=120, dim=dim, seed=seed)
    norm, center, scale = normalise(pts)
    if sigma and dim == 2:
        norm = normal_noise(norm, sigma, seed=seed, closed=closed)
    elif sigma:
        norm = norm + np.random.default_rng(seed).normal(0.0, sigma, norm.shape)
    # every n fitted at the same counts (around each n's own): one program per layout
    result = fit(norm, cps=range(4, 10), closed=closed, iterations=300, seed=seed)
    bound_extra = largest_allowance(result.normalised(result.points), closed)
    for c in result:
        bound = 3 * c.max_error + bound_extra
        assert c.info["max_excursion"] <= bound, (c, bound)
        assert c.max_deviation == pytest.approx(max(c.max_error, c.info["max_excursion"]))


def _past_the_ends(curve, points) -> float:
    """How far the curve's first and last tenth reach past the data's end points: beyond
    the line through an end point across its segment."""
    far = 0.0
    ends = (((0, 1), (0.0, 0.1)), ((-1, -2), (0.9, 1.0)))
    for (end, inner), (lo, hi) in ends:
        xy = curve.evaluate(np.linspace(lo, hi, 500))
        past = (xy - points[end]) @ (points[inner] - points[end]) < 0
        if past.any():
            far = max(far, float(np.max(np.linalg.norm(xy[past] - points[end], axis=1))))
    return far


@pytest.mark.parametrize("seed", [2547, 2542, 2550])
def test_an_over_fitted_open_curve_does_not_hook_back_past_an_end(seed):
    """Random cubics of 7 control points fitted with 7 to 9: the curve is pinned at the
    data's end points and reaches past them by less than its largest data error (at most
    2.3e-3 here).  An allowance reaching past the ends would let the fit with one or two
    control points to spare hook back there unpenalised: 0.047, 0.072 and 0.065 past an
    end at largest data errors of 1.8e-3, 4.5e-3 and 5.3e-3."""
    pts, _ = random_bspline_points(7, 3, False, num_points=120, dim=2, seed=seed)
    norm, _, _ = normalise(pts)
    result = fit(norm, cps=range(4, 10), iterations=300, seed=seed)
    for c in result.solutions[3:]:
        assert _past_the_ends(c, norm) <= c.max_error, c


def _turning(curve, points) -> float:
    """The curve's total turning, as the two-sided measures sample it."""
    args = (curve.control_points, curve.weights, curve.knots, curve.degree, curve.closed)
    return deviations(points, *args, curve.residuals).turning


@pytest.mark.parametrize("name,n", [("f1", 11), ("f2", 19)])
def test_the_polish_leaves_no_spike_or_fold_on_table_1(name, n):
    """The paper's f1 at 11 and f2 at 19 control points, defaults: the polish used to send
    a stretch of curve out of the frame between two samples (largest deviation 0.28 and
    6.8 half-extents) because the data error fell.  Now every point of the curve stays
    within a few hundredths of the data; and the polished curve is kept, and turns about
    as the data do: f2's used to fold back on itself inside the allowance, turning 5.7
    radians more than the data polyline (now less than the data polyline)."""
    points = analytic_points(name)
    c = fit(points, cps=[n], seed=0).solutions[0]
    assert c.max_deviation < 0.03, c
    assert c.mean_deviation < 3 * c.error + 1e-3, c
    assert c.info["refined"], c
    assert _turning(c, points) < turning(points, False) + 0.5 * np.pi, c


def test_too_few_control_points_report_the_seed_rather_than_a_loop():
    """The paper's f1 at 7 control points, too few for its peaks: the swarm's own curve
    has the lower data error (3.2e-3 against 3.6e-3) by a small loop at the highest
    peak, 4.5e-2 from the data there (drawn); its least-squares seed stays within 9e-3 of
    the data both ways and has the lower mean deviation (3.7e-3 against 4.0e-3), so it
    is reported.  With ``refine=False`` the swarm's curve is."""
    points = analytic_points("f1")
    seed, pure = (fit(points, cps=[7], seed=0, refine=r).solutions[0] for r in (True, False))
    assert seed.info["source"] == "seed" and not seed.info["refined"]
    assert pure.info["source"] == "swarm"
    assert seed.max_deviation < 0.5 * pure.max_deviation and seed.max_deviation < 1e-2
    assert seed.mean_deviation < pure.mean_deviation


def test_a_spiral_at_too_few_control_points_reports_a_curve_that_does_not_cross_itself():
    """Two and a half turns of a spiral at 6 control points (seed 0): no such cubic
    follows it.  The classic least-squares fit from chord lengths strays least from the
    data (0.29 both ways, normalised) but crosses itself twice, the swarm's curve once;
    the spiral does not.  The reported curve (the seed, as the polish left it) does not
    cross itself, and its mean deviation is below the classic fit's (0.102 against 0.120):
    a curve that crosses itself is no answer to data that do not, however near it stays."""
    t = np.linspace(0.0, 1.0, 200)
    angle, radius = 5 * np.pi * t, 0.2 + t
    points = np.c_[radius * np.cos(angle), radius * np.sin(angle)]
    result = fit(points, cps=[6], seed=0)
    c = result[3, 6]
    norm = result.normalised(result.points)
    ctrl = least_squares_ctrl(norm, 6, 3, False, norm[[0, -1]], even=False)
    knots = make_knots(6, 3, False)
    dist, _ = project_points(norm, ctrl, np.ones(6), knots, 3, False)
    classic = deviations(norm, ctrl, np.ones(6), knots, 3, False, dist)
    assert classic.crossings == 2 and classic.max_deviation < c.max_deviation
    assert c.info["self_crossings"] == 0
    assert c.mean_deviation < classic.mean_deviation


def test_f4_at_five_control_points_is_not_reported_looping_around_its_peak():
    """f4 at 5 control points alone (seed 0): the least-squares seed, the polished curve
    and the classic fit all loop around the data's peak, crossing themselves, the first
    two with a lower mean deviation than the swarm's curve, which cuts the peak (0.0256
    and 0.0247 against 0.0268; its largest deviation 0.32 against the seed's 0.095).  A
    loop that turns as the peak did escapes the turning test; the crossing does not, and
    the swarm's curve is reported."""
    result = fit(analytic_points("f4"), cps=[5], seed=0)
    c = result[3, 5]
    assert c.info["source"] == "swarm"
    assert c.info["self_crossings"] == 0
    assert 0.3 < c.max_deviation < 0.33


@pytest.mark.parametrize("cps, followed", [([11, 16], [11, 16]), ([8, 11, 15, 19, 25], [11])])
def test_f3s_cusp_between_two_samples_is_followed_to_its_tip(cps, followed):
    """The paper's f3 has a cusp whose tip lies between two samples, 0.045 above the chord
    between them, which the data polyline cuts.  A curve that follows the data's slopes up
    to the tip leaves that polyline there: by the polyline's measures the least-squares
    seed at 16 control points, which cuts the tip off, and the swarm's curve at 11 looked
    nearer the data than the polished curves.  Judged with the corner allowed for
    (:func:`~swarmcurves_jax.measures.corners`), the polished curves are reported (seed 0),
    within 3.2e-3 of the true curve both ways (Hausdorff, ``paper.hausdorff_distance``) where
    the curves reported before were about 2.0e-2 (at 11) and 4.3e-2 (at 16) from it.  In
    the peers' call (``benchmarks/peers_accuracy.py``) the polish at 11 had tied a thin
    loop at the tip in one rounding (commit 3d017b4's), and the least-squares seed was
    reported, 4.4e-2 from it, until the polish's step shortened was weighed
    (``selection.SHORTENED``)."""
    true = analytic_points("f3", 100_001)
    result = fit(analytic_points("f3"), cps=cps, seed=0)
    for n in followed:
        c = result[3, n]
        away = hausdorff_distance(c.evaluate(np.linspace(0.0, 1.0, 20_001)), true)
        assert c.info["refined"] and c.info["self_crossings"] == 0 and away < 1e-2, (c, away)


def test_a_spur_at_a_sharp_corner_is_not_reported():
    """An L of 81 points, two straight legs at a right angle, defaults: at 7 and 9 control
    points the swarm's curve buys a data error of 0.000 % of the diagonal with a spur past
    the corner, 2.0 % and 2.3 % of it (seed 0, drawn), which its fitness, sampling the
    curve four times a span, does not see.  The host's measures do: the curve turns a loop
    more than the data, and a candidate that does not loop and strays less is reported.
    (At 8 the swarm's curve makes the corner exactly, within 1e-5.)"""
    corners = np.array([(0.0, 1.0), (0.0, 0.0), (1.5, 0.0)])
    legs = [np.linspace(a, b, 40, endpoint=False) for a, b in zip(corners, corners[1:])]
    points = np.vstack([*legs, corners[-1:]])
    result = fit(points, seed=0)
    for c in result.solutions[3:]:  # 7 control points and more follow the corner
        assert c.max_deviation_pct_diag < 1.0, c


def test_a_sample_running_back_inside_the_allowance_costs_the_room_left():
    """Along a straight polyline (allowance 0.03 = three tenths of a segment), a sample
    running back costs the allowance less its distance, nothing outside the allowance or
    running forward; at a right-angle corner, running along either leg costs nothing."""
    x = np.linspace(0.0, 1.0, 11)
    line = data_segments(np.c_[x, 0 * x].astype(np.float32), np.ones(11), False)
    samples = jnp.asarray([[0.45, 0.0], [0.45, 0.0], [0.55, 0.01], [0.55, 0.05]])
    tangents = jnp.asarray([[1.0, 0.0], [-1.0, 0.0], [-1.0, 0.0], [-1.0, 0.0]])
    segment = jnp.asarray([4, 4, 5, 5])
    over = excess2_at(samples, *line.segments, segment)
    folds = np.asarray(sample_folds(tangents, over, line, segment))
    np.testing.assert_allclose(folds, [0.0, 0.03, 0.02, 0.0], atol=1e-6)
    corner = np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0], [0.2, 0.1], [0.2, 0.2]], np.float32)
    line = data_segments(corner, np.ones(5), False)
    at, segment = jnp.asarray([[0.2, 0.0]] * 2), jnp.asarray([1, 2])
    over = excess2_at(at, *line.segments, segment)
    turned = sample_folds(jnp.asarray([[0.0, 1.0], [1.0, 0.0]]), over, line, segment)
    np.testing.assert_array_equal(np.asarray(turned), [0.0, 0.0])


def test_a_sample_near_another_part_of_the_data_is_not_its_own():
    """Ten points whose feet lie at samples 0, 4, ..., 36: a sample's own segment is the
    one between the feet around it, give or take two; a closed curve's wraps around."""
    foot, mask = jnp.arange(0.0, 40.0, 4.0), jnp.ones(10)
    at = jnp.arange(40)
    near = (at // 4).astype(jnp.int32)  # the segment each sample lies along
    assert bool(jnp.all(own_segments(near, foot, mask, False)))
    far = (near + 5) % 9
    assert not bool(jnp.any(own_segments(far, foot, mask, False)))
    wrapped = jnp.where(at < 4, 9, near).astype(jnp.int32)  # the closing segment 9 -> 0
    assert bool(jnp.all(own_segments(wrapped, foot, mask, True)))
    assert not bool(jnp.all(own_segments(wrapped, foot, mask, False)))


class _Measured(NamedTuple):
    deviation: Deviations
    distances: np.ndarray
    name: str


def _measured(name, mean, turns, largest=5e-3, farthest=5e-3, crosses=0, gap=0.0):
    """A measured candidate: its mean and largest deviations, its largest data distance
    (``farthest``), its turning, how often it crosses itself and its order gap."""
    deviation = Deviations(largest, mean, 0.0, 0.0, 0.0, turns, crosses, largest, mean, gap)
    return _Measured(deviation, np.r_[0.0, farthest], name)


def _select(
    polished=None,
    seed=None,
    turns=5.5,
    largest=5e-3,
    classic=None,
    polished_seed=None,
    crosses=0,
    noise=0.0,
    polished_last=None,
    shortened=None,
):
    """``select`` on stand-ins: the swarm's best has fitness 2e-3, mean deviation 2e-4,
    largest deviation ``largest``, largest data distance 5e-3 (error 2.5e-3), turns
    ``turns`` rad and crosses itself ``crosses`` times, for data whose polyline turns
    6 rad, does not cross itself and zig-zags by ``noise``; ``polished``: (fitness,
    measured), ``seed``, the ``classic`` least-squares fit, the ``polished_seed`` and
    the polish's last iterate ``polished_last``: measured; ``shortened``: the polished
    curve taken back toward the best, measured as a function of how far (``a``; default:
    as the polished curve)."""
    best = Candidate(np.ones(3), 2e-3, "swarm")
    measured = {id(best): _measured("best", 2e-4, turns, largest, crosses=crosses)}
    other = None
    if polished is not None:
        other = Candidate(np.zeros(3), polished[0], "polish")
        measured[id(other)] = polished[1]
    fits = []
    for source, m in (("seed", seed), ("classic", classic)):
        if m is not None:
            fits.append(Candidate(np.zeros(3), None, source))
            measured[id(fits[-1])] = m
    extra = None
    if polished_seed is not None:
        extra = Candidate(np.zeros(3), None, "polished seed")
        measured[id(extra)] = polished_seed
    last = None
    if polished_last is not None:
        last = Candidate(np.zeros(3), None, "polish's last")
        measured[id(last)] = polished_last

    def pick(c):
        if c.source != "shortened polish":
            return measured[id(c)]
        a = float(c.position[0])  # how far back: the best's position is ones, the rest zeros
        return polished[1] if shortened is None else shortened(a)

    data = DataShape(6.0, 0, noise)
    chosen = select(best, other, pick, data, fits, polished_seed=extra, polished_last=last)
    return chosen.name


@pytest.mark.parametrize(
    "polished, kept",
    [
        ((1e-3, 1e-4, 7.0, 5e-3), "polished"),  # lower fitness and mean, turns as the data
        ((1e-3, 1e-4, 6.0 + 0.5 * np.pi + 0.1, 5e-3), "best"),  # folds: a quarter turn more
        ((1e-3, 3e-4, 7.0, 5e-3), "best"),  # its mean deviation is higher
        ((3e-3, 1e-4, 7.0, 5e-3), "best"),  # its fitness is higher
        ((1e-3, 1e-4, 7.0, 9e-3), "polished"),  # half the mean, a gap 1.8 times as wide
        ((1e-3, 1e-4, 7.0, 1.1e-2), "best"),  # half the mean, a gap 2.2 times as wide
    ],
)
def test_a_polished_curve_that_folds_or_opens_a_gap_is_not_kept(polished, kept):
    """The best: fitness 2e-3, mean deviation 2e-4, largest deviation 5e-3 (``_select``).
    A polish is kept where it lowers the fitness and the mean, turns as the data do, and
    widens the largest gap by a smaller factor than it narrows the mean."""
    fitness, mean, turns, largest = polished
    measured = _measured("polished", mean, turns, largest, min(largest, 5e-3))
    assert _select(polished=(fitness, measured)) == kept


@pytest.mark.parametrize(
    "polished, last, kept",
    [
        ((1e-3, 1e-4, 7.0 + 0.5 * np.pi), (1.1e-4, 7.0), "last"),  # the best iterate folds
        ((1e-3, 1e-4, 7.0 + 0.5 * np.pi), (1.1e-4, 7.0 + 0.5 * np.pi), "best"),  # both fold
        ((1e-3, 1e-4, 7.0 + 0.5 * np.pi), (3e-4, 7.0), "best"),  # the last is farther
        ((1e-3, 1e-4, 7.0), (0.9e-4, 7.0), "polished"),  # the best is kept: last not weighed
        ((3e-3, 1e-4, 7.0), (0.9e-4, 7.0), "best"),  # the polish's fitness is higher
    ],
)
def test_the_polish_s_last_iterate_stands_in_for_a_refused_polished_curve(polished, last, kept):
    """The polish reports the iterate with the best hold-out score, which sees neither a
    fold nor a gap; a later iterate can be the one the host keeps (Table 1's f3 at 14
    control points).  Where the host refuses the reported one, the polish's last iterate
    is weighed by the same tests, the polished curve's fitness standing for its own;
    where the host keeps it, or the polish did not lower the fitness, the last iterate is
    not weighed (``_select``: the best's mean deviation is 2e-4, the data turn 6 rad)."""
    fitness, mean, turns = polished
    measured = _measured("polished", mean, turns)
    assert _select(polished=(fitness, measured), polished_last=_measured("last", *last)) == kept


@pytest.mark.parametrize(
    "crosses_until, mean, kept",
    [
        (1 / 64, 1.1e-4, "shortened 0.015625"),  # untied 1/64 of the way back
        (1 / 16, 1.1e-4, "shortened 0.0625"),  # the first step back that unties it
        (1.0, 1.1e-4, "best"),  # every step back still crosses
        (1 / 64, 3e-4, "best"),  # untied, but farther than the best
    ],
)
def test_a_polished_curve_that_crosses_itself_is_taken_back_until_it_does_not(
    crosses_until, mean, kept
):
    """A polish that ties a loop too thin to see (at a cusp whose tip it follows) is
    refused; the polished curve taken :data:`~swarmcurves_jax.selection.SHORTENED` of the
    way back to the best is weighed in turn, by the same tests, and the first that passes
    is reported: the least shortening that unties the loop."""
    polished = _measured("polished", 1e-4, 7.0, crosses=1)

    def shortened(a):
        return _measured(f"shortened {a}", mean, 7.0, crosses=int(a < crosses_until))

    assert _select(polished=(1e-3, polished), shortened=shortened) == kept
    # the last iterate is weighed first; a polish that lowers no fitness is not shortened
    last = _measured("last", 1.05e-4, 7.0)
    assert _select(polished=(1e-3, polished), polished_last=last, shortened=shortened) == "last"
    assert _select(polished=(3e-3, polished), shortened=shortened) == "best"


@pytest.mark.parametrize(
    "gap, noise, kept",
    [
        (0.0, 5e-3, "polished"),  # half the mean, in the data's order
        (1.2e-3, 5e-3, "polished"),  # in their order 0.48 of its error (2.5e-3) farther
        (1.3e-3, 5e-3, "best"),  # 0.52 farther: folded across the noise
        (2.0e-3, 1e-3, "polished"),  # less noise: 0.8 of its error, counted 0.4 of it
        (3.2e-3, 1e-3, "best"),  # 1.28 of its error, counted 0.4 of it: 0.51
    ],
)
def test_a_polished_curve_nearer_the_points_only_out_of_their_order_is_not_kept(gap, noise, kept):
    """A polish that halves the mean deviation (1e-4 against the best's 2e-4, see
    ``_select``) by passing the points out of their order, a Z across a band of noise,
    is not kept: in their order the points lie, on average, more than half its error
    (2.5e-3) farther from it (``order_gap``), counted in proportion to the data's
    scatter against that error, up to all of it."""
    measured = _measured("polished", 1e-4, 6.0, gap=gap)
    assert _select(polished=(1e-3, measured), noise=noise) == kept


@pytest.mark.parametrize(
    "seed, kept",
    [
        ((1.5e-4, 6.0, 6e-3, 6e-3), "seed"),  # a lower mean deviation
        ((3e-4, 6.0, 4e-3, 4e-3), "seed"),  # a smaller largest gap, both ways
        ((3e-4, 6.0, 4e-3, 6e-3), "best"),  # a point farther from the curve
        ((3e-4, 6.0, 6e-3, 4e-3), "best"),  # the curve farther from the polyline
        ((1e-4, 6.0 + 0.5 * np.pi + 0.1, 4e-3, 4e-3), "best"),  # folds
    ],
)
def test_the_seed_is_kept_where_it_is_closer_to_the_data(seed, kept):
    """The least-squares seed against the swarm's best (see ``_select``): kept where its
    mean deviation is lower, or both its largest deviation and its largest data distance
    are, and it turns as the data do.  A polish is not kept for a smaller gap alone."""
    mean, turns, largest, farthest = seed
    assert _select(seed=_measured("seed", mean, turns, largest, farthest)) == kept
    smaller_gap = _measured("polished", 3e-4, 6.0, 4e-3, 4e-3)
    assert _select(polished=(1e-3, smaller_gap)) == "best"
    polished = (1e-3, _measured("polished", 1e-4, 6.0))  # kept against the best
    assert _select(polished, _measured("seed", 1.5e-4, 6.0, 6e-3, 6e-3)) == "polished"


LOOPING = 6.0 + 0.5 * np.pi + 0.5  # more than a quarter turn beyond the data's 6 rad


@pytest.mark.parametrize(
    "polished_seed, kept",
    [
        ((1.9e-4, 6.0, 4e-3), "polished seed"),  # a hair lower mean, a narrower gap
        ((1e-4, 6.0, 9e-3), "polished seed"),  # half the mean, a gap 1.8 times as wide
        ((1e-4, 6.0, 1.1e-2), "best"),  # half the mean, a gap 2.2 times as wide
        ((2.1e-4, 6.0, 3e-3), "best"),  # a narrower gap alone
        ((1e-4, LOOPING, 4e-3), "best"),  # folds
    ],
)
def test_the_polished_seed_is_weighed_as_a_polish_without_its_fitness(polished_seed, kept):
    """The polish keeps the start with the lowest hold-out mean; the seed as the polish
    left it is weighed after it by the polish's tests on the host (a lower mean, a lower
    product of the two measures, turning as the data do), whatever the device's fitness,
    which is another objective than the swarm's (the fold term, denser samples)."""
    mean, turns, largest = polished_seed
    measured = _measured("polished seed", mean, turns, largest, largest)
    assert _select(polished_seed=measured) == kept
    # against a polish that was kept: the polished seed must beat that one
    polished = (1e-3, _measured("polished", 1.5e-4, 6.0))
    assert _select(polished, polished_seed=_measured("polished seed", 1.6e-4, 6.0)) == "polished"
    assert _select(polished, polished_seed=_measured("polished seed", 1.4e-4, 6.0)) == (
        "polished seed"
    )


def test_the_classic_fit_is_weighed_after_the_seed():
    """The chord-length least-squares fit against whatever the seed left chosen, by the
    seed's rule: kept where it leaves a smaller gap both ways than the seed that replaced
    the best, not where it is only closer than the best was."""
    seed = _measured("seed", 1.5e-4, 6.0, 6e-3, 6e-3)  # a lower mean than the best's
    assert _select(seed=seed, classic=_measured("classic", 1.8e-4, 6.0, 4e-3, 4e-3)) == "classic"
    assert _select(seed=seed, classic=_measured("classic", 1.8e-4, 6.0, 5e-3, 7e-3)) == "seed"
    assert _select(classic=_measured("classic", 1.8e-4, 6.0, 7e-3, 7e-3)) == "classic"


@pytest.mark.parametrize(
    "which, other, kept",
    [
        ("seed", (3e-4, 6.0, 1e-2), "seed"),  # a higher mean, but no loop and strays less
        ("seed", (3e-4, 6.0, 6e-2), "best"),  # strays more than the loop does
        ("seed", (3e-4, LOOPING, 1e-2), "best"),  # loops too
        ("polished", (3e-4, 6.0, 1e-2), "polished"),  # whatever its fitness (above the best's)
        ("polished", (1e-4, LOOPING, 1e-2), "best"),  # loops too
    ],
)
def test_a_curve_that_loops_where_the_data_do_not_gives_way(which, other, kept):
    """The swarm's best loops (it turns more than a quarter turn beyond the data polyline)
    and strays 5e-2 from the data: a candidate that does not loop and strays less is
    reported instead, whatever its mean deviation or fitness."""
    mean, turns, largest = other
    candidate = _measured(which, mean, turns, largest, largest)
    given = dict(seed=candidate) if which == "seed" else dict(polished=(3e-3, candidate))
    assert _select(**given, turns=LOOPING, largest=5e-2) == kept


@pytest.mark.parametrize(
    "which, crosses, best_crosses, kept",
    [
        ("seed", 1, 0, "best"),  # closer, but crosses itself where the data do not
        ("seed", 0, 0, "seed"),  # closer, and as the data
        ("seed", 1, 1, "seed"),  # the best crosses itself too: the closer one
        ("seed", 2, 1, "best"),  # crosses itself more often than the best
        ("seed", 0, 1, "seed"),  # does not cross
        ("polished", 1, 0, "best"),
        ("polished", 0, 0, "polished"),
        ("polished seed", 1, 0, "best"),
        ("polished seed", 0, 0, "polished seed"),
    ],
)
def test_a_curve_that_crosses_itself_where_the_data_do_not_replaces_none(
    which, crosses, best_crosses, kept
):
    """A candidate closer to the data than the swarm's best by every measure, and turning
    as the data do, is reported only where it crosses itself no more often than the best
    or the data: f4's cubic with 5 control points loops around the peak of the data
    (its turning the data's, 6.6 radians) and was reported for its lower mean."""
    candidate = _measured(which, 1e-4, 6.0, 4e-3, 4e-3, crosses)
    given = {
        "seed": dict(seed=candidate),
        "polished": dict(polished=(1e-3, candidate)),
        "polished seed": dict(polished_seed=candidate),
    }[which]
    assert _select(**given, crosses=best_crosses) == kept


@pytest.mark.parametrize("which", ["seed", "polished", "polished seed"])
def test_a_crossing_alone_hands_the_curve_to_no_farther_candidate(which):
    """The swarm's best crosses itself twice, the data polyline not at all; a candidate
    that does not cross but has the higher mean deviation and the wider gap is not
    reported: on noisy data a curve that doubles back crosses itself (f4 with noise 0.04
    at 8 control points, seed 2: four times), and the candidate that crossed less there
    was 2.5 times as far from the true curve."""
    candidate = _measured(which, 3e-4, 6.0, 6e-3, 6e-3, crosses=0)
    given = {
        "seed": dict(seed=candidate),
        "polished": dict(polished=(3e-3, candidate)),
        "polished seed": dict(polished_seed=candidate),
    }[which]
    assert _select(**given, crosses=2) == "best"


def test_a_curve_that_runs_back_against_the_datas_order_pays_the_arc_behind():
    """Feet in samples, 20 samples of 0.1 arc each (``arc`` 0.05: a tangent's length, half
    a sample's chord), mean distance 0.05: steps forward cost nothing, nor a step back
    within a sample and twice the mean distance (0.2 of arc: near-ties of noisy points, far
    points' feet); a step back of 6 samples costs the 0.4 beyond that, per point, in full
    where the data's scatter reaches the mean distance, in proportion below it.  Around a
    closed curve the shorter way counts: passing the seam is a step forward."""
    basis = SimpleNamespace(per_span=jnp.int32(4), num_spans=jnp.int32(5))
    arc = jnp.full(20, 0.05)  # each sample's |tangent| 0.05: 0.1 a sample

    def cost(foot, closed, scatter=0.05):
        args = (jnp.float32(6), jnp.float32(0.05), jnp.float32(scatter), arc, basis)
        return float(runs_back(jnp.array(foot), jnp.ones(6), *args, closed))

    assert cost([0.5, 1.5, 2.5, 3.0, 4.5, 5.5], False) == 0.0
    assert cost([0.5, 1.5, 2.5, 0.6, 4.5, 5.5], False) == 0.0
    assert cost([0.5, 1.5, 2.5, 10.5, 4.5, 5.5], False) == pytest.approx(0.4 / 6, rel=1e-5)
    assert cost([0.5, 1.5, 2.5, 10.5, 4.5, 5.5], False, 0.5) == pytest.approx(0.4 / 6, rel=1e-5)
    assert cost([0.5, 1.5, 2.5, 10.5, 4.5, 5.5], False, 0.01) == pytest.approx(0.08 / 6, rel=1e-5)
    assert cost([12.5, 15.5, 18.5, 1.5, 5.5, 8.5], True) == 0.0  # over the seam, round once
    assert cost([12.5, 15.5, 18.5, 1.5, 5.5, 8.5], False) == pytest.approx(1.5 / 6, rel=1e-5)
    assert cost([12.5, 15.5, 18.5, 1.5, 6.5, 3.5], True) == pytest.approx(0.1 / 6, rel=1e-5)


NOISY_LINE = np.c_[np.linspace(0.0, 1.0, 100), 0.01 * np.random.default_rng(0).normal(size=100)]
NOISIER_LINE = np.c_[NOISY_LINE[:, 0], 2.0 * NOISY_LINE[:, 1]]  # the same noise, twice as large


@pytest.mark.parametrize("points", [NOISY_LINE, NOISIER_LINE], ids=["noise 0.01", "noise 0.02"])
def test_noisy_points_along_a_line_are_not_folded_over(points):
    """100 points along a line, noise about their spacing, at 5-7 control points: the
    swarm folded the 6 and the 7 back and forth along the band of noise (crossing
    themselves 3 and 2 times, running back 0.85 and 1.0 of the line's length), at a lower
    mean distance than a curve that follows the points.  Paying for the arc its curve runs
    back against the points' order, it follows them: none runs back by more than ten
    points' spacing (0.01; here under one) or crosses itself more than once.  With twice
    the noise the polish folded the 6 and the 7 into Zs the line's length (running back
    1.0 and 0.95 of it), at a lower mean deviation than the swarm's curves (0.0185 against
    0.0199 at 6), and ``best`` took the folded 6; they pass the points out of their order
    (``order_gap``: by more than their error beyond the swarm's curve), and none is
    reported."""
    result = fit(points, cps=range(5, 8), seed=0)
    for c in result:
        x = c.evaluate(np.linspace(0.0, 1.0, 2001))[:, 0]
        assert np.max(np.maximum.accumulate(x) - x) < 0.1, c.n_ctrl
        assert c.info["self_crossings"] <= 1, c.n_ctrl


L_OUTLINE = np.array(
    [[0, 0], [1, 0], [2, 0], [2, 0.5], [2, 1], [1.5, 1], [1, 1], [1, 1.5], [1, 2], [0.5, 2],
     [0, 2], [0, 1]],
    dtype=float,
)  # fmt: skip


@pytest.mark.parametrize("n", [8, 12])
def test_the_seed_of_a_sparse_outline_does_not_loop_at_its_corners(n):
    """An L of 12 points (its corners and the middles of its edges), closed: the
    least-squares fits nearest the points, from chord lengths at 12 control points (an
    interpolant) and from even steps at 8, loop at the corners (crossing themselves 5 and
    2 times); the centripetal start does not, and the seed is the fit that crosses itself
    least for its distance to the data both ways."""
    points = normalise(L_OUTLINE)[0]
    ctrl = least_squares_ctrl(points, n, 3, True)
    samples = uniform_grid_design(n, 3, True) @ ctrl
    assert crossings(samples, True) == 0
    dist, _ = project_points(points, ctrl, np.ones(n), make_knots(n, 3, True), 3, True)
    assert np.mean(dist) < (1e-12 if n == 12 else 3e-2)


def test_a_sparse_outline_is_fitted_without_loops_at_nearly_as_many_control_points():
    """The L outline fitted closed at 8 and 12 control points: the curves looped at its
    corners (crossing themselves 2 and 5 times, 0.77 from the data at 12); from the
    seeds above they do not, and stay within 0.11 of the data both ways (normalised)."""
    result = fit(L_OUTLINE, cps=[8, 12], closed=True, seed=0)
    for c in result:
        assert c.info["self_crossings"] == 0, c.n_ctrl
        assert c.max_deviation < 0.11 * 2.0, c.n_ctrl  # the outline's scale is 2
