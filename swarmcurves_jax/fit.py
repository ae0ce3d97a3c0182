"""``fit``: every (degree, n) swarm of a call, run as one compiled XLA program."""

from __future__ import annotations

import functools
import inspect
import math
import os
import queue
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P
from pykdtree.kdtree import KDTree

from . import pso
from . import refine as local
from ._validation import (
    check_bool,
    check_no_unknown,
    check_pairs,
    check_params,
    check_points,
    check_positive_int,
    check_tol,
    check_weight_bounds,
)
from .basis import design_matrix
from .curves import Curve
from .devices import Placement, cpu_devices
from .fitness import (
    PRECISION,
    Polyline,
    SpanBasis,
    curve_samples,
    data_segments,
    excursion,
    foot_samples,
    free_knot_basis,
    make_span_basis,
    point_distances,
    sample_excursions,
)
from .knots import (
    curvature_widths,
    knots_from_widths,
    logits_from_widths,
    make_knots,
    span_widths,
)
from .measures import deviations
from .projection import project_points
from .results import FitResult

__all__ = ["fit", "normalise", "default_num_samples", "bucket_length"]


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


#: The most fitness samples a curve may have (the search packs their index into a float).
MAX_SAMPLES = 4096


#: Fitness search samples per knot span (a polygon's segments need one: searched exactly).
SAMPLES_PER_SPAN = 4
#: The refinement's samples per span: it runs a few dozen evaluations, not 2000 x 64,
#: and polishes to the limit of float32 only from starts near each foot point (measured:
#: a perturbed random cubic polishes to 4e-8 with 16, 1.2e-4 with 4).
REFINE_SAMPLES_PER_SPAN = 16


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


class _Space(NamedTuple):
    """Static layout of a particle's flat position: ``n_pad`` points of ``dim`` coords,
    then ``n_pad`` log-weights when rational, then ``num_knots`` knot logits (free knots:
    :func:`swarmcurves_jax.knots.span_widths`), and what the fitness needs to read them."""

    n_pad: int
    dim: int
    rational: bool
    num_knots: int = 0
    closed: bool = False

    @property
    def num_ctrl(self) -> int:
        return self.n_pad * self.dim

    @property
    def size(self) -> int:
        return self.num_ctrl + (self.n_pad if self.rational else 0) + self.num_knots

    def knot_logits(self, q):
        return q[self.size - self.num_knots :]

    def basis(self, q, pair, k, fixed: SpanBasis) -> SpanBasis:
        """The fitness's basis: ``fixed`` (precomputed), or from ``q``'s free knots (with
        as many search samples as ``fixed``)."""
        if not self.num_knots:
            return fixed
        spans = pair[1] if self.closed else pair[1] - pair[0]
        samples = fixed.sample_value.shape[0]
        return free_knot_basis(self.knot_logits(q), spans, k, self.closed, samples, self.n_pad)

    def split(self, q):
        """``(ctrl (n_pad, dim), log_weights (n_pad,) or None)`` of a position (JAX or NumPy)."""
        ctrl = q[: self.num_ctrl].reshape(self.n_pad, self.dim)
        return ctrl, (q[self.num_ctrl : self.num_ctrl + self.n_pad] if self.rational else None)


def _geometry(q, space):
    ctrl, log_w = space.split(q)
    return ctrl, None if log_w is None else jnp.exp(log_w)


def _distances(q, basis, points, space, pair, k, foot=None, stale=False):
    """Estimated distance of every point to the curve of position ``q``: shape (N,).
    A ``foot`` given here is stored (a branch's result, the dense search's),
    never fused from a search in the same loop, so it needs no barrier; ``stale``: it may
    be an earlier position's (:func:`~swarmcurves_jax.fitness.point_distances`)."""
    uniform = not space.num_knots
    basis = space.basis(q, pair, k, basis)
    return point_distances(
        *_geometry(q, space),
        basis,
        points,
        foot,
        degree=k,
        barrier=foot is None,
        uniform=uniform,
        stale=stale,
    )


def _feet(q, basis, points, space, pair, k, dense=True):
    """Where each point's Newton steps start on the curve of position ``q``, in samples:
    shape (N,) float (:func:`~swarmcurves_jax.fitness.search_starts`)."""
    basis = space.basis(q, pair, k, basis)
    return foot_samples(*_geometry(q, space), basis, points, dense)


def _excursion(q, basis, polyline: Polyline, space, pair, k, per_sample=False):
    """How far the curve of position ``q`` strays from the data polyline: the arc-length
    mean excess (:func:`~swarmcurves_jax.fitness.excursion`), or with ``per_sample`` each
    sample's excess and arc length."""
    basis = space.basis(q, pair, k, basis)
    samples, tangents = curve_samples(*_geometry(q, space), basis)
    if per_sample:
        return sample_excursions(samples, tangents, basis, polyline)
    return excursion(samples, tangents, basis, polyline)


def _search_apart(space: _Space) -> bool:
    """Whether the swarm's search runs in a branch of its own every iteration, its result
    stored and read by the Newton steps: on the CPU, with fixed knots.

    After the search, each point's span selects, Newton steps and divisions form one chain
    of dependent operations, and XLA:CPU's fused loop over the points waits on it (measured
    on W1: leaving one exact ``sqrt`` out of the chain made it 4 % faster, with as many
    instructions).  With the search apart, the chain needs no ``sqrt`` barrier and can run
    two points per loop trip (:func:`_paired`).  Measured on a 2-core AVX2 EPYC: W1 (warm,
    interleaved in one process) 3.87 s fused -> 3.63 s apart -> 3.45 s paired; the swarm
    stage of 2D degrees 4-5 (300 iterations) 0.86 -> 0.76 -> 0.71 s; 3D cubics and 3D
    quintics within 4 % either way.  Free knots keep the fused search (each particle's
    basis would be built twice: 1.7x slower paired), and other backends too (a branch per
    iteration there is not measured).
    """
    return jax.default_backend() == "cpu" and not space.num_knots


def _paired(space: _Space, k: int) -> bool:
    """Whether the Newton steps run two points per loop trip (the points in two halves):
    where a point's span coefficients, ``(k + 3) x (dim [+ 1 if rational])`` values, are at
    most 16.  Two chains of more spill AVX2's 16 registers: 3D quintics (24 values) ran
    15 % slower paired, a 2D rational cubic (18) 3 %; three or four parts of W1's points
    ran slower than one (4.25 and 4.40 against 3.63 s)."""
    return _search_apart(space) and (k + 3) * (space.dim + space.rational) <= 16


def _by_degree(fn, groups, bases, *args):
    """``fn(*args_of_one_swarm, basis, k=degree)`` vmapped over the swarms of each degree
    group, concatenated: a group's basis has its own shapes (spans, samples) and its
    degree is static, so its fitness is specialised (a polygon's is a fraction of a
    cubic's).  ``groups``: :func:`_degree_groups`; ``bases`` one per group.
    """
    parts = [
        jax.vmap(functools.partial(fn, k=k))(
            *(jax.tree_util.tree_map(lambda a, i=i, j=j: a[i:j], x) for x in args), basis
        )
        for (k, i, j, _), basis in zip(groups, bases, strict=True)
    ]
    return jax.tree_util.tree_map(lambda *p: jnp.concatenate(p), *parts)


def _masked_mean(distances, mask, count, parts: int = 1):
    """Mean of ``distances(cut)`` over the real points: the padding (``mask`` 0) adds
    nothing.  The points are cut into ``parts`` equal slices whose distances are summed
    elementwise, so that each loop trip runs ``parts`` independent chains (:func:`_paired`).
    The sum is a product with ones: XLA:CPU rewrites a sum of more than 32 values as a
    pass of partial sums over the stored distances, which took longer than the product
    (measured on W1, warm, interleaved in one process: 3.05 against 3.10 s).
    Times the reciprocal, not ``/ count``: see
    :func:`swarmcurves_jax.fitness._span_and_start`."""
    size = mask.shape[0] // parts
    d = [distances(c) * mask[c] for c in (slice(i * size, (i + 1) * size) for i in range(parts))]
    total = sum(d[1:], d[0])
    return jnp.dot(total, jnp.ones_like(total), precision=PRECISION) * (1.0 / count)


def _over_curves(fn, per_curve, shared, mesh, batch):
    """``fn(shared, *one_curve)`` for every curve along the leading axis of ``per_curve``.

    A loop (``lax.map``), ``batch`` curves vmapped per trip: with ``batch`` 1 every curve
    runs exactly the program a lone fit runs, so results do not depend on the batch (on
    XLA:CPU a vmapped curve axis also makes the work 10-70 % slower).  With a ``mesh`` the
    curves are split over its devices by ``shard_map``, each looping over its own share.
    """

    def local(per_curve, shared):
        size = jax.tree_util.tree_leaves(per_curve)[0].shape[0]
        step = min(batch, size)
        return jax.lax.map(
            lambda c: fn(shared, *c), per_curve, batch_size=step if step > 1 else None
        )

    if mesh is None:
        return local(per_curve, shared)
    spec = P(mesh.axis_names[0])
    # No collectives inside: each device's loop is independent, so the varying-axis
    # checks (which would want every replicated loop carry cast) are off.
    split = jax.shard_map(local, mesh=mesh, in_specs=(spec, P()), out_specs=spec, check_vma=False)
    return split(per_curve, shared)


#: XLA:CPU settings of the swarm program (other backends ignore them), measured on W1
#: (``benchmarks/bench_w1.py``): 512-bit vectors where the CPU has them (the search runs
#: 1.5x faster on AVX-512), and no YNNPACK fusions, which split the fitness into loops
#: that each re-read their inputs (1.5x slower).
CPU_COMPILER_OPTIONS = {
    "xla_cpu_prefer_vector_width": 512,
    "xla_cpu_experimental_ynn_fusion_type": "",
}
#: The swarm program's: also ``min``/``max`` (and so ``clip``) as single instructions,
#: not NaN-propagating, which on x86 costs a compare and a blend more each (measured:
#: W1's fitness 12 % less CPU time, its search has four per pair).  Its values are finite
#: by construction (positions in their box, validated points, weights ``exp`` of bounded
#: logs), and a non-finite fitness is caught by ``isfinite`` (:func:`pso.update`).
SWARM_COMPILER_OPTIONS = CPU_COMPILER_OPTIONS | {"xla_cpu_enable_fast_min_max": True}


@functools.partial(
    jax.jit,
    static_argnames=(
        "space",
        "num_steps",
        "seeded",
        "groups",
        "search_every",
        "mesh",
        "batch",
    ),
    compiler_options=SWARM_COMPILER_OPTIONS,
)
def _swarm_program(
    keys,
    draws,
    state,
    feet,
    first,
    boxes,
    seeds,
    points,
    mask,
    shared,
    *,
    space,
    num_steps,
    seeded,
    groups,
    search_every=1,
    mesh=None,
    batch=1,
):
    """Run ``num_steps`` PSO steps of every swarm of every curve; swarms whose ``step`` is 0
    start fresh.  Per curve (leading axis): ``keys`` and ``draws``, each swarm's run key
    data and initial draws (:func:`_initial_draws`), ``state``, ``feet`` (the
    last search's starts, (swarms, P, N) floats; ``()`` when ``search_every`` is 1),
    ``boxes``, ``seeds``, ``points`` (padded to a bucket length) and ``mask`` (1 on real
    points); ``shared``: ``(pairs, params, bases, tol, max_steps)``; ``first``: the
    iteration this chunk starts at (the searches fall on multiples of ``search_every``).
    """

    def one_curve(shared, key_data, draws, state, feet, boxes, seeds, points, mask):
        (pairs, params, bases, tol, max_steps), first = shared
        count = jnp.sum(mask)
        polyline = data_segments(points, mask, space.closed)

        def start(draw, state, box, seed):
            """The swarm's state, fresh where it has not started."""
            fresh = pso.init_from_uniforms(draw, box, seed)
            return jax.tree_util.tree_map(
                lambda a, b: jnp.where(state.step == 0, a, b), fresh, state
            )

        state = jax.vmap(start)(draws, state, boxes, seeds if seeded else None)
        run_keys = jax.random.wrap_key_data(key_data)

        def group_fitness(pair, positions, feet, basis, k, search):
            """The group's fitness (P,) and feet.  A polygon's search is its exact distance,
            run inside each evaluation (no Newton steps).  Otherwise the search runs in a
            branch of its own (every ``search_every`` iterations, or every iteration where
            :func:`_search_apart`), so that its result is stored once, not recomputed by
            each reader (XLA:CPU fuses cheap producers into each); else it is fused."""

            def mean(q, foot, parts=1):  # a bucket length is a multiple of 16: 2 parts fit
                def at(cut):
                    found = None if foot is None else foot[cut]
                    return _distances(
                        q, basis, points[cut], space, pair, k, found, search_every > 1
                    )

                strays = _excursion(q, basis, polyline, space, pair, k)
                return _masked_mean(at, mask, count, parts) + strays

            if k == 1 or (search_every == 1 and not _search_apart(space)):
                return jax.vmap(lambda q: mean(q, None))(positions), feet

            def searched():
                return jax.vmap(lambda q: _feet(q, basis, points, space, pair, k, False))(positions)

            stored = (
                feet if search_every > 1 else jnp.zeros((len(positions), *mask.shape), points.dtype)
            )
            found = jax.lax.cond(search, searched, lambda: stored)
            read = functools.partial(mean, parts=2 if _paired(space, k) else 1)
            return jax.vmap(read)(positions, found), found if search_every > 1 else feet

        def fitness(positions, feet, iteration):  # (swarms, P, dim) -> (swarms, P), feet
            # With search_every 1 every iteration searches, by `iteration >= 0`: a constant
            # true would dissolve the branch (and fuse the search again), and XLA cannot
            # fold this one (`first` is a runtime value).
            search = iteration % search_every == 0 if search_every > 1 else iteration >= 0
            search = functools.partial(group_fitness, search=search)
            return _by_degree(search, groups, bases, pairs, positions, feet)

        (state, feet), info = pso.run_swarms(
            run_keys, state, params, boxes, fitness, num_steps, tol, max_steps, feet, first
        )
        return state, feet, jax.tree_util.tree_map(lambda a: a.T, info)  # (swarms, steps)

    per_curve = (keys, draws, state, feet, boxes, seeds, points, mask)
    return _over_curves(one_curve, per_curve, (shared, first), mesh, batch)


@functools.partial(
    jax.jit,
    static_argnames=("num_particles", "size", "dtype"),
    compiler_options={"xla_backend_optimization_level": 1},
)
def _initial_draws(key_data, pairs, *, num_particles, size, dtype):
    """Every swarm's run key data and its initial positions' U[0, 1) draws, per curve:
    (curves, swarms, 2) uint32 and (curves, swarms, num_particles, size).

    A swarm's key is its curve's key folded with its degree and count, so its random
    stream depends neither on the other swarms nor on the other curves of the call.
    A program of its own, run while the swarm programs trace: threefry compiled into each
    swarm program took about 1 s of its compilation on XLA:CPU, for work done once per
    call.  Integer hashing and exact conversions, so LLVM's level 1 gives the same bits
    and compiles in 0.33 s against 0.78 s, running as fast (measured at W1's shapes).
    """

    def one(key_data, pair):
        key = jax.random.fold_in(
            jax.random.fold_in(jax.random.wrap_key_data(key_data), pair[0]), pair[1]
        )
        init_key, run_key = jax.random.split(key)
        u = jax.random.uniform(init_key, (num_particles, size), dtype=dtype)
        return jax.random.key_data(run_key), u

    return jax.vmap(jax.vmap(one, (None, 0)), (0, None))(key_data, pairs)


#: Starts refined per swarm: its best, its least-squares seed, its next best particles.
REFINE_STARTS = 4


@functools.partial(
    jax.jit,
    static_argnames=("space", "method", "seeded", "groups", "mesh", "batch"),
    compiler_options=CPU_COMPILER_OPTIONS,
)
def _refine_program(
    state, boxes, seeds, points, mask, shared, *, space, method, seeded, groups, mesh=None, batch=1
):
    """Polish every swarm of every curve from ``REFINE_STARTS`` starts; per swarm, the
    result with the best hold-out score (:data:`swarmcurves_jax.refine.HOLDOUT_EVERY`)
    and its fitness.  Padded points (``mask`` 0) have zero residuals."""

    def one_curve(shared, state, boxes, seeds, points, mask):
        pairs, bases = shared
        holdout = (jnp.arange(points.shape[0]) % local.HOLDOUT_EVERY == 2) * mask
        polyline = data_segments(points, mask, space.closed)
        count = jnp.sum(mask)

        def one_swarm(pair, state, box, seed, basis, k):
            def residuals(q, foot):
                """The points' distances, then each curve sample's excursion weighted by
                its share of the arc (times the point count: their sum per point is the
                swarm's excursion term)."""
                near = _distances(q, basis, points, space, pair, k, foot) * mask
                excess, arc = _excursion(q, basis, polyline, space, pair, k, per_sample=True)
                share = jax.lax.stop_gradient(arc * (count / jnp.maximum(jnp.sum(arc), 1e-30)))
                return jnp.concatenate([near, excess * share])

            def search(q):
                return foot_samples(*_geometry(q, space), space.basis(q, pair, k, basis), points)

            free = box.mask * (box.lower != box.upper)  # pinned ends and padding stay
            others = min(REFINE_STARTS - 1 - int(seeded), state.pbest_fitness.shape[0])
            _, top = jax.lax.top_k(-state.pbest_fitness, others)
            starts = [state.best_position[None], state.pbest_position[top]]
            starts = jnp.concatenate(starts + ([seed[None]] if seeded else []))
            polish = local.levenberg_marquardt if method == "lm" else local.lbfgs
            extra = jnp.zeros(basis.sample_value.shape[-2], mask.dtype)
            problem = local.Problem(
                residuals,
                search,
                free,
                box.lower,
                box.upper,
                jnp.concatenate([holdout, extra]),
                jnp.concatenate([mask, extra]),
                jnp.concatenate([jnp.zeros_like(mask), extra + 1.0]),
            )
            xs, fs, scores = jax.vmap(lambda x0: polish(problem, x0))(starts)
            i = jnp.argmin(jnp.where(jnp.isnan(scores), jnp.inf, scores))
            return xs[i], fs[i]

        return _by_degree(one_swarm, groups, bases, pairs, state, boxes, seeds)

    per_curve = (state, boxes, seeds, points, mask)
    return _over_curves(one_curve, per_curve, shared, mesh, batch)


def _empty_state(num_curves, num_swarms, num_particles, dim, dtype) -> pso.PSOState:
    """Host-built placeholder (step 0): the program initialises it on its first chunk."""
    lead = (num_curves, num_swarms)
    z = lambda *shape: np.zeros((*lead, *shape), dtype)  # noqa: E731
    return pso.PSOState(
        position=z(num_particles, dim),
        velocity=z(num_particles, dim),
        pbest_position=z(num_particles, dim),
        pbest_fitness=np.full((*lead, num_particles), np.inf, dtype),
        gbest_position=z(dim),
        gbest_fitness=np.full(lead, np.inf, dtype),
        best_position=z(dim),
        best_fitness=np.full(lead, np.inf, dtype),
        stall=np.zeros(lead, np.int32),
        step=np.zeros(lead, np.int32),
    )


#: Knot logits stay in [-3, 3]: span widths then differ by up to e^6 ~ 400x before the
#: minimum span (MIN_SPAN_FRACTION of a uniform span) takes over.
KNOT_LOGIT_BOUND = 3.0


def _boxes(pairs, space: _Space, weight_bounds, ends, dtype) -> pso.Box:
    """Per-swarm search boxes.

    Control points start in U[-1, 1] and are unbounded after; log-weights start in
    U[-1, 1] and stay inside log(weight_bounds); knot logits start in U[-0.1, 0.1] (near
    uniform knots) and stay inside +-KNOT_LOGIT_BOUND.  ``ends`` ((2, D) or None) pins the
    first and last control points of open curves to the data's end points (lower = upper).
    """
    num_ctrl, size = space.num_ctrl, space.size
    init_lo, init_hi = -np.ones(size), np.ones(size)
    lower, upper = np.full(size, -np.inf), np.full(size, np.inf)
    if space.rational:
        wlo, whi = np.log(weight_bounds[0]), np.log(weight_bounds[1])
        lower[num_ctrl:], upper[num_ctrl:] = wlo, whi
        init_lo[num_ctrl:] = np.maximum(-1.0, wlo)
        init_hi[num_ctrl:] = np.minimum(1.0, whi)
    if space.num_knots:
        init_lo[-space.num_knots :], init_hi[-space.num_knots :] = -0.1, 0.1
        lower[-space.num_knots :], upper[-space.num_knots :] = -KNOT_LOGIT_BOUND, KNOT_LOGIT_BOUND
    boxes = []
    for k, n in pairs:
        b = [init_lo.copy(), init_hi.copy(), lower.copy(), upper.copy(), np.zeros(size)]
        b[4][: n * space.dim] = 1
        if space.rational:
            b[4][num_ctrl : num_ctrl + n] = 1
        if space.num_knots:
            first = size - space.num_knots
            b[4][first : first + (n if space.closed else n - k)] = 1
        if ends is not None:
            for row, point in ((0, ends[0]), (n - 1, ends[1])):
                sl = slice(row * space.dim, (row + 1) * space.dim)
                for arr in b[:4]:
                    arr[sl] = point
        boxes.append(b)
    return pso.Box(*(np.array(parts, dtype) for parts in zip(*boxes)))


def chord_parameters(points: np.ndarray, closed: bool) -> np.ndarray:
    """Cumulative chord-length parameters in [0, 1] (closed: [0, 1), the seam at 0)."""
    pts = np.vstack([points, points[:1]]) if closed else points
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)])
    u = u / u[-1] if u[-1] > 0 else np.linspace(0, 1, len(pts))
    return u[:-1] if closed else u


def _lsq(b, points, ends):
    if ends is None:
        return np.linalg.lstsq(b, points, rcond=None)[0]
    rhs = points - np.outer(b[:, 0], ends[0]) - np.outer(b[:, -1], ends[1])
    inner = np.linalg.lstsq(b[:, 1:-1], rhs, rcond=None)[0]
    return np.vstack([ends[0], inner, ends[1]])


def least_squares_ctrl(points, n, k, closed, ends=None, rounds: int = 20, t=None) -> np.ndarray:
    """Linear least-squares control points with parameter correction (the swarm's seed).

    Starts from chord-length parameters, then ``rounds`` times moves every point's
    parameter to its nearest point on the current curve (a 2048-sample grid) and solves
    again (Hoschek's correction).  Chord lengths alone misplace the parameters of looping
    curves; measured on random closed cubics the correction lifts recovery from 4 to 6
    of 12 (``benchmarks/recovery_rates.py``).  With ``ends`` the first and last control
    points are fixed.  ``t``: the knot vector (default: the uniform one).
    """
    if t is None:
        t, dense = make_knots(n, k, closed), _uniform_grid_design(n, k, closed)
    else:
        dense = design_matrix(_seed_grid(closed), t, k, closed=closed)
    ctrl = _lsq(design_matrix(chord_parameters(points, closed), t, k, closed=closed), points, ends)
    best, best_err, last = ctrl, np.inf, None
    for _ in range(rounds + 1):
        # each point's nearest grid sample, exact (pykdtree rather than scipy's cKDTree: W1's
        # seeds 0.18 -> 0.10 s on two threads; cKDTree spends three quarters of its build
        # in NumPy's slow min and max down the columns of a (2048, 2) array)
        dist, j = KDTree(dense @ ctrl).query(points)
        err = np.mean(dist)
        if err < best_err:  # a correction can also fold the parameters: keep the best
            best, best_err = ctrl, err
        if last is not None and np.array_equal(j, last):
            break  # a fixed point: every later round would give this same curve again
        ctrl, last = _lsq(dense[j], points, ends), j
    return best


def _seed_grid(closed: bool) -> np.ndarray:
    """The 2048 parameters whose curve points the seeds' correction searches."""
    return np.linspace(0.0, 1.0, 2048, endpoint=not closed)


def _uniform_grid_design(n: int, k: int, closed: bool) -> np.ndarray:
    """:func:`_seed_grid`'s design matrix on the uniform knots (read-only): the same for
    every call of a shape, so made once (W1's 21 swarms: 9 ms a call), up to 64 control
    points (the cache then holds at most 32 MB)."""
    return (_grid_design if n <= 64 else _grid_design.__wrapped__)(n, k, closed)


@functools.lru_cache(maxsize=32)
def _grid_design(n: int, k: int, closed: bool) -> np.ndarray:
    dense = design_matrix(_seed_grid(closed), make_knots(n, k, closed), k, closed=closed)
    dense.setflags(write=False)
    return dense


def _host_map(fn, items) -> list:
    """``[fn(x) for x in items]``, in order, on a thread per CPU: the host's per-swarm
    work (least-squares seeds, true projections) comes before and after a lone fit's swarm
    program, and its k-d tree queries and LAPACK solves release Python's lock.  Measured
    on W1 (2 cores, warm): seeds 0.27 -> 0.19 s, projections 0.18 -> 0.13 s, the same
    curves bit for bit."""
    items = list(items)
    workers = min(len(items), os.cpu_count() or 1)
    if workers < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, items))


def _seeds(pairs, space: _Space, norm_pts, closed, ends, dtype) -> np.ndarray:
    """One least-squares position per swarm, laid out like a particle."""

    def one(pair):
        k, n = pair
        row, t = np.zeros(space.size), None
        if space.num_knots:  # free knots: start where the data turn (knots.curvature_widths)
            spans = n if closed else n - k
            logits = logits_from_widths(curvature_widths(norm_pts, spans, closed))
            first = space.size - space.num_knots
            row[first : first + spans] = np.clip(logits, -KNOT_LOGIT_BOUND, KNOT_LOGIT_BOUND)
            t = _knots(row, k, n, space)
        row[: n * space.dim] = least_squares_ctrl(norm_pts, n, k, closed, ends, t=t).ravel()
        return row

    return np.stack(_host_map(one, pairs)).astype(dtype)


def stack_bases(pairs, closed, num_samples, n_pad, dtype) -> SpanBasis:
    """The precomputed span bases (fixed knots) of swarms, stacked and padded alike;
    read-only, made once per shape (W1's three groups: 10 ms a call)."""
    key = tuple((int(k), int(n)) for k, n in pairs)
    return _stacked_bases(key, bool(closed), int(num_samples), int(n_pad), np.dtype(dtype))


@functools.lru_cache(maxsize=64)
def _stacked_bases(pairs, closed, num_samples, n_pad, dtype) -> SpanBasis:
    spans = max(n if closed else n - k for k, n in pairs)
    top = max(k for k, _ in pairs)
    per = [make_span_basis(n, k, closed, num_samples, n_pad, spans, top) for k, n in pairs]
    stacked = SpanBasis(
        *(
            np.stack(parts).astype(np.int32 if name in ("per_span", "num_spans") else dtype)
            for name, parts in zip(SpanBasis._fields, zip(*per))
        )
    )
    for a in stacked:
        a.setflags(write=False)
    return stacked


def _root_key(seed) -> jax.Array:
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


def fit(
    points,
    cps=range(4, 11),
    degrees=3,
    *,
    closed: bool = False,
    rational: bool = False,
    free_knots: bool = False,
    fix_ends: bool = True,
    init: str = "lsq",
    refine: bool | str = True,
    particles: int = 64,
    iterations: int = 2000,
    tol: float | None = None,
    seed: int | jax.Array = 0,
    params: pso.PSOParams | None = None,
    weight_bounds: tuple[float, float] = (1e-2, 1e2),
    num_samples: int | None = None,
    search_every: int = 1,
    chunk_size: int = 200,
    callback: Callable[[int, np.ndarray], object] | None = None,
    progress: bool = False,
    max_fitness_points: int = 2000,
    dtype=jnp.float32,
    **unknown,
) -> FitResult:
    """Fit B-spline (or NURBS) curves with every requested degree and control-point count.

    Each (degree, n) pair is an independent particle swarm; all swarms of the
    call run in one jit-compiled program, on the default JAX device (a GPU if JAX sees
    one); when JAX has several CPU devices (``jax_num_cpu_devices``), the swarms are
    dealt over them, one program each, with the same results
    (:func:`~swarmcurves_jax.devices.cpu_devices`).  Reported errors are true
    point-to-curve distances in the normalised frame.

    Parameters
    ----------
    points : array_like, shape (N, 2) or (N, 3)
        Points ordered along the curve.  For ``closed=True`` a last point that repeats
        the first is dropped (it carries no information).
    cps : int or iterable of int
        Control-point counts.
    degrees : int or iterable of int
        Degrees (1 is a polygon).  Every count must be ``>= degree + 1``.
    closed : bool
        Closed curve on uniform periodic knots (``C^(degree-1)`` at the seam) instead of
        an open curve on clamped uniform knots (end points interpolated).
    rational : bool
        Optimise NURBS weights too, inside ``weight_bounds``; reported scaled to max 1.
    free_knots : bool
        Let the swarm (and the refinement) move the interior knots too, kept sorted with
        every span at least 10 % of a uniform one (:mod:`swarmcurves_jax.knots`), so knots
        gather where the curvature is high.  Default: the paper's fixed uniform knots.
    init : {"lsq", "uniform"}
        ``"lsq"`` puts one particle per swarm on the least-squares fit (with parameter
        correction); ``"uniform"`` starts every particle in U[-1, 1] as the paper does.
    refine : bool or {"lm", "lbfgs"}
        Polish every swarm's solution locally after the swarm (see
        :mod:`swarmcurves_jax.refine`): ``True`` or ``"lm"`` is Levenberg–Marquardt on
        the orthogonal distances, ``"lbfgs"`` optax's L-BFGS, ``False`` the paper's pure
        PSO.  A polished solution replaces the swarm's only if its two-sided
        ``mean_deviation`` is lower.
    particles : int
        Particles per swarm.
    iterations : int
        Iteration limit (the paper: 2000).  Each iteration evaluates every particle once.
    tol : float, optional
        Stop a swarm once its best fitness (mean distance plus the excursion term,
        normalised frame) is ``<= tol``;
        the call returns as soon as every swarm has.
    seed : int or jax PRNG key
        Same inputs and seed give the same curves (on the same device).
    params : PSOParams, optional
        Inertia, cognitive and social coefficients and the velocity clamp
        (default :func:`swarmcurves_jax.pso.default_params`).
    weight_bounds : (float, float)
        Bounds of the rational weights during the search.
    num_samples : int, optional
        Curve samples used by the fitness (default :func:`default_num_samples`).
    search_every : int
        The swarm searches each point's nearest curve sample (most of the fitness's work)
        every ``search_every`` iterations (polygons: every iteration); in between, a
        particle's Newton steps start from its last search's samples.  8 is faster, but
        the swarm finds exact curves less often
        (docs/method.md, "Reusing the search"); the default 1 searches every iteration.
    chunk_size : int
        Iterations per compiled chunk; between chunks the host checks ``tol`` and calls
        ``callback``.  Results do not depend on it.
    callback : callable, optional
        ``callback(iteration, best_fitness)`` after every chunk, ``best_fitness`` of shape
        (num_solutions,).
    max_fitness_points : int
        The swarm's fitness uses at most this many of the points, evenly spread along
        their order (all of them when there are fewer); the reported errors always use
        every point.  Keeps time and memory bounded for huge scans.
    progress : bool
        Show a progress bar (tqdm) with the best error per degree.  Quiet by default.
        Ctrl-C stops the run cleanly: the result holds the best solutions found so far
        and ``stop_reason == "interrupted"``.
    dtype : jnp.float32 or jnp.float64
        Precision of the swarm (float64 needs ``jax_enable_x64``).

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np
    >>> from swarmcurves_jax import fit
    >>> x = np.linspace(-1, 1, 50)
    >>> result = fit(np.c_[x, x**2], cps=[3, 4], degrees=2, iterations=300)
    >>> result[2, 3].error < 1e-2
    True
    """
    start = time.perf_counter()
    check_no_unknown(unknown, _FIT_ARGS)
    closed = check_bool(closed, "closed")
    check_pairs(cps, degrees, closed)
    opts = _options(**{name: value for name, value in locals().items() if name in _OPTIONS})
    if callback is not None and not callable(callback):
        raise ValueError(f"callback must be callable or None, got {callback!r}")
    prep = _prepare(points, closed, opts, seed, "points")
    bar = _progress_bar(opts.iterations, prep.pairs) if opts.progress else None
    try:
        (result,) = _run_group(
            [prep],
            opts,
            callback=None if callback is None else lambda at, best: callback(at, best[0]),
            bar=bar,
            catch_interrupt=True,
            start=start,
            split=cpu_devices(),
        )
    finally:
        if bar is not None:
            bar.close()
    return result


class _Options(NamedTuple):
    """A call's validated options, shared by every curve of a batch."""

    cps: object
    degrees: object
    rational: bool
    free_knots: bool
    fix_ends: bool
    init: str
    method: str | None
    particles: int
    iterations: int
    tol: float | None
    params: pso.PSOParams
    weight_bounds: tuple[float, float]
    num_samples: int | None
    search_every: int
    chunk_size: int
    progress: bool
    max_fitness_points: int
    dtype: object


#: fit's keyword arguments that every curve of a batch shares (checked by ``_options``).
_OPTIONS = (
    "cps degrees rational free_knots fix_ends init refine particles iterations tol params "
    "weight_bounds num_samples search_every chunk_size progress max_fitness_points dtype"
).split()


def _options(
    cps,
    degrees,
    rational,
    free_knots,
    fix_ends,
    init,
    refine,
    particles,
    iterations,
    tol,
    params,
    weight_bounds,
    num_samples,
    search_every,
    chunk_size,
    progress,
    max_fitness_points,
    dtype,
) -> _Options:
    """Check every shared option but the counts (checked per curve: their message says
    open or closed); exact errors that name the argument."""
    if init not in ("lsq", "uniform"):
        raise ValueError(f"init must be 'lsq' or 'uniform', got {init!r}")
    if num_samples is not None:
        num_samples = check_positive_int(num_samples, "num_samples")
        if num_samples > MAX_SAMPLES:
            raise ValueError(f"num_samples must be <= {MAX_SAMPLES}, got {num_samples}")
    dtype = jnp.dtype(dtype)
    if dtype not in (jnp.float32, jnp.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise ValueError("dtype float64 needs jax.config.update('jax_enable_x64', True)")
    return _Options(
        cps=cps,
        degrees=degrees,
        rational=check_bool(rational, "rational"),
        free_knots=check_bool(free_knots, "free_knots"),
        fix_ends=check_bool(fix_ends, "fix_ends"),
        init=init,
        method=_refine_method(refine),
        particles=check_positive_int(particles, "particles"),
        iterations=check_positive_int(iterations, "iterations"),
        tol=check_tol(tol),
        params=check_params(pso.default_params() if params is None else params),
        weight_bounds=check_weight_bounds(weight_bounds),
        num_samples=num_samples,
        search_every=check_positive_int(search_every, "search_every"),
        chunk_size=check_positive_int(chunk_size, "chunk_size"),
        progress=check_bool(progress, "progress"),
        max_fitness_points=check_positive_int(max_fitness_points, "max_fitness_points"),
        dtype=dtype,
    )


def bucket_length(n: int) -> int:
    """The padded length of a curve of ``n`` fitness points: a multiple of 16 up to 128,
    then 8 steps per octave, so padding adds less than 12.5 % (and curves of similar
    lengths share one compiled program)."""
    if n <= 128:
        return 16 * math.ceil(n / 16)
    step = 2 ** (n.bit_length() - 4)  # 1/8 of the octave [2^(b-1), 2^b) holding n
    return step * math.ceil(n / step)


class _Prepared(NamedTuple):
    """One curve, ready for the device: normalisation, knots and seeds, all in NumPy."""

    points: np.ndarray  # the caller's points (float64; a closed input's repeat dropped)
    norm_pts: np.ndarray  # normalised: what the errors are measured on
    center: np.ndarray
    scale: float
    closed: bool
    pairs: list
    space: _Space
    groups: tuple
    data: np.ndarray  # the fitness's points (at most max_fitness_points), padded
    mask: np.ndarray  # 1 on real points, 0 on padding
    fit_pts: np.ndarray  # the fitness's points, unpadded (float64, in dtype's precision)
    ends: np.ndarray | None  # pinned end points of an open curve
    key_data: np.ndarray
    seed_value: int | None  # for reports


def _prepare(points, closed: bool, opts: _Options, seed, name: str) -> _Prepared:
    """Validate and normalise one curve's points (cheap: the least-squares seeds are
    built when its program call is launched, so a batch overlaps them with device work).

    ``name`` is how errors call the points (``points``, ``point_sets[3]``).
    """
    root_key = _root_key(seed)
    try:
        pts = check_points(points)
    except ValueError as exc:
        raise ValueError(name + str(exc)[len("points") :]) from None
    pairs = check_pairs(opts.cps, opts.degrees, closed)
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
    fit_pts = _canonical_order(norm_pts)
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
    space = _Space(
        n_pad=n_max,
        dim=dim,
        rational=opts.rational,
        num_knots=(n_max if closed else n_max - degrees_used[0]) if opts.free_knots else 0,
        closed=closed,
    )
    ends = fit_pts[[0, -1]] if (opts.fix_ends and not closed) else None
    length = bucket_length(len(fit_pts))
    pad = length - len(fit_pts)
    return _Prepared(
        points=pts,
        norm_pts=norm_pts,
        center=center,
        scale=scale,
        closed=closed,
        pairs=pairs,
        space=space,
        groups=_degree_groups(pairs, closed, opts.num_samples),
        data=np.concatenate([fit_pts, np.repeat(fit_pts[-1:], pad, axis=0)]).astype(dtype),
        mask=np.r_[np.ones(len(fit_pts)), np.zeros(pad)].astype(dtype),
        fit_pts=fit_pts,
        ends=ends,
        key_data=np.asarray(jax.random.key_data(root_key)),
        seed_value=int(seed) if isinstance(seed, (int, np.integer)) else None,
    )


def group_key(prep: _Prepared) -> tuple:
    """Curves with equal keys run in one compiled program (the shape bucket)."""
    return prep.space, prep.groups, len(prep.data)


def _run_group(preps, opts: _Options, **kwargs) -> list[FitResult]:
    """Run curves of one shape bucket as one program call and wait for the results."""
    return _collect(_launch(preps, opts, **kwargs))


def _swarm_costs(pairs, groups, closed: bool, columns: int) -> np.ndarray:
    """Each swarm's fitness work per point, in search samples: a spline's samples, plus
    ``5 + spans (k + 3) columns / 5`` for its span selects and Newton steps (``spans``: its
    group's, ``columns``: D, + 1 if rational); a polygon's 1.25 a segment (its search is
    its distance, :func:`~swarmcurves_jax.fitness.polyline_distances`).  Fitted to the
    CPU time of W1's groups: a sample 3.4 us a swarm and iteration, the rest
    20 samples' worth for the quadratics (8 spans), 22 for the cubics (7), a polygon 11.5
    for 9 segments.  ``benchmarks/bench_w1.py`` times the split it gives."""
    cost = np.zeros(len(pairs))
    for k, i, j, samples in groups:
        spans = max(n if closed else n - k for _, n in pairs[i:j])
        cost[i:j] = 1.25 * samples if k == 1 else samples + 5 + spans * (k + 3) * columns / 5
    return cost


def _split_swarms(groups, parts: int, cost: np.ndarray) -> list[np.ndarray]:
    """The swarms of a call dealt into at most ``parts`` sets of similar ``cost`` (per
    swarm, :func:`_swarm_costs`), each set in call order.  Each set compiles a program
    with its own degree groups, so whole groups are dealt first (the costliest to the
    least loaded set); then single swarms move from the most to the least loaded set
    while that set stays below the other: freely into a group it already has, and to
    start a new group there only 5 % below.
    """
    count = min(parts, groups[-1][2])
    sets, load = [[] for _ in range(count)], np.zeros(count)
    group = np.zeros(groups[-1][2], int)
    for g, (_, i, j, _) in enumerate(groups):
        group[i:j] = g
    for k, i, j, _ in sorted(groups, key=lambda g: (-cost[g[1]] * (g[2] - g[1]), g[1])):
        d = int(np.argmin(load))
        sets[d] += range(i, j)
        load[d] += cost[i:j].sum()
    while True:
        top, low = int(np.argmax(load)), int(np.argmin(load))
        best = None
        for i in sorted(sets[top], key=lambda i: (-cost[i], i)):
            known = group[i] in group[sets[low]]
            if load[low] + cost[i] < load[top] * (1.0 if known else 0.95):
                best = i
                break
        if best is None:
            return [np.array(sorted(x)) for x in sets if x]
        sets[top].remove(best)
        sets[low].append(best)
        load[top] -= cost[best]
        load[low] += cost[best]


def _part_groups(groups, chosen: np.ndarray):
    """:func:`_degree_groups` of the swarms ``chosen``, each group keeping the whole
    call's search samples (so a swarm's result does not depend on the split), and per
    group its index in ``groups`` and the positions of its chosen swarms there."""
    out, within = [], []
    for g, (k, i, j, samples) in enumerate(groups):
        mine = np.flatnonzero((chosen >= i) & (chosen < j))
        if len(mine):
            out.append((k, int(mine[0]), int(mine[-1]) + 1, samples))
            within.append((g, chosen[mine] - i))
    return tuple(out), within


class _Launched(NamedTuple):
    """A program call in flight: its device arrays and what the host needs to finish it."""

    preps: list
    opts: _Options
    place: Placement
    state: pso.PSOState
    refined: tuple | None
    history: list
    stop_reason: str
    stopped: np.ndarray
    done: int
    start: float
    timings: dict


def _launch(
    preps,
    opts: _Options,
    *,
    callback=None,
    bar=None,
    catch_interrupt=False,
    place=Placement(),
    size=None,
    start=None,
    sync=True,
    split=None,
) -> _Launched:
    """Launch curves of one shape bucket (equal :func:`group_key`) as one program call.

    Every array gets a leading curve axis.  The batch is padded with copies of its first
    curve (their results dropped) to ``size`` curves (default: a multiple of the devices,
    ``place.multiple``), so equal calls reuse one compiled program.
    ``callback(iteration, best (curves, solutions))`` runs after every chunk.  With
    ``sync`` the swarm is waited for before the refinement, to time each; without, both are
    queued and this returns at once (unless ``tol`` needs the swarm's progress).
    ``split``: CPU devices (:func:`~swarmcurves_jax.devices.cpu_devices`) to deal the
    swarms over (without a mesh), one program each, run at once from threads, whose chunks
    this thread reports in order; the refinement is one program, and every result equals
    the unsplit call's.
    """
    start = time.perf_counter() if start is None else start
    first = preps[0]
    space, pairs, groups = first.space, first.pairs, first.groups
    num = len(preps)
    size = num + (-num % place.multiple) if size is None else size
    padded = preps + [first] * (size - num)
    dtype, iterations, tol = opts.dtype, opts.iterations, opts.tol
    _check_memory(  # a device holds `place.batch` curves' temporaries at a time
        min(place.batch, size) * place.multiple * len(pairs),
        opts.particles,
        space.size,
        len(first.data),
        max(g[3] for g in groups),
        space.dim,
        jnp.dtype(dtype).itemsize,
    )
    stack = lambda field: np.stack([getattr(p, field) for p in padded])  # noqa: E731
    keys, pair_ids = stack("key_data"), np.array(pairs, np.int32)
    # The initial draws compile and run in a thread while the host sets up and the swarm
    # programs trace (XLA compiles outside Python's lock).
    pool = ThreadPoolExecutor(1)
    draws = pool.submit(
        lambda: jax.device_get(
            _initial_draws(
                keys, pair_ids, num_particles=opts.particles, size=space.size, dtype=dtype
            )
        )
    )
    pool.shutdown(wait=False)
    built = {}  # the padding repeats the first curve: build its seeds once
    for p in padded:
        if id(p) not in built:
            built[id(p)] = (
                _boxes(pairs, space, opts.weight_bounds, p.ends, dtype),
                _seeds(pairs, space, p.fit_pts, p.closed, p.ends, dtype),
            )
    boxes = pso.Box(*(np.stack(parts) for parts in zip(*(built[id(p)][0] for p in padded))))
    seeds = np.stack([built[id(p)][1] for p in padded])
    state = _empty_state(len(padded), len(pairs), opts.particles, space.size, dtype)
    data, mask = stack("data"), stack("mask")
    bases = tuple(
        stack_bases(pairs[i:j], space.closed, samples, space.n_pad, dtype)
        for _, i, j, samples in groups
    )
    refine_bases = None  # only for a refinement (W1's 21 swarms: 9 ms)
    if opts.method is not None:
        per_span = REFINE_SAMPLES_PER_SPAN
        refine_bases = tuple(
            stack_bases(
                pairs[i:j],
                space.closed,
                max(samples, default_num_samples(pairs[i:j], space.closed, per_span)),
                space.n_pad,
                dtype,
            )
            for _, i, j, samples in groups
        )
    params = pso.PSOParams(*(np.asarray(p, dtype) for p in opts.params))
    tol_arr = np.asarray(-1.0 if tol is None else tol, dtype)
    max_steps = np.asarray(iterations, np.int32)
    steps = min(opts.chunk_size, iterations)
    seeded = opts.init == "lsq"
    stop_reason = "iterations"
    setup = time.perf_counter() - start  # the host's seeds, boxes and bases

    def report(at, best):
        if bar is not None:
            bar.update(min(at, iterations) - bar.n)
            bar.set_postfix_str(_best_per_degree(pairs, best.min(axis=0)))
        if callback is not None:
            callback(min(at, iterations), best[:num])

    watch = callback is not None or bar is not None

    # A split's parts trace their programs one at a time: tracing is Python, so two threads
    # tracing at once share one core and both start compiling late, while a part that has
    # traced compiles (outside Python's lock) as the next one traces.
    tracing = threading.Lock()

    def swarm(run, drawn, state, boxes, seeds, pair_ids, bases, groups, place, report, stop):
        """The swarm loop of these swarms on ``place``, until done or ``stop`` is set.  It
        keeps in ``run`` the state, the per-chunk histories, the iterations done and, per
        curve, the iteration after which it reached tol (-1: not yet): a Ctrl-C leaves the
        last whole chunk's there, and its placed inputs for the refinement.
        ``drawn()``: these swarms' :func:`_initial_draws`, waited for only after the trace.
        ``report(iteration, best)`` follows the chunks."""
        reuse = opts.search_every > 1
        feet = np.zeros((*seeds.shape[:2], opts.particles, data.shape[1]), dtype) if reuse else ()
        state, feet, boxes, seeds, dev_data, dev_mask = place.curves(
            (state, feet, boxes, seeds, data, mask)
        )
        # Zeros in the draws' place (shape, type, device) trace the program as they would.
        dev_draws = place.curves(
            (
                np.zeros((*seeds.shape[:2], keys.shape[1]), np.uint32),
                np.zeros((*seeds.shape[:2], opts.particles, space.size), dtype),
            )
        )
        shared = place.shared((pair_ids, params, bases, tol_arr, max_steps))
        run.update(state=state, history=[], done=0, stopped=np.full(num, -1))
        run["inputs"] = boxes, seeds, dev_data, dev_mask
        # Without tol, progress reports read the previous chunk's result after the next
        # chunk is queued, so the device never waits for the host.
        pending = None
        static = dict(
            space=space,
            num_steps=steps,
            seeded=seeded,
            groups=groups,
            search_every=opts.search_every,
            mesh=place.mesh,
            batch=place.batch,
        )
        while run["done"] < iterations and not (stop.is_set() and run["history"]):
            inputs = (state, feet, np.int32(run["done"]), boxes, seeds, dev_data, dev_mask, shared)
            if not run["history"]:
                with tracing:  # the first call's trace and lowering, cached for it
                    _swarm_program.trace(*dev_draws, *inputs, **static).lower()
                dev_draws = place.curves(drawn())
            state, feet, info = _swarm_program(*dev_draws, *inputs, **static)
            run["state"] = state
            run["history"].append(info.best_fitness)
            run["done"] += steps
            if tol is not None:
                best = np.asarray(place.get(state.best_fitness))
                if watch:
                    report(run["done"], best)
                reached = np.all(best[:num] <= tol, axis=1)
                run["stopped"] = np.where(
                    reached & (run["stopped"] < 0), run["done"], run["stopped"]
                )
                if np.all(reached):
                    break
            elif watch:
                if pending is not None:
                    report(pending[0], np.asarray(place.get(pending[1])))
                pending = (run["done"], state.best_fitness)
        if pending is not None:
            report(pending[0], np.asarray(place.get(pending[1])))

    parts = []
    if split and place.mesh is None:
        cost = _swarm_costs(pairs, groups, space.closed, space.dim + space.rational)
        parts = _split_swarms(groups, len(split), cost)
    order = np.argsort(np.concatenate(parts)) if parts else None
    events, stop = queue.Queue(), threading.Event()

    def part(i):
        """:func:`swarm` of the swarms ``parts[i]`` on ``split[i]``, back on the host; its
        reports go to ``events``, for the calling thread to merge."""
        chosen = parts[i]
        own, taken = _part_groups(groups, chosen)
        pick = lambda tree: jax.tree_util.tree_map(lambda a: a[:, chosen], tree)  # noqa: E731
        own_bases = tuple(jax.tree_util.tree_map(lambda a, w=w: a[w], bases[g]) for g, w in taken)
        run = {}
        try:
            swarm(
                run,
                lambda: pick(draws.result()),
                pick(state),
                pick(boxes),
                seeds[:, chosen],
                pair_ids[chosen],
                own_bases,
                own,
                Placement(device=split[i]),
                lambda at, best: events.put((i, at, best)),
                stop,
            )
        finally:
            events.put((i, None, None))  # this part is done (or failed)
        run["state"] = jax.tree_util.tree_map(np.asarray, run["state"])
        run["history"] = np.concatenate([np.asarray(h) for h in run["history"]], axis=2)
        return run

    def merged(*a):
        """The parts' arrays (curve, swarm, ...) as one, in call order."""
        return np.concatenate(a, axis=1)[:, order]

    def relay():
        """Report the parts' chunks in order, each once every part has reached it (a part
        that stopped at tol stays at its last, frozen best), until every part is done."""
        seen, last, finished, shown = [{} for _ in parts], [None] * len(parts), set(), 0
        while len(finished) < len(parts):
            i, at, best = events.get()
            if at is None:
                finished.add(i)
            else:
                seen[i][at], last[i] = best, best
            while any(shown + steps in x for x in seen) and all(
                shown + steps in seen[j] or (j in finished and last[j] is not None)
                for j in range(len(parts))
            ):
                shown += steps
                report(shown, merged(*(x.pop(shown, last[j]) for j, x in enumerate(seen))))

    run = {"state": state, "history": [], "done": 0, "stopped": np.full(num, -1)}
    try:
        if len(parts) > 1:
            interrupted = False
            with ThreadPoolExecutor(len(parts)) as pool:
                futures = [pool.submit(part, i) for i in range(len(parts))]
                try:
                    relay()
                except KeyboardInterrupt:  # the parts stop after their current chunk
                    stop.set()
                    interrupted = True
                ran = [f.result() for f in futures]
            done = max(r["done"] for r in ran)
            # A part that reached tol sooner stopped sooner; the unsplit loop would have
            # gone on recording its swarms' (frozen) best until the last part stopped.
            pad = lambda h: np.pad(h, ((0, 0), (0, 0), (0, done - h.shape[2])), mode="edge")  # noqa: E731
            stopped = np.stack([r["stopped"] for r in ran])
            run = {
                "state": place.curves(jax.tree_util.tree_map(merged, *(r["state"] for r in ran))),
                "history": [merged(*(pad(r["history"]) for r in ran))],
                "done": done,
                "stopped": np.where(np.all(stopped >= 0, axis=0), stopped.max(axis=0), -1),
            }
            if interrupted:
                raise KeyboardInterrupt
        else:
            swarm(
                run, draws.result, state, boxes, seeds, pair_ids, bases, groups, place, report, stop
            )
        if tol is not None and np.all(run["stopped"] >= 0):
            stop_reason = "tol"
    except KeyboardInterrupt:
        if not catch_interrupt:
            raise
        stop_reason = "interrupted"
    if not run["history"]:
        raise KeyboardInterrupt
    state, history, done, stopped = run["state"], run["history"], run["done"], run["stopped"]
    timings = {"setup": setup}
    if sync:
        place.get(state.best_fitness)
        timings["swarm"] = time.perf_counter() - start
    refined = None
    if opts.method is not None and stop_reason != "interrupted":
        # The lone loop's placed inputs; a split's were on the parts' devices.
        boxes, seeds, data, mask = run.get("inputs") or place.curves((boxes, seeds, data, mask))
        refined = _refine_program(
            state,
            boxes,
            seeds,
            data,
            mask,
            place.shared((pair_ids, refine_bases)),
            space=space,
            method=opts.method,
            seeded=seeded,
            groups=groups,
            mesh=place.mesh,
            batch=place.batch,
        )
    return _Launched(
        preps, opts, place, state, refined, history, stop_reason, stopped, done, start, timings
    )


def _collect(run: _Launched) -> list[FitResult]:
    """Wait for a launched call and build its results on the host (true projections)."""
    preps, opts, place, state = run.preps, run.opts, run.place, run.state
    first = preps[0]
    space, pairs = first.space, first.pairs
    iterations, stopped, done = opts.iterations, run.stopped, run.done
    swarm = place.get((state.best_position, state.best_fitness, state.step))
    refined = None if run.refined is None else place.get(run.refined)
    timings = dict(run.timings)
    if "swarm" in timings:
        if refined is not None:
            timings["refine"] = time.perf_counter() - run.start - timings["swarm"]
    else:
        timings["call"] = time.perf_counter() - run.start  # swarm and refine, queued
    history = np.concatenate(place.get(run.history), axis=2)
    results = []
    for b, prep in enumerate(preps):
        candidates = [[(swarm[0][b, i], float(swarm[1][b, i]), False)] for i in range(len(pairs))]
        if refined is not None:
            for i, options in enumerate(candidates):
                if refined[1][b, i] < options[0][1]:
                    options.append((refined[0][b, i], float(refined[1][b, i]), True))
        solutions = _host_map(
            lambda i, b=b, prep=prep: _make_curve(
                *pairs[i],
                candidates[i],
                int(swarm[2][b, i]),
                space,
                prep.closed,
                prep.norm_pts,
                prep.center,
                prep.scale,
                prep.seed_value,
            ),
            range(len(pairs)),
        )
        # What the curve would have reported alone: a lone fit stops after the chunk in
        # which it reaches tol.
        reason = run.stop_reason
        if stopped[b] >= 0 and reason != "interrupted":
            reason = "tol"
        ran = min(stopped[b] if stopped[b] >= 0 else done, iterations)
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


def _degree_groups(pairs, closed, num_samples=None) -> tuple[tuple[int, int, int, int], ...]:
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


def _refine_method(refine) -> str | None:
    if refine is True:
        return "lm"
    if refine is False or refine is None:
        return None
    if isinstance(refine, str) and refine in local.METHODS:
        return refine
    raise ValueError(f"refine must be True, False, 'lm' or 'lbfgs', got {refine!r}")


def _canonical_order(points: np.ndarray) -> np.ndarray:
    """``points`` or ``points[::-1]``, whichever is lexicographically first.

    The swarm sees the same array for an input and its reverse, so both give the same
    curves (then oriented like each input): reversing the input never changes the fit.
    """
    fwd, rev = points.ravel(), points[::-1].ravel()
    differ = np.flatnonzero(fwd != rev)
    return points if len(differ) == 0 or fwd[differ[0]] < rev[differ[0]] else points[::-1]


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


def _available_memory() -> int | None:
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _check_memory(num_swarms, num_particles, size, num_points, num_samples, dim, itemsize):
    """Refuse up front, with the estimate, a run whose device arrays cannot fit in memory."""
    per_particle = (
        num_points * (4 * dim + 9)  # Newton temporaries and the carried search result
        + num_samples * (4 * dim + 4)  # curve samples and derivatives
        + 7 * size  # position, velocity, pbest, random draws, restart candidates, initial draws
    )
    need = 2 * num_swarms * num_particles * per_particle * itemsize  # x2: XLA temporaries
    free = _available_memory()
    if free is not None and need > 0.8 * free:
        raise ValueError(
            f"fit would need about {need / 2**30:.1f} GiB of memory for {num_swarms} swarms x "
            f"{num_particles} particles x {num_points} points, but {free / 2**30:.1f} GiB are "
            "free; lower particles, the number of (degree, cps) pairs, or max_fitness_points"
        )


def _progress_bar(iterations, pairs):
    from tqdm.auto import tqdm

    return tqdm(total=iterations, desc=f"{len(pairs)} swarms", unit="it", leave=False)


def _best_per_degree(pairs, best) -> str:
    out = {}
    for (k, _), f in zip(pairs, best):
        out[k] = min(out.get(k, np.inf), float(f))
    return " ".join(f"d{k}={v:.2e}" for k, v in out.items())


def _knots(q, k, n, space) -> np.ndarray:
    """The knot vector of a position: fixed uniform, or from its knot logits (float64)."""
    if not space.num_knots:
        return make_knots(n, k, space.closed)
    spans = n if space.closed else n - k
    logits = space.knot_logits(q)[: space.n_pad if space.closed else space.n_pad - k]
    t = knots_from_widths(span_widths(logits, spans), spans, k, space.closed)
    return t[: spans + 2 * k + 1]


def _make_curve(k, n, candidates, steps, space, closed, norm_pts, center, scale, seed):
    """Host side: un-pad, measure by true projection both ways, map back to the caller's
    frame.

    ``candidates``: ``(position, fitness, refined)`` of the swarm's best and, if its
    fitness is lower, the refined one; the lower two-sided ``mean_deviation`` wins (the
    fitness is an estimate, and the one-sided error cannot see a polish that lowers it by
    sending a stretch of curve away from the data).
    """
    measured = []
    for q, fitness, refined in candidates:
        q = np.asarray(q, dtype=np.float64)
        t = _knots(q, k, n, space)
        ctrl, log_w = space.split(q)
        ctrl = ctrl[:n]
        weights = np.ones(n) if log_w is None else np.exp(log_w[:n] - log_w[:n].max())
        dist, foot = project_points(norm_pts, ctrl, weights, t, k, closed)
        dev = deviations(norm_pts, ctrl, weights, t, k, closed, dist)
        measured.append((dev, ctrl, weights, t, dist, foot, fitness, refined))
    dev, ctrl, weights, t, dist, foot, fitness, refined = min(
        measured, key=lambda m: math.inf if math.isnan(m[0].mean_deviation) else m[0].mean_deviation
    )
    if _runs_backwards(foot, closed):  # same geometry, traversed like the input
        ctrl, weights, t = _reversed(ctrl, weights, t, k, closed, bool(space.num_knots))
    diag = float(np.linalg.norm(np.ptp(norm_pts, axis=0)))
    error = float(np.mean(dist))
    pct = lambda x: 100.0 * x / diag if diag > 0 else (0.0 if x == 0 else math.inf)  # noqa: E731
    return Curve(
        degree=k,
        control_points=center + scale * ctrl,
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
            "fitness": fitness,
            "refined": refined,
            "seed": seed,
            "max_excursion": dev.max_excursion,
            "rms_excursion": dev.rms_excursion,
        },
    )


#: fit's keyword names, for the "did you mean" of an unknown one.
_FIT_ARGS = tuple(p for p in inspect.signature(fit).parameters if p != "unknown")
