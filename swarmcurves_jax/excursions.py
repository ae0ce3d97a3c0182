"""How far a curve strays from the polyline through its data: the excursion term.

The mean point-to-curve distance cannot see a stretch of curve that no point projects
onto; a loop or a spike between two points costs it nothing.  The swarm and the polish
add the arc-length mean of how far each curve sample lies beyond an allowance around the
data polyline (:func:`excursion`), so a curve that leaves the data is worse.  The polish
also pays for a fold, the curve doubling back on itself inside the allowance
(:func:`sample_folds`): lowering the data error that way is its local moves' shortcut, not
the swarm's.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .fitness import excess2_at, min_excess2
from .span_basis import SpanBasis, float32_sum

__all__ = [
    "ALLOWANCE_BASE",
    "Polyline",
    "data_segments",
    "data_polylines",
    "sample_excursions",
    "sample_folds",
    "own_segments",
    "excursion",
    "runs_back",
]


class Polyline(NamedTuple):
    """The polyline through the ordered data as the fitness sees it, one row per segment
    (``B``: the padded point count): ``centre`` (B, D), ``half`` (B, D) from the centre to
    its end (the segment is ``centre + s * half``, ``|s| <= 1``, as the fitness's tangent
    segments are), ``allowance2`` (B,), the square of how far a curve may stray from it
    unpenalised (``-inf`` on rows that are no segment, so that none of them is ever the
    nearest), ``ahead`` (B, 5, D), the unit directions the data run in along it and
    the two segments either side (its own past an open polyline's ends), and
    ``scatter`` (), the mean over the segments of their ends' scatter (the ``rough`` of
    :data:`ALLOWANCE_BASE`): the data's noise, or their sparseness at turns.
    An open polyline's first and last rows stop short of its end points by their
    allowance, so that the allowance ends there.  Made on the host
    (:func:`data_segments`), an input of the programs."""

    centre: jax.Array | np.ndarray
    half: jax.Array | np.ndarray
    allowance2: jax.Array | np.ndarray
    ahead: jax.Array | np.ndarray
    scatter: jax.Array | np.ndarray

    @property
    def segments(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(centre, half, allowance2)``: what the distance kernels of
        :mod:`swarmcurves_jax.fitness` take."""
        return self.centre, self.half, self.allowance2


#: A segment's allowance is ``h * (ALLOWANCE_BASE + tan(turn / 4) / 2) + rough``, ``h``
#: its length, ``turn`` the larger turning angle at its ends (at most 3 rad) and
#: ``rough`` the larger distance of an end from the chord of its two neighbours: the
#: sagitta ``h tan(turn / 4) / 2`` of a circular arc through its ends that turns as the
#: data do, three tenths of the segment, and the data's own scatter (noise zig-zags the
#: polyline about the curve).  So the smooth curve the data sample stays inside the
#: allowance, and a loop or a spike leaves it.  The three tenths leave room for a curve
#: with fewer control points than the data need, which cuts across their turns by about
#: its own error: with a tenth the term fought the data there (the paper's f2 at 19
#: control points: data error 4.7e-4 against 3.7e-4, its largest deviation no smaller;
#: ``benchmarks/faithfulness.py``).
ALLOWANCE_BASE = 0.3


def data_segments(points, mask, closed: bool) -> Polyline:
    """The :class:`Polyline` through the real points (``mask`` 1; padding after them), in
    order, back to the first for a ``closed`` curve; an open one's end segments shortened
    by their allowance (:func:`_inside_the_ends`).  On the host, in float64, returned in
    the points' type: it depends on the data alone, so each program call takes it as an
    input rather than compiling it into the swarm's and the polish's programs (about 0.3
    and 0.2 CPU-s of their compilation, ``benchmarks/compile_cost.py``)."""
    dtype = np.asarray(points).dtype
    points = np.asarray(points, np.float64)
    size = points.shape[0]
    count = int(np.sum(mask))
    idx = np.arange(size)
    segments = count if closed else count - 1
    nxt = np.where((idx + 1 < count)[:, None], np.roll(points, -1, axis=0), points[0])
    vec = nxt - points
    len2 = np.sum(vec * vec, axis=1)
    unit = vec / np.sqrt(np.maximum(len2, 1e-30))[:, None]
    last = segments - 1
    before = np.where(idx == 0, last if closed else 0, idx - 1)
    after = np.where(idx < last, idx + 1, 0 if closed else idx)

    def turn(other):  # the angle between each segment and another (0 with itself)
        return np.arccos(np.clip(np.sum(unit * unit[other], axis=1), -1.0, 1.0))

    bend = np.minimum(np.maximum(turn(before), turn(after)), 3.0)
    # each vertex's distance from the chord of its neighbours (the segment before it
    # and this one): its scatter; at an open curve's ends, none
    chord = vec + vec[before]
    along = np.clip(
        np.sum(vec[before] * chord, axis=1) / np.maximum(np.sum(chord * chord, axis=1), 1e-30),
        0.0,
        1.0,
    )
    off = vec[before] - along[:, None] * chord
    scatter = np.where(before != idx, np.sqrt(np.sum(off * off, axis=1)), 0.0)
    rough = np.maximum(scatter, scatter[after])
    length = np.sqrt(len2)
    allowance = length * (ALLOWANCE_BASE + 0.5 * np.tan(0.25 * bend)) + rough
    allowance2 = np.where(idx < segments, allowance * allowance, -np.inf)
    start, end = _inside_the_ends(points, nxt, unit, length, allowance, idx, last, closed)
    half = 0.5 * (end - start)
    # the data's directions at each segment: its own and its two neighbours' either side
    ahead = np.stack([unit[before[before]], unit[before], unit, unit[after], unit[after[after]]], 1)
    noise = np.sum(np.where(idx < segments, rough, 0.0)) / max(segments, 1)
    line = Polyline(start + half, half, allowance2, ahead, np.asarray(noise))
    return Polyline(*(a.astype(dtype) for a in line))


def data_polylines(points, mask, closed: bool) -> Polyline:
    """:func:`data_segments` of each curve of a batch (leading axis), stacked."""
    lines = [data_segments(p, m, closed) for p, m in zip(points, mask)]
    return Polyline(*(np.stack(parts) for parts in zip(*lines)))


def _inside_the_ends(points, nxt, unit, length, allowance, idx, last, closed: bool):
    """Each segment's ends; an open polyline's first segment starts, and its last ends,
    its allowance inside the data's end point (at most its length), so that the allowance
    stops at the end point.  The curve is pinned there and has no sagitta to make beyond
    it: an allowance reaching past the end lets an over-fitted curve hook back at an end
    unpenalised (a random cubic of 7 control points fitted with 8: 0.047 past the end at
    a data error of 3.9e-4)."""
    if closed:
        return points, nxt
    cut_start = np.where(idx == 0, np.minimum(allowance, length), 0.0)
    cut_end = np.where(idx == last, np.minimum(allowance, length - cut_start), 0.0)
    return points + cut_start[:, None] * unit, nxt - cut_end[:, None] * unit


def sample_excursions(
    samples: jax.Array,
    tangents: jax.Array,
    basis: SpanBasis,
    polyline: Polyline,
    segment: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """How far each curve sample strays beyond the data polyline's allowance, (M,), and
    half the arc length it stands for, its tangent segment's half vector's length, (M,)
    (0 on samples that repeat the last; a weight, so the half does not matter); given each
    sample's ``segment``, also its fold (:func:`sample_folds`), (M,).

    The excess is ``sqrt(min over segments of max(0, d**2 - a**2))`` (``d``: the
    distance to a segment, ``a``: its allowance): zero inside the allowance, about ``d``
    far from it, and one square root per sample rather than per pair.  ``segment``
    (M,): the segment each sample's minimum is at, if known
    (:func:`~swarmcurves_jax.fitness.nearest_segments`, the polish's search); then only
    that one is measured.
    """
    if segment is None:
        over = min_excess2(samples, *polyline.segments)
    else:
        over = excess2_at(samples, *polyline.segments, segment)
    excess = jnp.sqrt(jnp.maximum(over, 0.0) + 1e-30)
    real = jnp.arange(samples.shape[0]) < basis.per_span * basis.num_spans
    arc = jnp.sqrt(jnp.sum(tangents * tangents, axis=1)) * real
    if segment is None:
        return excess, arc
    return excess, arc, sample_folds(tangents, over, polyline, segment)


def sample_folds(tangents, over, polyline: Polyline, segment) -> jax.Array:
    """How far each curve sample inside the allowance runs back against the data (M,),
    given its ``over = d**2 - a**2`` at its ``segment`` (:func:`sample_excursions`).

    A fold, the curve doubling back on itself inside the allowance, costs no distance:
    the excess sees only what leaves it.  A sample that runs against its segment and the
    two either side (so not one turning a corner with the data, nor a curve that turns
    more than a sparse polyline between its points) costs the room the allowance leaves
    it, ``a - d``, in proportion to how far it turns back: nothing running with the data,
    ``a`` running straight back along the polyline."""
    speed = jnp.sqrt(jnp.sum(tangents * tangents, axis=1))
    along = jnp.max(jnp.sum(tangents[:, None, :] * polyline.ahead[segment], axis=2), axis=1)
    back = jnp.maximum(-along, 0.0) / jnp.maximum(speed, 1e-30)
    a2 = jnp.maximum(polyline.allowance2[segment], 0.0)
    room = jnp.sqrt(a2) - jnp.sqrt(jnp.maximum(over + a2, 0.0) + 1e-30)
    return back * jnp.maximum(room, 0.0)


def own_segments(segment, foot, mask, closed: bool) -> jax.Array:
    """Whether each curve sample's nearest ``segment`` (M,) is its own part of the data
    (M,) bool: within two segments of where the points' feet (``foot`` (N,), in samples,
    ``mask`` 1 on the real points) place it.  A curve that passes near another part of
    the data (sparse data whose curve runs back beside itself) runs against that part's
    segments without folding."""
    at = jnp.arange(segment.shape[0], dtype=foot.dtype)
    expected = jnp.sum((foot[None, :] <= at[:, None] + 0.5) * mask[None, :], axis=1) - 1
    gap = jnp.abs(segment - expected.astype(segment.dtype))
    if closed:
        gap = jnp.minimum(gap, jnp.sum(mask).astype(segment.dtype) - gap)
    return gap <= 2


def runs_back(foot, mask, count, near, scatter, arc, basis: SpanBasis, closed: bool):
    """How far, per real point, the curve runs back against the data's order: the arc
    length from each point's foot (``foot`` (N,), in samples; ``mask`` 1 on the ``count``
    real points) back to the next point's beyond a sample and twice the points' mean
    distance ``near`` (around a closed curve, the shorter way round; the samples taken as
    equally long, twice the mean of ``arc``, half each sample's arc
    (:func:`sample_excursions`)), in proportion to the data's ``scatter``
    (:class:`Polyline`) up to ``near``.

    A curve that folds back and forth inside the band of noisy data passes nearer its
    points than one that follows them (100 points along a line, noise about their
    spacing: 6 control points folded twice along the band, mean distance 9.8e-3 against
    a straight cubic's 1.22e-2), and inside the allowance the excursion costs it nothing;
    the order of its feet shows it.  The slack leaves free the near-ties of noisy points
    and the feet of points far from a curve too coarse to follow them, which may lie
    anywhere within their distance; without noise to fold inside (``scatter`` below
    ``near``) the term fades, as it only cost clean outlines accuracy (the benchmark
    outlines of ``benchmarks/faithfulness.py``: data error 4.7 % higher, geometric mean,
    at full weight; 1.3 % so).  Polygons go without: their exact distance has no search
    to read the feet from, and one of their own cost W1 a fifth more compilation."""
    idx = jnp.arange(foot.shape[0])
    last = count.astype(jnp.int32) - 1
    m = (basis.per_span * basis.num_spans).astype(foot.dtype)
    spacing = 2.0 * float32_sum(arc) * (1.0 / m)
    step = jnp.where(idx == last, foot[0], jnp.roll(foot, -1)) - foot
    if closed:
        step = step - m * jnp.round(step * (1.0 / m))
    pairs = mask * ((idx <= last) if closed else (idx < last))
    back = jnp.maximum(-step * spacing - spacing - 2.0 * near, 0.0)
    noisy = jnp.minimum(scatter * (1.0 / jnp.maximum(near, 1e-30)), 1.0)
    return noisy * float32_sum(back * pairs) * (1.0 / count)


def excursion(
    samples, tangents, basis: SpanBasis, polyline: Polyline, order=None, closed: bool = False
) -> jax.Array:
    """The arc-length mean of :func:`sample_excursions`: the swarm's penalty for a curve
    that leaves the data between or beyond the points, which the mean point-to-curve
    distance cannot see; given ``order`` (the points' feet, mask, count and mean
    distance, the data's scatter), plus :func:`runs_back` from the same samples' arc."""
    excess, arc = sample_excursions(samples, tangents, basis, polyline)
    strays = jnp.sum(excess * arc) / jnp.maximum(jnp.sum(arc), 1e-30)
    if order is None:
        return strays
    return strays + runs_back(*order, arc, basis, closed)
