"""The swarm's seeds: least-squares curves with parameter correction, one per swarm.

With ``init="lsq"`` one particle of every swarm starts on the least-squares fit of its
(degree, count), the best of fits from several parameterisations (chord lengths,
centripetal, even steps, the fit's own arc length), each followed by Hoschek's correction
(each point's parameter moved to its nearest point on the current curve, and solved
again), ranked by their distance to the data both ways and how often they cross
themselves (:func:`_rank`).  Rational swarms also try the linearised rational fit on
chord-length and even parameters.
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np
from pykdtree.kdtree import KDTree
from threadpoolctl import ThreadpoolController

from .basis import design_matrix
from .knots import curvature_widths, logits_from_widths, make_knots
from .layout import KNOT_LOGIT_BOUND, Layout, knot_vector
from .measures import crossings, data_polyline, sample_excursions

__all__ = [
    "chord_parameters",
    "least_squares_ctrl",
    "least_squares_nurbs",
    "uniform_grid_design",
    "seed_positions",
]


def chord_parameters(points: np.ndarray, closed: bool, power: float = 1.0) -> np.ndarray:
    """Cumulative chord-length parameters in [0, 1] (closed: [0, 1), the seam at 0);
    ``power`` 0.5: centripetal, each step the square root of its chord."""
    pts = np.vstack([points, points[:1]]) if closed else points
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1) ** power
    u = np.concatenate([[0.0], np.cumsum(seg)])
    u = u / u[-1] if u[-1] > 0 else np.linspace(0, 1, len(pts))
    return u[:-1] if closed else u


def _lsq(b, points, ends):
    if ends is None:
        return np.linalg.lstsq(b, points, rcond=None)[0]
    rhs = points - np.outer(b[:, 0], ends[0]) - np.outer(b[:, -1], ends[1])
    inner = np.linalg.lstsq(b[:, 1:-1], rhs, rcond=None)[0]
    return np.vstack([ends[0], inner, ends[1]])


def least_squares_ctrl(
    points, n, k, closed, ends=None, rounds: int = 20, t=None, even: bool = True
) -> np.ndarray:
    """Linear least-squares control points with parameter correction (the swarm's seed).

    Solved from chord-length parameters, centripetal ones, evenly spaced ones and the
    fit's own arc length (:func:`_arc_parameters`), each then ``rounds`` times moving
    every point's parameter to its nearest point on the current curve (a 2048-sample grid)
    and solving again (Hoschek's correction); the best ranked curve is kept (:func:`_rank`),
    and with more points than control points an exact one ends the search (points at even
    parameters skip the arc-length rounds).  Chord lengths alone misplace the parameters
    of looping curves; centripetal ones keep a curve through sparse corners from looping
    there; evenly spaced parameters are exact for points a program sampled at even
    parameter steps, as CAD and drawing programs flatten their curves; the arc-length
    rounds approach the parameters of points spaced evenly along the curve.  With ``ends``
    the first and last control points are fixed.  ``t``: the knot vector (default: the
    uniform one).  ``even=False``: from chord lengths alone (the classic least-squares
    fit).
    """
    return _polynomial_seed(points, n, k, closed, ends, rounds, t, even)[0]


def _starts(points, closed, even=True):
    """The parameterisations a seed is solved from: chord lengths, centripetal (steps as
    the chords' square roots, which keep an interpolating curve from overshooting sparse
    corners into loops), evenly spaced (closed: also one step on, where a closed curve's
    points lie when their order was reversed, as ``prepare.canonical_order`` may do: the
    first point then was the last)."""
    starts = [chord_parameters(points, closed)]
    if even:
        starts.append(chord_parameters(points, closed, 0.5))
        starts.append(np.linspace(0.0, 1.0, len(points), endpoint=not closed))
    if even and closed:
        starts.append((np.arange(len(points)) + 1.0) / len(points) % 1.0)
    return starts


def _polynomial_seed(points, n, k, closed, ends, rounds=20, t=None, even=True, data=None):
    """(control points, mean distance bound) of :func:`least_squares_ctrl`, and the
    control points of its first start, chord lengths (the classic fit)."""
    if t is None:
        t, dense = make_knots(n, k, closed), uniform_grid_design(n, k, closed)
    else:
        dense = design_matrix(_seed_grid(closed), t, k, closed=closed)
    best = chord = None
    data = _data_shape(points, closed) if data is None else data
    unique = len(points) > n  # else many curves pass through every point
    for u in _parameterisations(points, closed, dense, ends, even):
        fit = _corrected(design_matrix(u, t, k, closed=closed), dense, points, ends, rounds)
        chord = fit[0] if chord is None else chord
        if unique and fit[1] <= EXACT:
            return fit[0], fit[1], chord  # the points lie on this curve
        rank = _rank(fit, dense, closed, *data)
        if best is None or rank < best[2]:  # a tie keeps the earlier start
            best = (*fit, rank)
    return best[0], best[1], chord


def _data_shape(points, closed):
    """``(polyline, crossings)`` of the data, which :func:`_rank` weighs every seed
    against: made once per call (:func:`seed_positions`), not once per swarm."""
    return data_polyline(points, closed), crossings(points, closed)


#: How much farther from the data a seed counts for each time its curve crosses itself
#: beyond the data polyline (:func:`_rank`).
CROSSING_COST = 1.2


def _rank(fit, dense, closed, polyline, data_crossings) -> float:
    """How a seed ``fit`` (control points, mean distance bound) ranks, lowest first: its
    distance both ways (the bound, plus the arc-length mean distance from the ``polyline``
    of the curve through every fourth sample of the grid ``dense``), times
    :data:`CROSSING_COST` for each crossing beyond the data's.  The nearest start can
    loop where a sparse outline turns: an L of 12 points, closed, whose loop-free starts
    (centripetal, even) are 9 % (12 control points) and 26 % (8) farther.  A seed is only a
    start: the swarm can untangle a nearer one (a polygon of 5 corners fitted to the
    paper's f2 ended 30 % nearer from a start that crossed itself once, 34 % nearer than
    the best that did not), so a crossing is a cost, not a bar."""
    samples = dense[::4] @ fit[0]
    extra = max(crossings(samples, closed) - data_crossings, 0)
    return CROSSING_COST**extra * (fit[1] + sample_excursions(samples, polyline)[1])


def _parameterisations(points, closed, dense, ends, even=True):
    """The seed's starting parameters, the costly arc-length ones made only when asked."""
    starts = _starts(points, closed, even)
    yield from starts
    if even:
        chord = starts[0]
        for seam in _seams(chord, closed):
            yield _arc_parameters(points, chord, closed, dense, ends, seam)


#: A seed whose mean distance bound is at most this (the normalised frame) is exact: the
#: points lie on it, and no later start or correction round is tried.
EXACT = 1e-12


#: Rounds of :func:`_arc_parameters`: measured on random splines sampled evenly by arc
#: length (``benchmarks/recovery_rates.py --spacing arclength``), its seeds' median error is
#: 1.9e-2 after 0 rounds, 9.0e-3 after 10, 3.3e-3 after 30, 1.0e-3 after 100, 8.6e-4 after 300.
ARC_ROUNDS = 100


def _seams(chord, closed):
    """Where the first point lies along the curve, as a fraction of the chord length: at
    the start; closed, also one closing chord on (the points' order reversed).  ``chord``:
    the points' :func:`chord_parameters`, whose last is one closing chord short of 1."""
    return [0.0, 1.0 - chord[-1]] if closed else [0.0]


def _arc_parameters(points, chord, closed, dense, ends, seam=0.0):
    """Parameters at which the fitted curve's own arc length matches the points' chord
    length (from ``seam``), by fixed-point rounds: for points spaced along the curve (as a
    scan or a resampled outline is), neither chord lengths nor even steps are the curve's
    parameters, but each round's fit has an arc-length map closer to them, and the
    parameters keep the points' order.  The arc length is measured on every fourth
    sample of the grid (the rounds cost a third less; the seeds' errors as on all).
    ``chord``: the points' :func:`chord_parameters`."""
    frac = (chord + seam) % 1.0 if closed else chord
    grid = _seed_grid(closed)
    every = np.arange(0, len(grid), 4) if closed else np.r_[0 : len(grid) - 1 : 4, len(grid) - 1]
    coarse, at = dense[every], grid[every]
    if closed:
        coarse, at = np.vstack([coarse, coarse[:1]]), np.append(at, 1.0)
    u = frac
    for _ in range(ARC_ROUNDS):
        s = coarse @ _lsq(_grid_rows(dense, u, closed), points, ends)
        steps = np.diff(s, axis=0)
        length = np.concatenate([[0.0], np.cumsum(np.sqrt(np.sum(steps * steps, axis=1)))])
        new = np.interp(frac * length[-1], length, at)
        new = new % 1.0 if closed else new
        if np.max(np.abs(new - u)) < 1e-12:
            break
        u = new
    return u


def _grid_rows(dense, u, closed):
    """The design matrix at parameters ``u``, interpolated linearly between the rows of
    the grid's ``dense`` (4x cheaper than evaluating the basis; off by under 1e-5 of a
    basis value, which moves the arc-length rounds' parameters, not the seed's fit)."""
    steps = len(dense) if closed else len(dense) - 1
    x = u * steps
    i = np.minimum(np.floor(x).astype(int), steps - 1)
    f = (x - i)[:, None]
    return dense[i] * (1.0 - f) + dense[(i + 1) % len(dense)] * f


def least_squares_nurbs(points, n, k, closed, ends=None, t=None):
    """``(control points, weights)``: the rational seed, the nearer to the points of
    :func:`least_squares_ctrl` (weights 1) and the linearised rational fits.

    At fixed parameters ``u`` a rational curve through the points satisfies
    ``sum_j N_j(u_i) w_j (P_j - x_i) = 0``, linear in ``w_j P_j`` and ``w_j``: the least
    singular vector of that system is exact for points sampled at those parameters
    (chord-length or evenly spaced, as for the polynomial seed; measured: starting from
    the rational fit's own arc length too recovered no more of the rational curves
    spaced by arc length in ``benchmarks/recovery_rates.py``).  A solution with a weight
    that is not positive is dropped; weights are scaled to a geometric mean of 1.
    """
    return _nurbs_seed(points, n, k, closed, ends, t)[:2]


def _nurbs_seed(points, n, k, closed, ends, t, data=None):
    """(control points, weights) of :func:`least_squares_nurbs`, and the control points
    of the polynomial seed's chord-length start."""
    ctrl, err, chord = _polynomial_seed(points, n, k, closed, ends, t=t, data=data)
    t = make_knots(n, k, closed) if t is None else t
    best = (ctrl, np.ones(n), err)
    for u in _starts(points, closed):
        b = design_matrix(u, t, k, closed=closed)
        fit = _rational_lsq(b, points, ends)
        if fit is not None:
            num = (b * fit[1]) @ fit[0] / (b @ fit[1])[:, None]
            fit_err = np.mean(np.linalg.norm(num - points, axis=1))
            if fit_err < best[2]:
                best = (*fit, fit_err)
    return best[0], best[1], chord


def _rational_lsq(b, points, ends):
    """(control points, weights) solving ``sum_j b_ij w_j (P_j - x_i) = 0`` in least
    squares (unknowns ``w_j P_j`` and ``w_j``, fixed ``ends`` kept), or None when a weight
    is not positive."""
    m, n = b.shape
    d = points.shape[1]
    inner = np.arange(n) if ends is None else np.arange(1, n - 1)
    fixed = np.zeros((n, d))
    if ends is not None:
        fixed[0], fixed[-1] = ends
    # rows (point i, coordinate a); columns: w_j P_ja for the free j, then w_j
    q_cols = np.einsum("ij,ab->iajb", b[:, inner], np.eye(d)).reshape(m * d, -1)
    w_cols = np.einsum("ij,ija->iaj", b, fixed[None] - points[:, None]).reshape(m * d, n)
    v = np.linalg.svd(np.hstack([q_cols, w_cols]), full_matrices=False)[2][-1]
    v = v * np.sign(np.sum(v[-n:]))  # the weights' sign: mostly positive
    w = v[-n:]
    if not np.all(w > 1e-8 * np.max(np.abs(w))):
        return None
    ctrl = fixed.copy()
    ctrl[inner] = v[: len(inner) * d].reshape(-1, d) / w[inner, None]
    return ctrl, w / np.exp(np.mean(np.log(w)))


def _corrected(b, dense, points, ends, rounds):
    """(control points, mean distance bound): the least-squares fit on design ``b``, then
    Hoschek's correction on the grid ``dense``, keeping the nearest curve seen.  A curve's
    distance to each point is bounded by the nearer of its nearest grid sample and the
    point it was solved for, so an exact start (points sampled at its parameters) is
    kept exactly rather than traded for grid-snapped parameters."""
    ctrl = _lsq(b, points, ends)
    best, best_err, last = ctrl, np.inf, None
    with _one_openmp_thread():
        for _ in range(rounds + 1):
            # each point's nearest grid sample, exact (pykdtree rather than scipy's cKDTree:
            # W1's seeds 0.98 -> 0.71 s, both on one thread; cKDTree spends three quarters of
            # its build in NumPy's slow min and max down the columns of a (2048, 2) array);
            # leaves of 64 samples: a round's tree built and queried in 76 us instead of
            # 111 us (16)
            dist, j = KDTree(dense @ ctrl, leafsize=64).query(points)
            err = np.mean(np.minimum(dist, np.linalg.norm(b @ ctrl - points, axis=1)))
            if err < best_err:  # a correction can also fold the parameters: keep the best
                best, best_err = ctrl, err
            if best_err <= EXACT or (last is not None and np.array_equal(j, last)):
                break  # exact, or a fixed point: every later round gives this curve again
            b, last = dense[j], j
            ctrl = _lsq(b, points, ends)
    return best, best_err


@functools.cache
def _openmp_pools() -> ThreadpoolController:
    """The OpenMP thread pools loaded in this process (pykdtree's among them)."""
    return ThreadpoolController().select(user_api="openmp")


@contextlib.contextmanager
def _one_openmp_thread():
    """pykdtree's queries on one OpenMP thread: OpenMP's threads wait for each other
    whenever another core is busy (a program compiling or running beside the seeds, any
    other process).  Measured on 2 cores (``benchmarks/seeds_under_load.py``): W1's seeds
    0.71 s on idle cores either way; beside one busy core 0.71 s on one thread, 1.8-7.4 s
    on two; f4 at 2000 points 0.78 against 0.67 s idle, 0.79 against 2.2 s beside a busy
    core.  ``threadpoolctl`` sets the pools' size, and restores it after; OpenMP keeps
    that size per thread, so other threads' OpenMP work is untouched."""
    with _openmp_pools().limit(limits=1):
        yield


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
    """Two least-squares positions per swarm, laid out like a particle, shape
    ``(swarms, 2, size)``: the seed (:func:`least_squares_ctrl`, or
    :func:`least_squares_nurbs` for rational curves), which starts the swarm, and the
    classic fit from chord lengths alone (weights 1), which the selection also weighs: the
    seed is the start nearest the points on average, and where the fit has too few
    control points for the shape the classic fit can leave the smaller gap."""

    data = _data_shape(norm_pts, closed)

    def one(pair):
        k, n = pair
        row, t = np.zeros(space.size), None
        if space.num_knots:  # free knots: start where the data turn (knots.curvature_widths)
            spans = n if closed else n - k
            logits = logits_from_widths(curvature_widths(norm_pts, spans, closed))
            first = space.size - space.num_knots
            row[first : first + spans] = np.clip(logits, -KNOT_LOGIT_BOUND, KNOT_LOGIT_BOUND)
            t = knot_vector(row, k, n, space)
        classic = row.copy()
        if space.rational:
            ctrl, weights, chord = _nurbs_seed(norm_pts, n, k, closed, ends, t, data)
            row[space.num_ctrl : space.num_ctrl + n] = np.log(weights)
        else:
            ctrl, _, chord = _polynomial_seed(norm_pts, n, k, closed, ends, t=t, data=data)
        row[: n * space.dim] = ctrl.ravel()
        classic[: n * space.dim] = chord.ravel()
        return row, classic

    # one after the other: the rounds are many small NumPy calls that hold Python's lock,
    # and two threads on 2 cores took W1's seeds 0.81 -> 1.0 s
    return np.asarray([one(pair) for pair in pairs], dtype=dtype)
