"""The last stage: the selected solutions built into curves and results.

:func:`collect` waits for a launched call, has every swarm's candidates measured and one
kept (:mod:`swarmcurves_jax.selection`), maps it back to the caller's frame, oriented
like the input (:func:`make_curve`), and builds each curve's
:class:`~swarmcurves_jax.results.FitResult`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .curves import Curve
from .devices import host_map
from .launch import Launched
from .polish import Polished
from .pystack import in_one_chunk
from .results import FitResult
from .selection import REFINED, Candidate, DataShape, Measured, measure, select

__all__ = ["collect", "make_curve"]


@in_one_chunk
def collect(run: Launched) -> list[FitResult]:
    """Wait for a launched call and build its results on the host (true projections)."""
    preps, opts, place, progress = run.preps, run.opts, run.place, run.progress
    pairs = preps[0].pairs
    state = progress.state
    swarm = place.get((state.best_position, state.best_fitness, state.step))
    polished = None if run.polished is None else Polished(*place.get(run.polished))
    timings = dict(run.timings)
    if "swarm" in timings:
        if polished is not None:
            timings["refine"] = time.perf_counter() - run.start - timings["swarm"]
    else:
        timings["call"] = time.perf_counter() - run.start  # swarm and polish, queued
    history = np.concatenate(place.get(progress.history), axis=2)
    # the least-squares fits are candidates where the polish ran (not after an interrupt)
    seeds = run.seeds if polished is not None and opts.init == "lsq" else None
    results = []
    for b, prep in enumerate(preps):
        data = DataShape.of(prep.norm_pts, prep.space.closed)

        def solution(i, b=b, prep=prep, data=data):
            best = Candidate(swarm[0][b, i], float(swarm[1][b, i]), "swarm")
            other = (
                None
                if polished is None
                else Candidate(polished.position[b, i], float(polished.fitness[b, i]), "polish")
            )
            fits, polished_seed, last = [], None, None
            if polished is not None:
                last = _other(polished.last[b, i], other, "polish's last")
            if seeds is not None:
                fits = _least_squares(seeds[b, i])
                polished_seed = _other(polished.seed[b, i], other, "polished seed")
            k, n = pairs[i]
            on_data = lambda c: measure(c, k, n, prep.space, prep.norm_pts)  # noqa: E731
            chosen = select(best, other, on_data, data, fits, polished_seed, last)
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


def _other(position, reported: Candidate, source: str) -> Candidate | None:
    """Another of the polish's results for one swarm (its polished seed or last iterate),
    where it differs from the ``reported`` one."""
    if np.array_equal(position, reported.position):
        return None
    return Candidate(position, None, source)


def _least_squares(rows: np.ndarray) -> list[Candidate]:
    """A swarm's seed and its classic chord-length fit as candidates (the classic one only
    where it differs: often it is the seed)."""
    seed, classic = rows
    fits = [Candidate(seed, None, "seed")]
    if not np.array_equal(seed, classic):
        fits.append(Candidate(classic, None, "classic"))
    return fits


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
            "refined": m.candidate.source in REFINED,
            "source": m.candidate.source,
            "seed": prep.seed_value,
            "max_excursion": dev.max_excursion,
            "rms_excursion": dev.rms_excursion,
            "self_crossings": dev.crossings,
            "order_gap": dev.order_gap,
            "corner_max_deviation": dev.corner_max,
            "corner_mean_deviation": dev.corner_mean,
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
