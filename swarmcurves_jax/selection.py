"""Selection: which of a swarm's solutions it reports.

Every swarm has its best position and, after a polish, up to nine more candidates: its
polished one (:mod:`swarmcurves_jax.polish`), that polish's last iterate, the polished
one taken part of the way back to the best, its seed as the polish left it, and two
least-squares fits, its seed and the classic chord-length fit
(:mod:`swarmcurves_jax.seeds`).
:func:`measure` measures each by true projection both ways
(:mod:`swarmcurves_jax.projection`, :mod:`swarmcurves_jax.measures`) in float64 on the
host; :func:`select` keeps the one that stays closest to the data without looping where
the data do not, and never trades a curve for one that crosses itself more often.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .layout import Layout, knot_vector
from .measures import Deviations, crossings, deviations, scatter, turning
from .projection import project_points

__all__ = [
    "Candidate",
    "DataShape",
    "Measured",
    "EXTRA_TURNING",
    "REFINED",
    "SHORTENED",
    "select",
    "measure",
]


class Candidate(NamedTuple):
    """A swarm's solution: its flat position, its fitness on the device (None for the
    least-squares fits and the polish's other results) and where it comes from: "swarm",
    "polish", "polish's last", "shortened polish", "polished seed", "seed" or "classic"."""

    position: np.ndarray
    fitness: float | None
    source: str


#: The sources of the candidates the polish made (``curve.info["refined"]``).
REFINED = ("polish", "polish's last", "shortened polish", "polished seed")


class DataShape(NamedTuple):
    """How the polyline through the data turns (radians) and how often it crosses itself:
    a curve that follows the data turns and crosses about as often; and how far the data
    zig-zag (:func:`~.measures.scatter`): inside that much noise a curve can fold
    (:func:`_folds_beyond`)."""

    turning: float
    crossings: int
    scatter: float

    @classmethod
    def of(cls, points: np.ndarray, closed: bool) -> "DataShape":
        return cls(turning(points, closed), crossings(points, closed), scatter(points, closed))


class Measured(NamedTuple):
    """A candidate measured on the host (normalised frame, float64)."""

    candidate: Candidate
    ctrl: np.ndarray
    weights: np.ndarray
    knots: np.ndarray
    distances: np.ndarray  # each point's distance to the curve
    feet: np.ndarray  # each point's foot parameter
    deviation: Deviations


#: How much more than the swarm's curve (or the data polyline, if that turns more) a
#: polished curve or the seed may turn, and how much more than the data polyline a curve
#: turns before it counts as looping where the data do not: a quarter turn.  A fold, a
#: loop or a horn at a corner adds about half a turn or more, whatever its size; a curve
#: that follows the data turns about as they do (the polish's own fold term,
#: :func:`~.excursions.sample_folds`, sees a fold only where its samples fall, and can
#: miss one between them).
EXTRA_TURNING = 0.5 * math.pi


def select(
    best: Candidate,
    polished: Candidate | None,
    measure,
    data: DataShape,
    fits: Sequence[Candidate] = (),
    polished_seed: Candidate | None = None,
    polished_last: Candidate | None = None,
) -> Measured:
    """The solution a swarm reports, judged on the host (``measure(candidate)``) by the
    two-sided measures, the data's corners between samples allowed for
    (``corner_mean`` and ``corner_max``, :func:`~.measures.corners`: the data polyline
    cuts a sharp peak between two samples, and a curve that follows the data up to its
    tip is not the farther for leaving it).

    Its best, or its polished one if that one has the lower fitness, the lower two-sided
    ``mean_deviation`` and the lower product of the two measures
    (:func:`_closer_together`), and is shaped as the best or the ``data`` are
    (:func:`_shaped_as`: turning at most :data:`EXTRA_TURNING` more, crossing itself no
    more often): the fitness is the device's estimate, and neither it nor the one-sided
    error sees a polish that lowers it by sending a stretch of curve away from the data
    or folding it back on itself.  Where that polished curve is measured and not kept,
    the ``polished_last`` (the last iterate of the same start) by the same tests, the
    polished curve's fitness standing for its own: the hold-out score that picked the
    iterate reported sees neither gap nor fold, and near the end of a polish its iterates
    differ by little (Table 1's f3 at 14 control points, ``cps=range(4, 20)``: the
    reported iterate's product of the two measures 3.41e-7 against the swarm curve's
    3.19e-7, the last iterate's 3.11e-7; it follows f3's cusp to its tip, 3.7e-3 from the
    true curve against the swarm curve's 3.8e-2); then the polished curve shortened
    (:func:`_shortened`), by the same tests.  Then the ``polished_seed`` by the
    same tests but the fitness (the polish keeps the start with the lowest hold-out mean,
    which does not see a gap: at complex_path0's 10 control points the polished seed's
    mean is the same within 0.03 % and its largest deviation 0.257 against 0.308).
    Then each least-squares fit in ``fits`` (the swarm's seed, the classic chord-length
    fit), in turn, where it is closer to the data (a lower mean, :func:`_lower_mean`, or a
    smaller worst gap, :func:`_smaller_gap`) and shaped no worse: the swarm minimises a
    mean, and with too few control points for the shape its curve can leave a larger gap
    than a least-squares fit, or make a small loop.  Any of them also replaces a curve
    that loops where the data do not, whatever its fitness, if it does not and strays
    less (:func:`_untangles`): the fitness samples the curve a few times a span, and a
    loop between its samples costs it nothing.
    """
    chosen = measure(best)
    if polished is not None:
        lower = polished.fitness < best.fitness
        if lower or _loops(chosen, data):
            for candidate in (polished, polished_last, *_shortened(polished, best)):
                if candidate is None:
                    continue
                other = measure(candidate)
                if _replaces(other, chosen, lower and _polished_closer(other, chosen), data):
                    chosen = other
                    break
    if polished_seed is not None:
        other = measure(polished_seed)
        if _replaces(other, chosen, _polished_closer(other, chosen), data):
            chosen = other
    for fit in fits:
        other = measure(fit)
        closer = _lower_mean(other, chosen) or _smaller_gap(other, chosen)
        if _replaces(other, chosen, closer, data):
            chosen = other
    return chosen


#: How far back toward the swarm's curve a refused polished curve is taken, in turn
#: (:func:`_shortened`): the polish's last stretch can tie a loop too thin to see at a
#: cusp, or rise past its tip, and a step a little shorter undoes it while keeping almost
#: all of its gain.  The paper's f3, whose cusp's tip lies between two samples: in
#: ``fit(f3, cps=[8, 11, 15, 19, 25])`` at commit 3d017b4 the polished curve at 11
#: followed the cusp to the true tip, its two branches crossing 1.6e-3 below it; 1/64 of
#: the way back it crossed nothing, its data error 1.1e-4 against the seed's 1.1e-3,
#: reported before.  In ``cps=range(4, 20)`` at 14 (the polish compiled otherwise since)
#: the shortened polish is 8.2e-4 from the true f3 (Hausdorff), the swarm curve 3.5e-2
#: (``python examples/cusp.py``).
SHORTENED = (1 / 64, 1 / 16, 1 / 4)


def _shortened(polished: Candidate, best: Candidate) -> list[Candidate]:
    """The polished curve taken :data:`SHORTENED` of the way back to the swarm's best,
    its fitness standing for theirs: convex combinations of two positions in the search
    box, so in it too (pinned ends, padding and a free knot vector's order kept)."""
    start, end = (np.asarray(c.position, np.float64) for c in (polished, best))
    return [
        Candidate((1 - a) * start + a * end, polished.fitness, "shortened polish")
        for a in SHORTENED
    ]


def _replaces(other: Measured, chosen: Measured, closer: bool, data: DataShape) -> bool:
    """Whether ``other`` is reported instead of ``chosen``: ``closer`` to the data (the
    caller's test) and shaped as they are, or untangling a loop of ``chosen``."""
    if closer and _shaped_as(other, chosen, data):
        return True
    return _untangles(other, chosen, data)


def _lower_mean(other: Measured, chosen: Measured) -> bool:
    """Whether ``other``'s two-sided mean deviation (corners allowed for) is the lower."""
    return other.deviation.corner_mean < _or_inf(chosen.deviation.corner_mean)


def _polished_closer(other: Measured, chosen: Measured) -> bool:
    """Whether a polished curve is closer to the data than ``chosen``: a lower
    ``mean_deviation`` (what the polish lowers) and no gap widened by more than that
    (:func:`_closer_together`)."""
    return _lower_mean(other, chosen) and _closer_together(other, chosen)


def _closer_together(other: Measured, chosen: Measured) -> bool:
    """Whether ``other`` is the closer by both two-sided measures taken together (corners
    allowed for), the product of the mean and the largest deviation: a polish may widen
    the largest gap only by a smaller factor than it narrows the mean.  A polish that
    lowers the mean by pulling most of the curve onto the data while a stretch of it
    drifts away (across a sharp turn between two samples, say) is not reported."""
    mine, theirs = other.deviation, chosen.deviation
    return mine.corner_mean * mine.corner_max < _or_inf(theirs.corner_mean * theirs.corner_max)


def _smaller_gap(other: Measured, chosen: Measured) -> bool:
    """Whether ``other``'s worst gap is the smaller both ways it is measured: a smaller
    largest data distance and no larger largest deviation."""
    nearer = bool(np.max(other.distances) < np.max(chosen.distances))
    return nearer and other.deviation.corner_max <= _or_inf(chosen.deviation.corner_max)


def _loops(m: Measured, data: DataShape) -> bool:
    """Whether a curve loops where the data do not: it turns more than
    :data:`EXTRA_TURNING` beyond the data polyline.  Crossing itself more often than the
    data polyline does is no test here, only a bar to replacing (:func:`_shaped_as`): on
    noisy data a curve that doubles back crosses itself (f4 with noise 0.04 at 8 control
    points: four times, the data polyline once), and the one candidate that crossed less
    was 2.5 times as far from the true curve."""
    return m.deviation.turning > data.turning + EXTRA_TURNING


def _untangles(other: Measured, chosen: Measured, data: DataShape) -> bool:
    """Whether ``chosen`` loops where the data do not and ``other`` does not, with a
    smaller largest deviation: a small loop at a sharp corner of the data lowers the mean
    distance there and leaves the data."""
    if not _loops(chosen, data) or _loops(other, data):
        return False
    return other.deviation.corner_max < _or_inf(chosen.deviation.corner_max)


def _shaped_as(other: Measured, chosen: Measured, data: DataShape) -> bool:
    """Whether ``other`` turns at most :data:`EXTRA_TURNING` more than ``chosen`` or the
    data polyline, whichever turns more, crosses itself no more often than the one of
    them that crosses itself more (a loop around a sharp peak of the data can turn as
    the peak did, f4's cubic with 5 control points: 6.6 radians against the data's 6.6,
    and still cross itself), and does not fold across noisy data where ``chosen`` does
    not (:func:`_folds_beyond`)."""
    room = max(chosen.deviation.turning, data.turning) + EXTRA_TURNING
    allowed = max(chosen.deviation.crossings, data.crossings)
    shaped = other.deviation.turning <= room and other.deviation.crossings <= allowed
    return shaped and not _folds_beyond(other, chosen, data)


#: How much of its error a curve may lose, beyond ``chosen``'s loss, by passing the points
#: in their order (:func:`~.measures.order_gap`) before it counts as folded.
FOLD_GAP = 0.5


def _folds_beyond(other: Measured, chosen: Measured, data: DataShape) -> bool:
    """Whether ``other`` passes the points out of their order, where ``chosen`` does not,
    by more than :data:`FOLD_GAP` of its error: its order gap beyond ``chosen``'s, counted
    in proportion to the data's scatter against that error (up to all of it).

    A curve that folds back and forth across a band of noisy points passes nearer them
    than any curve that follows them, a lower mean deviation (the polyline through them
    zig-zags across the band too), and the turning and crossings need not show it (a Z
    crosses nothing).  In their order its passes lie the band's width apart: 100 points
    along a line, noise twice their spacing, the defaults: the polish's Z at 6 control
    points, mean deviation 0.0179 against the swarm's 0.0190, loses 1.3 of its error
    (0.019; the swarm's curve nothing).  Over 55 fits (noisy f1, f4 and random cubics,
    noise 0.02 of their size, at 6, 8 and 11 control points; that line at 4-10; clean
    random closed curves), every candidate against the swarm's curve: the folded ones
    (running back against the points over five times the curve's length or more) lost
    0.23-1.4 of their error beyond it, the others at most 0.21; those past the bar are
    the line's (0.52-1.4), the folds that undercut the swarm's mean; the others had the
    higher means, and none is reported.  A curve with too few
    control points for clean data lies farther from them than they scatter, and passes
    some out of order where it cuts across their turns without folding: the weight leaves
    it be (the benchmark outlines' scatter: 4e-5 to 1.3e-2)."""
    error = float(np.mean(other.distances))
    weight = min(data.scatter / error, 1.0) if error > 0 else 0.0
    excess = other.deviation.order_gap - chosen.deviation.order_gap
    return weight * excess > FOLD_GAP * error


def _or_inf(x: float) -> float:
    return math.inf if math.isnan(x) else x


def measure(candidate: Candidate, k: int, n: int, space: Layout, norm_pts) -> Measured:
    """A candidate un-padded and measured both ways against the normalised points."""
    q = np.asarray(candidate.position, dtype=np.float64)
    t = knot_vector(q, k, n, space)
    ctrl, log_w = space.split(q)
    ctrl = ctrl[:n]
    weights = np.ones(n) if log_w is None else np.exp(log_w[:n] - log_w[:n].max())
    dist, foot = project_points(norm_pts, ctrl, weights, t, k, space.closed)
    dev = deviations(norm_pts, ctrl, weights, t, k, space.closed, dist, foot)
    return Measured(candidate, ctrl, weights, t, dist, foot, dev)
