"""Particle swarm optimisation as pure functions over a state pytree (the paper's update).

One swarm minimises ``fitness_fn(positions) -> (P,)`` over flat positions of shape
``(P, dim)``.  Everything here is traceable: ``run`` is a ``lax.scan`` over ``step``, and a
caller vmaps it over independent swarms.  Each step evaluates the particles, updates the
personal (``pbest``) and global (``gbest``) bests, then moves them with the paper's update

    v <- inertia * v + cognitive * r_l * (pbest - q) + social * r_g * (gbest - q)
    q <- q + v

with ``r_l, r_g ~ U[0, 1]`` per coordinate and step, ``|v| <= v_max`` per coordinate, and
positions kept inside ``[lower, upper]``.  NaN or inf fitness counts as ``+inf``.

A converged swarm only polishes its basin, so after ``patience`` steps without a 0.1 %
improvement of the run's best the swarm restarts from fresh uniform positions (a new,
independent run); ``best_*`` keeps the best ever found, which is what a caller reports.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "PSOParams",
    "PSOState",
    "PSOInfo",
    "Box",
    "default_params",
    "init",
    "init_from_uniforms",
    "step",
    "step_draws",
    "run",
    "run_swarms",
    "update",
    "uniforms",
]

FitnessFn = Callable[[jax.Array], jax.Array]
_NO_LIMIT = 2**31 - 1  # max_steps default: int32 max


class PSOParams(NamedTuple):
    """Traced swarm coefficients (change them without recompiling).

    ``inertia`` is the paper's psi, ``cognitive`` phi_l, ``social`` phi_g; ``v_max`` clamps
    every velocity coordinate; ``patience`` is the number of steps without improvement
    after which the swarm restarts (``inf``: never).
    """

    inertia: jax.Array | float
    cognitive: jax.Array | float
    social: jax.Array | float
    v_max: jax.Array | float
    patience: jax.Array | float = float("inf")


def default_params() -> PSOParams:
    """Defaults chosen by measurement (``benchmarks/tune_pso.py``; docs/accuracy.md)."""
    return PSOParams(inertia=0.7298, cognitive=1.49618, social=1.49618, v_max=0.1, patience=100.0)


class Box(NamedTuple):
    """Per-coordinate search box of one swarm, shape (dim,) each.

    ``init_lower/init_upper`` bound the uniform initial positions, ``lower/upper`` every
    later position; ``mask`` is 1 for live coordinates and 0 for padding, which never moves.
    """

    init_lower: jax.Array
    init_upper: jax.Array
    lower: jax.Array
    upper: jax.Array
    mask: jax.Array


class PSOState(NamedTuple):
    position: jax.Array  # (P, dim)
    velocity: jax.Array  # (P, dim)
    pbest_position: jax.Array  # (P, dim)
    pbest_fitness: jax.Array  # (P,)
    gbest_position: jax.Array  # (dim,) best of the current run (drives the update)
    gbest_fitness: jax.Array  # ()
    best_position: jax.Array  # (dim,) best ever, across restarts (the result)
    best_fitness: jax.Array  # ()
    stall: jax.Array  # () int32: steps since the run's best last improved by 0.1 %
    step: jax.Array  # () int32: evaluations done


class PSOInfo(NamedTuple):
    """Per-step diagnostics (kept out of the carried state)."""

    best_fitness: jax.Array  # () best ever after this step
    mean_fitness: jax.Array  # () mean finite fitness of the evaluated particles
    restarted: jax.Array  # () bool: the swarm restarted after this step


def init(
    key: jax.Array, box: Box, num_particles: int, seed_position: jax.Array | None = None
) -> PSOState:
    """Uniform positions in the initial box, zero velocity, nothing evaluated yet.

    ``seed_position`` (dim,), if given, replaces particle 0 (e.g. a least-squares guess).
    """
    u = jax.random.uniform(key, (num_particles, box.mask.shape[0]), dtype=box.lower.dtype)
    return init_from_uniforms(u, box, seed_position)


def init_from_uniforms(u: jax.Array, box: Box, seed_position: jax.Array | None = None) -> PSOState:
    """:func:`init` from its U[0, 1) draws ``u`` (P, dim), made elsewhere: ``fit`` draws
    them on the host (:mod:`swarmcurves_jax.draws`), since threefry compiled into each
    swarm program cost it about 1 s of compilation (measured on XLA:CPU)."""
    pos = _scale_to_init_box(u, box)
    num_particles = u.shape[0]
    if seed_position is not None:
        pos = pos.at[0].set(jnp.clip(seed_position, box.lower, box.upper) * box.mask)
    inf = jnp.full((num_particles,), jnp.inf, dtype=pos.dtype)
    zero = jnp.zeros((), jnp.int32)
    return PSOState(pos, jnp.zeros_like(pos), pos, inf, pos[0], inf[0], pos[0], inf[0], zero, zero)


def _scale_to_init_box(u: jax.Array, box: Box) -> jax.Array:
    """Map U[0, 1] draws (P, dim) into the initial box; padding stays at 0."""
    span = (box.init_upper - box.init_lower)[None, :]
    return (box.init_lower[None, :] + u * span) * box.mask[None, :]


def _mix(x: jax.Array) -> jax.Array:
    """MurmurHash3's 32-bit finaliser: a bijection of uint32 with full avalanche."""
    x = (x ^ (x >> 16)) * jnp.uint32(0x85EBCA6B)
    x = (x ^ (x >> 13)) * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def uniforms(key: jax.Array, counter: jax.Array, shape: tuple[int, ...], dtype) -> jax.Array:
    """U[0, 1) draws of ``shape``, a pure function of ``(key, counter)``.

    Counter-based like ``jax.random``'s threefry, but with a two-round integer hash
    (element ``i`` of draw ``counter``: ``_mix(_mix(i ^ a) ^ b)``, 24 bits, where
    ``a, b`` hash the key's words with the counter): on XLA:CPU ``jax.random.uniform``
    costs about 7 ns a number, which was 90 % of the swarm's own work on W1 (measured),
    where this fuses into the update for well under 1 ns.  Quality is checked in
    ``tests/test_pso.py`` (uniformity, independence of draws and counters).
    """
    words = jax.random.key_data(key).reshape(-1).astype(jnp.uint32)
    a = _mix(words[0] ^ _mix(jnp.asarray(counter, jnp.uint32) + jnp.uint32(0x9E3779B9)))
    for w in words[1:]:
        a = _mix(a ^ w)
    b = _mix(a ^ jnp.uint32(0x6A09E667))
    i = jax.lax.iota(jnp.uint32, math.prod(shape)).reshape(shape)
    return (_mix(_mix(i ^ a) ^ b) >> 8).astype(dtype) * (1.0 / (1 << 24))


def step(
    key: jax.Array,
    state: PSOState,
    params: PSOParams,
    box: Box,
    fitness_fn: FitnessFn,
    tol: jax.Array | float,
    max_steps: jax.Array | int,
) -> tuple[PSOState, PSOInfo]:
    """One evaluate-update-move step: :func:`update` with ``fitness_fn(state.position)``."""
    return update(key, state, params, box, fitness_fn(state.position), tol, max_steps)


def update(
    key: jax.Array,
    state: PSOState,
    params: PSOParams,
    box: Box,
    fit: jax.Array,
    tol: jax.Array | float,
    max_steps: jax.Array | int,
    draws: jax.Array | None = None,
) -> tuple[PSOState, PSOInfo]:
    """The step after evaluating: ``fit`` (P,) is the fitness of ``state.position``.

    A swarm whose best fitness is already ``<= tol``, or which has done ``max_steps``
    evaluations, is left unchanged (frozen), so a swarm's result never depends on how long
    the other swarms of the same program run.  ``draws``: this step's ``(r_l, r_g)``,
    :func:`step_draws` of ``(key, state)``, if already made (:func:`run_swarms`).
    """
    fit = jnp.where(jnp.isfinite(fit), fit, jnp.inf)
    better = fit < state.pbest_fitness
    pbest_pos = jnp.where(better[:, None], state.position, state.pbest_position)
    pbest_fit = jnp.where(better, fit, state.pbest_fitness)
    i = jnp.argmin(pbest_fit)
    gbest_pos, gbest_fit = pbest_pos[i], pbest_fit[i]
    improved = gbest_fit < state.best_fitness
    best_pos = jnp.where(improved, gbest_pos, state.best_position)
    best_fit = jnp.where(improved, gbest_fit, state.best_fitness)
    progress = gbest_fit < state.gbest_fitness * (1.0 - 1e-3)
    stall = jnp.where(progress, 0, state.stall + 1)

    r_l, r_g = step_draws(key, state) if draws is None else draws
    q = state.position
    v = (
        params.inertia * state.velocity
        + params.cognitive * r_l * (pbest_pos - q)
        + params.social * r_g * (gbest_pos[None, :] - q)
    )
    v = jnp.clip(v, -params.v_max, params.v_max) * box.mask[None, :]
    q = jnp.clip(q + v, box.lower[None, :], box.upper[None, :])
    moved = PSOState(
        q, v, pbest_pos, pbest_fit, gbest_pos, gbest_fit, best_pos, best_fit, stall, state.step + 1
    )

    restart = stall >= params.patience
    # A restart discards this step's move, so its r_l draw is free to place the new swarm.
    fresh = _scale_to_init_box(r_l, box)
    inf = jnp.full_like(pbest_fit, jnp.inf)
    restarted = moved._replace(
        position=fresh,
        velocity=jnp.zeros_like(v),
        pbest_position=fresh,
        pbest_fitness=inf,
        gbest_fitness=inf[0],
        stall=jnp.zeros_like(stall),
    )
    new = jax.tree_util.tree_map(lambda a, b: jnp.where(restart, a, b), restarted, moved)
    active = (state.best_fitness > tol) & (state.step < max_steps)
    state = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new, state)
    finite = jnp.isfinite(fit)
    mean_fit = jnp.sum(jnp.where(finite, fit, 0.0)) / jnp.maximum(jnp.sum(finite), 1)
    return state, PSOInfo(state.best_fitness, mean_fit, restart & active)


def step_draws(key: jax.Array, state: PSOState) -> jax.Array:
    """The step's ``(r_l, r_g)`` draws (2, P, dim): :func:`uniforms` of the swarm's key and
    its ``state.step``."""
    return uniforms(key, state.step, (2, *state.position.shape), state.position.dtype)


def run(
    key: jax.Array,
    state: PSOState,
    params: PSOParams,
    box: Box,
    fitness_fn: FitnessFn,
    num_steps: int,
    tol: jax.Array | float = -1.0,
    max_steps: jax.Array | int = _NO_LIMIT,
) -> tuple[PSOState, PSOInfo]:
    """``num_steps`` steps in one ``lax.scan``; info is stacked along the first axis.

    A step's random draws are :func:`uniforms` of ``(key, state.step)``, so splitting a
    run into chunks gives exactly the same swarm as one long run.
    """

    def body(s, _):
        return step(key, s, params, box, fitness_fn, tol, max_steps)

    return jax.lax.scan(body, state, None, length=num_steps)


def run_swarms(
    keys: jax.Array,
    states: PSOState,
    params: PSOParams,
    boxes: Box,
    fitness_fn: Callable[[jax.Array], jax.Array],
    num_steps: int,
    tol: jax.Array | float = -1.0,
    max_steps: jax.Array | int = _NO_LIMIT,
    memory=None,
    first: jax.Array | int = 0,
):
    """:func:`run` of independent swarms (a leading swarm axis on ``keys``, ``states`` and
    ``boxes``) in one ``lax.scan``, with one ``fitness_fn`` of all their positions
    (S, P, dim) -> (S, P): the caller may evaluate groups of swarms differently, and each
    step is one trip of one loop, not one per group.  Each swarm's result equals its
    :func:`run`.  Info is (num_steps, S).

    With a ``memory`` (a pytree), the fitness carries it from step to step:
    ``fitness_fn(positions, memory, iteration) -> (fitness, memory)``, the iteration
    counted from ``first`` (so that a run split into chunks equals one long run); this
    returns ``(states, memory), info``.

    The next step's draws are made at the end of each step and carried in the loop, the
    same numbers :func:`update` would make: made inside it, XLA:CPU recomputed the hash
    in each fusion that reads them (position, velocity, restart), and W1 took 2-3 % longer
    (measured).

    Steps from iteration ``max_steps`` on (counted from ``first``) are skipped, not run
    frozen: one compiled chunk length serves every iteration count, and a last, partial
    chunk costs only the steps it runs.  A skipped step's info repeats the best fitness,
    with a NaN mean and no restart.
    """
    move = jax.vmap(update, in_axes=(0, 0, None, 0, 0, None, None, 0))
    draw = jax.vmap(step_draws)
    remembers = memory is not None
    fn = fitness_fn if remembers else lambda positions, mem, _: (fitness_fn(positions), mem)

    def body(i, carry):
        s, mem, draws, info = carry
        fit, mem = fn(s.position, mem, first + i)
        s, new = move(keys, s, params, boxes, fit, tol, max_steps, draws)
        info = jax.tree_util.tree_map(lambda a, b: a.at[i].set(b), info, new)
        return s, mem, draw(keys, s), info

    # Skipped steps' rows: the best fitness (filled in below), a NaN mean, no restart.
    best = states.best_fitness
    info = PSOInfo(
        jnp.zeros((num_steps, *best.shape), best.dtype),
        jnp.full((num_steps, *best.shape), jnp.nan, best.dtype),
        jnp.zeros((num_steps, *best.shape), bool),
    )
    # `first` and `max_steps` are shared by every swarm and curve: under the callers'
    # vmaps the trip count stays one number (a batched one would run every swarm to the
    # longest).
    count = jnp.clip(jnp.asarray(max_steps, jnp.int32) - first, 0, num_steps)
    carry = (states, memory, draw(keys, states), info)
    states, memory, _, info = jax.lax.fori_loop(0, count, body, carry)
    ran = jnp.arange(num_steps).reshape(-1, *([1] * best.ndim)) < count
    info = info._replace(best_fitness=jnp.where(ran, info.best_fitness, states.best_fitness))
    return ((states, memory) if remembers else states), info
