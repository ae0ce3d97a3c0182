"""The last stage: solutions measured on the host, selected, and returned as curves.

Every swarm's best position, and its polished one, are measured by true projection both
ways (:mod:`swarmcurves_jax.projection`, :mod:`swarmcurves_jax.measures`) in float64;
:func:`select` keeps one per swarm; :func:`make_curve` maps it back to the caller's
frame, oriented like the input; :func:`collect` builds each curve's
:class:`~swarmcurves_jax.results.FitResult`.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from .curves import Curve
from .devices import host_map
from .launch import Launched
from .layout import Layout, knot_vector
from .measures import Deviations, deviations, turning
from .projection import project_points
from .results import FitResult

__all__ = ["Candidate", "Measured", "collect", "select", "measure", "make_curve"]


class Candidate(NamedTuple):
    """A swarm's solution: its flat position, its fitness on the device (None for the
    seed, which the host made) and where it comes from: "swarm", "polish" or "seed"."""

    position: np.ndarray
    fitness: float | None
    source: str


class Measured(NamedTuple):
    """A candidate measured on the host (normalised frame, float64)."""

    candidate: Candidate
    ctrl: np.ndarray
    weights: np.ndarray
    knots: np.ndarray
    distances: np.ndarray  # each point's distance to the curve
    feet: np.ndarray  # each point's foot parameter
    deviation: Deviations


def collect(run: Launched) -> list[FitResult]:
    """Wait for a launched call and build its results on the host (true projections)."""
    preps, opts, place, progress = run.preps, run.opts, run.place, run.progress
    pairs = preps[0].pairs
    state = progress.state
    swarm = place.get((state.best_position, state.best_fitness, state.step))
    polished = None if run.polished is None else place.get(run.polished)
    timings = dict(run.timings)
    if "swarm" in timings:
        if polished is not None:
            timings["refine"] = time.perf_counter() - run.start - timings["swarm"]
    else:
        timings["call"] = time.perf_counter() - run.start  # swarm and polish, queued
    history = np.concatenate(place.get(progress.history), axis=2)
    # the least-squares seeds are candidates where the polish ran (not after an interrupt)
    seeds = run.seeds if polished is not None and opts.init == "lsq" else None
    results = []
    for b, prep in enumerate(preps):
        data_turning = turning(prep.norm_pts, prep.space.closed)

        def solution(i, b=b, prep=prep, data_turning=data_turning):
            best = Candidate(swarm[0][b, i], float(swarm[1][b, i]), "swarm")
            other = (
                None
                if polished is None
                else Candidate(polished[0][b, i], float(polished[1][b, i]), "polish")
            )
            seed = None if seeds is None else Candidate(seeds[b, i], None, "seed")
            k, n = pairs[i]
            on_data = lambda c: measure(c, k, n, prep.space, prep.norm_pts)  # noqa: E731
            chosen = select(best, other, on_data, data_turning, seed)
            return make_curve(chosen, k, n, int(swarm[2][b, i]), prep)

        solutions = host_map(solution, range(len(pairs)))
        # What the curve would have reported alone: a lone fit stops after the chunk in
        # which it reaches tol.
        stopped, reason = progress.stopped[b], run.stop_reason
        if stopped >= 0 and reason != "interrupted":
            reason = "tol"
        ran = min(stopped if stopped >= 0 else progress.done, opts.iterations)
        results.append(
            FitResult(
                solutions=solutions,
                points=prep.points,
                center=prep.center,
                scale=prep.scale,
                history=history[b, :, :ran].astype(np.float64),
                stop_reason=reason,
                seed=prep.seed_value,
                wall_time=time.perf_counter() - run.start,
                timings=timings,
            )
        )
    return results


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
    data_turning: float,
    seed: Candidate | None = None,
) -> Measured:
    """The solution a swarm reports, judged on the host (``measure(candidate)``) by the
    two-sided measures.

    Its best, or its polished one if that one's fitness is lower, then also its two-sided
    ``mean_deviation``, and it turns at most :data:`EXTRA_TURNING` more than the best or
    the data (``data_turning``) do: the fitness is the device's estimate, and neither it
    nor the one-sided error sees a polish that lowers it by sending a stretch of curve
    away from the data or folding it back on itself.  Then the swarm's least-squares
    ``seed``, where it is closer to the data (a lower mean, :func:`_lower_mean`, or a
    smaller worst gap, :func:`_smaller_gap`) and turns no more than that: the swarm
    minimises a mean, and with too few control points for the shape its curve can leave
    a larger gap than the seed it started from, or make a small loop.  Either also
    replaces a curve that loops where the data do not, whatever its fitness, if it does
    not and strays less (:func:`_untangles`): the fitness samples the curve a few times a
    span, and a loop between its samples costs it nothing.
    """
    chosen = measure(best)
    if polished is not None:
        lower = polished.fitness < best.fitness
        if lower or _loops(chosen, data_turning):
            other = measure(polished)
            if _replaces(other, chosen, lower and _lower_mean(other, chosen), data_turning):
                chosen = other
    if seed is not None:
        other = measure(seed)
        closer = _lower_mean(other, chosen) or _smaller_gap(other, chosen)
        if _replaces(other, chosen, closer, data_turning):
            chosen = other
    return chosen


def _replaces(other: Measured, chosen: Measured, closer: bool, data_turning: float) -> bool:
    """Whether ``other`` is reported instead of ``chosen``: ``closer`` to the data (the
    caller's test) and turning as they do, or untangling a loop of ``chosen``."""
    if closer and _turns_as_data(other, chosen, data_turning):
        return True
    return _untangles(other, chosen, data_turning)


def _lower_mean(other: Measured, chosen: Measured) -> bool:
    """Whether ``other``'s two-sided mean deviation is the lower."""
    return other.deviation.mean_deviation < _or_inf(chosen.deviation.mean_deviation)


def _smaller_gap(other: Measured, chosen: Measured) -> bool:
    """Whether ``other``'s worst gap is the smaller both ways it is measured: a smaller
    largest data distance and no larger largest deviation."""
    nearer = bool(np.max(other.distances) < np.max(chosen.distances))
    return nearer and other.deviation.max_deviation <= _or_inf(chosen.deviation.max_deviation)


def _loops(m: Measured, data_turning: float) -> bool:
    """Whether a curve loops where the data do not: it turns more than
    :data:`EXTRA_TURNING` beyond the data polyline."""
    return m.deviation.turning > data_turning + EXTRA_TURNING


def _untangles(other: Measured, chosen: Measured, data_turning: float) -> bool:
    """Whether ``chosen`` loops where the data do not and ``other`` does not, with a
    smaller largest deviation: a small loop at a sharp corner of the data lowers the mean
    distance there and leaves the data."""
    if not _loops(chosen, data_turning) or _loops(other, data_turning):
        return False
    return other.deviation.max_deviation < _or_inf(chosen.deviation.max_deviation)


def _turns_as_data(other: Measured, chosen: Measured, data_turning: float) -> bool:
    """Whether ``other`` turns at most :data:`EXTRA_TURNING` more than ``chosen`` or the
    data polyline, whichever turns more."""
    room = max(chosen.deviation.turning, data_turning) + EXTRA_TURNING
    return other.deviation.turning <= room


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
    dev = deviations(norm_pts, ctrl, weights, t, k, space.closed, dist)
    return Measured(candidate, ctrl, weights, t, dist, foot, dev)


def make_curve(m: Measured, k: int, n: int, steps: int, prep) -> Curve:
    """The selected solution as a :class:`Curve` in the caller's frame, traversed like the
    input."""
    ctrl, weights, t, closed, space = m.ctrl, m.weights, m.knots, prep.closed, prep.space
    if _runs_backwards(m.feet, closed):  # same geometry, traversed like the input
        ctrl, weights, t = _reversed(ctrl, weights, t, k, closed, bool(space.num_knots))
    diag = float(np.linalg.norm(np.ptp(prep.norm_pts, axis=0)))
    dist, dev = m.distances, m.deviation
    error = float(np.mean(dist))
    pct = lambda x: 100.0 * x / diag if diag > 0 else (0.0 if x == 0 else math.inf)  # noqa: E731
    return Curve(
        degree=k,
        control_points=prep.center + prep.scale * ctrl,
        weights=weights,
        knots=t,
        closed=closed,
        rational=space.rational,
        error=error,
        max_error=float(np.max(dist)),
        rms_error=float(np.sqrt(np.mean(dist**2))),
        error_pct_diag=pct(error),
        mean_deviation=dev.mean_deviation,
        max_deviation=dev.max_deviation,
        max_deviation_pct_diag=pct(dev.max_deviation),
        residuals=dist,
        info={
            "iterations": steps,
            "fitness": m.candidate.fitness,
            "refined": m.candidate.source == "polish",
            "source": m.candidate.source,
            "seed": prep.seed_value,
            "max_excursion": dev.max_excursion,
            "rms_excursion": dev.rms_excursion,
        },
    )


def _runs_backwards(foot: np.ndarray, closed: bool) -> bool:
    """Whether the data's foot-point parameters mostly decrease along the data's order.

    A majority vote of the steps' signs: their sum would telescope to last minus first,
    which says nothing when the input's ends coincide.
    """
    steps = np.diff(foot)
    if closed:
        steps = (steps + 0.5) % 1.0 - 0.5
    return int(np.sum(np.sign(steps))) < 0


def _reversed(ctrl, weights, t, k: int, closed: bool, free_knots: bool):
    """The same curve traversed the other way: control points and weights reversed and,
    on free (non-uniform) knots, the knot vector mirrored, ``1 - t[::-1]``, with a closed
    curve's control points rolled by ``k`` to line up with the mirrored periodic knots.
    Uniform knots are their own mirror, and a uniform closed curve needs no roll."""
    ctrl, weights = ctrl[::-1], weights[::-1]
    if not free_knots:
        return ctrl, weights, t
    if closed:
        ctrl, weights = np.roll(ctrl, k, axis=0), np.roll(weights, k)
    return ctrl, weights, 1.0 - t[::-1]
