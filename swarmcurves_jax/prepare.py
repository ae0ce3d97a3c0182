"""The first stage of a fit: check one curve's points and make them ready for the device.

Points are validated, a closed outline's repeated first point dropped, normalised into
``[-1, 1]^D``, ordered canonically (an input and its reverse give the same curves),
thinned to ``max_fitness_points`` and padded to a bucket length, so curves of similar
lengths share one compiled program.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._validation import check_pairs, check_points
from .layout import Layout
from .options import MAX_SAMPLES, FitOptions

__all__ = [
    "normalise",
    "SAMPLES_PER_SPAN",
    "default_num_samples",
    "bucket_length",
    "polish_length",
    "pad_points",
    "degree_groups",
    "Prepared",
    "prepare",
    "group_key",
    "root_key",
    "canonical_order",
]


def normalise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The normalisation: ``(points - c) / s`` inside ``[-1, 1]^D``, aspect kept.

    Points that all coincide have no extent; their scale is taken as 1.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = (lo + hi) / 2
    scale = float(np.max(hi - lo) / 2)
    if not scale > 0:
        scale = 1.0
    return (points - center) / scale, center, scale


#: Fitness search samples per knot span (a polygon's segments need one: searched exactly).
SAMPLES_PER_SPAN = 4


def default_num_samples(pairs, closed: bool, per_span: int = SAMPLES_PER_SPAN) -> int:
    """Fitness search samples for swarms of one degree: ``per_span`` per knot span of the
    one with the most spans, one per segment of a polygon, at least 8.

    The samples only pick each point's span and Newton's start (:mod:`.fitness`).
    Measured by ``benchmarks/fitness_accuracy.py`` (fitness against the true projection):
    on W1's least-squares curves, perturbed, the median over-estimate is 5e-4 with two
    per span, 5.5e-6 with four (90th percentile 2e-3); on random curves with loops and
    cusps the true curve's fitness is at worst 2e-2 with two, 2.7e-3 with four, 4.9e-4
    with eight (the earlier Taylor model with 48 samples: 3e-3).  Four trade that
    against time: the search is most of the fitness's cost.
    """
    need = [(n if closed else n - k) * (1 if k == 1 else per_span) for k, n in pairs]
    return int(min(MAX_SAMPLES, max(8, *need)))


def bucket_length(n: int) -> int:
    """The padded length of a curve of ``n`` fitness points: a multiple of 16 up to 128,
    then 8 steps per octave, so padding adds less than 12.5 % (and curves of similar
    lengths share one compiled program)."""
    if n <= 128:
        return 16 * math.ceil(n / 16)
    step = 2 ** (n.bit_length() - 4)  # 1/8 of the octave [2^(b-1), 2^b) holding n
    return step * math.ceil(n / step)


def polish_length(length: int) -> int:
    """The length the polish pads a curve's points to, from their bucket ``length``: the
    next power of two.  The polish compiles for longer than it runs (``fit(f4)``: 3.7
    CPU-seconds against 0.26 s), the swarm runs for longer than it compiles (2.9 s against
    2.4 CPU-seconds), so the polish pads further: curves of 129 to 256 points share one
    polish program (eight swarm buckets), its run up to 1.8x longer for a bucket just past
    a power of two."""
    return 1 << (length - 1).bit_length()


def pad_points(data: np.ndarray, mask: np.ndarray, length: int):
    """``data`` (..., N, D) and ``mask`` (..., N) padded to ``length`` points: copies of the
    last point, masked out (0), which every mean, residual and segment of the programs
    skips; for the swarm's bucket (:func:`bucket_length`) and the polish's
    (:func:`polish_length`)."""
    lead = [(0, 0)] * (mask.ndim - 1)
    extra = (0, length - mask.shape[-1])
    return np.pad(data, [*lead, extra, (0, 0)], mode="edge"), np.pad(mask, [*lead, extra])


def degree_groups(pairs, closed, num_samples=None) -> tuple[tuple[int, int, int, int], ...]:
    """``(degree, first, stop, samples)`` of each run of equal degrees in ``pairs``
    (sorted): the swarms one vmap runs, and their fitness's search samples
    (``num_samples``, or :func:`default_num_samples` of the run).

    Splitting a run so that its smaller counts search fewer samples was measured on W1
    (two groups each for degrees 2 and 3, 24 % less search work on paper): no gain in
    time within the noise, and a longer compile, so a degree is one group.  Measured
    again with the search stored apart: W1 2.68 s warm with both degrees cut
    (2.86 s with one), against 3.03 s, but cold 9.8-10.1 s (8.6 s with one) against 7.6 s,
    and the smaller counts, searching 4 samples a span where they had searched up to 16,
    found exact curves less often (two paper cases over seeds 0-5: 5 of 12 against 7 of
    12; ``tests/test_paper.py``'s sparse cubic lost at seed 0): still one group.
    """
    out = []
    for i, (k, _) in enumerate(pairs):
        if out and out[-1][0] == k:
            out[-1][2] = i + 1
        else:
            out.append([k, i, i + 1])
    return tuple(
        (k, i, j, num_samples or default_num_samples(pairs[i:j], closed)) for k, i, j in out
    )


class Prepared(NamedTuple):
    """One curve, ready for the device: normalisation, knots and seeds, all in NumPy."""

    points: np.ndarray  # the caller's points (float64; a closed input's repeat dropped)
    norm_pts: np.ndarray  # normalised: what the errors are measured on
    center: np.ndarray
    scale: float
    closed: bool
    pairs: list
    space: Layout
    groups: tuple
    data: np.ndarray  # the fitness's points (at most max_fitness_points), padded
    mask: np.ndarray  # 1 on real points, 0 on padding
    fit_pts: np.ndarray  # the fitness's points, unpadded (float64, in dtype's precision)
    ends: np.ndarray | None  # pinned end points of an open curve
    key_data: np.ndarray
    seed_value: int | None  # for reports


def prepare(points, closed: bool, opts: FitOptions, seed, name: str) -> Prepared:
    """Validate and normalise one curve's points (cheap: the least-squares seeds are
    built when its program call is launched, so a batch overlaps them with device work).

    ``name`` is how errors call the points (``points``, ``point_sets[3]``).
    """
    key = root_key(seed)
    pairs = check_pairs(opts.cps, opts.degrees, closed)
    try:
        pts = check_points(points)
    except ValueError as exc:
        raise ValueError(name + str(exc)[len("points") :]) from None
    if closed:
        pts = _drop_closing_duplicate(pts)
    n_max = max(n for _, n in pairs)
    if len(pts) < n_max:
        raise ValueError(
            f"{name}: {len(pts)} points are too few for {n_max} control points; "
            f"give at least as many points as the largest count in cps"
        )
    if np.ptp(pts, axis=0).max() == 0:
        warnings.warn(
            f"{name} all coincide: every curve collapses onto that point", UserWarning, stacklevel=3
        )
    dtype = opts.dtype
    norm_pts, center, scale = normalise(pts)
    fit_pts = canonical_order(norm_pts)
    if len(fit_pts) > opts.max_fitness_points:
        fit_pts = fit_pts[
            np.unique(np.linspace(0, len(fit_pts) - 1, opts.max_fitness_points).round().astype(int))
        ]
    # The swarm's data, and the host's seed and ends, in the swarm's precision: the host
    # then works on exactly the numbers the device sees, so shifting or scaling the input
    # (which moves norm_pts by rounding only) cannot tip the seed's nearest-point choices.
    fit_pts = fit_pts.astype(dtype).astype(np.float64)
    dim = pts.shape[1]
    degrees_used = sorted({k for k, _ in pairs})
    most = max(n if closed else n - k for k, n in pairs)
    if opts.num_samples is not None and opts.num_samples < most:
        raise ValueError(
            f"num_samples must be >= the most knot spans of a requested curve ({most}), "
            f"got {opts.num_samples}"
        )
    space = Layout(
        n_pad=n_max,
        dim=dim,
        rational=opts.rational,
        num_knots=(n_max if closed else n_max - degrees_used[0]) if opts.free_knots else 0,
        closed=closed,
    )
    ends = fit_pts[[0, -1]] if (opts.fix_ends and not closed) else None
    data, mask = pad_points(fit_pts, np.ones(len(fit_pts)), bucket_length(len(fit_pts)))
    return Prepared(
        points=pts,
        norm_pts=norm_pts,
        center=center,
        scale=scale,
        closed=closed,
        pairs=pairs,
        space=space,
        groups=degree_groups(pairs, closed, opts.num_samples),
        data=data.astype(dtype),
        mask=mask.astype(dtype),
        fit_pts=fit_pts,
        ends=ends,
        key_data=np.asarray(jax.random.key_data(key)),
        seed_value=int(seed) if isinstance(seed, (int, np.integer)) else None,
    )


def group_key(prep: Prepared) -> tuple:
    """Curves with equal keys run in one compiled program (the shape bucket)."""
    return prep.space, prep.groups, len(prep.data)


def root_key(seed) -> jax.Array:
    """The call's key from ``seed``: an int, or one JAX key of the default implementation
    (typed, or its raw uint32 data), whose data the programs wrap back as such."""
    if isinstance(seed, jax.Array):
        try:
            typed = jnp.issubdtype(seed.dtype, jax.dtypes.prng_key)
            key = seed if typed else jax.random.wrap_key_data(seed)
            impl = str(jax.random.key_impl(key))
        except TypeError:  # raw data of the wrong shape or type
            key, impl = None, None
        default = jax.config.jax_default_prng_impl
        if impl != default or key.shape != ():
            raise ValueError(
                f"seed must be an int or one JAX PRNG key of the default implementation "
                f"({default}), e.g. jax.random.key(0); got {seed.dtype} of shape {seed.shape}"
                + ("" if impl is None else f", implementation {impl}")
            )
        return key
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an int or a JAX PRNG key, got {seed!r}")
    return jax.random.key(int(seed))


def _drop_closing_duplicate(points: np.ndarray) -> np.ndarray:
    """A closed outline may repeat its first point at the end; that copy is not data."""
    span = np.ptp(points, axis=0).max()
    if len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= 1e-12 * max(span, 1.0):
        return points[:-1]
    return points


def canonical_order(points: np.ndarray) -> np.ndarray:
    """``points`` or ``points[::-1]``, whichever is lexicographically first.

    The swarm sees the same array for an input and its reverse, so both give the same
    curves (then oriented like each input): reversing the input never changes the fit.
    """
    fwd, rev = points.ravel(), points[::-1].ravel()
    differ = np.flatnonzero(fwd != rev)
    return points if len(differ) == 0 or fwd[differ[0]] < rev[differ[0]] else points[::-1]
