"""Launching a program call: the host's inputs, the swarm loop in chunks, then the polish.

One call fits the curves of one shape bucket.  The swarm program runs in chunks of
``chunk_size`` iterations (:func:`chunks`); between them the host reports progress and
checks ``tol`` (:func:`follow`).  The swarms run on one device, split over a mesh by curve
(:mod:`swarmcurves_jax.devices`), or dealt over several CPU devices by swarm
(:mod:`swarmcurves_jax.dealing`, :func:`run_dealt`).  Then the polish is queued.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Iterator, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import compile_cache, pso
from .dealing import part_groups, split_swarms, swarm_costs, widen
from .devices import Placement
from .draws import initial_draws
from .excursions import Polyline, data_polylines
from .layout import Layout, search_boxes
from .objective import stack_bases
from .options import FitOptions
from .polish import POLISH_COMPILER_OPTIONS, polish_bases, polish_program
from .prepare import pad_points, polish_length
from .pystack import in_one_chunk
from .search import SWARM_COMPILER_OPTIONS, swarm_program
from .seeds import seed_positions

__all__ = ["Batch", "Inputs", "Progress", "Launched", "launch", "chunks", "follow", "run_dealt"]


class Inputs(NamedTuple):
    """Per-curve inputs of the programs (leading axis: curves)."""

    boxes: pso.Box
    seeds: np.ndarray
    data: np.ndarray
    mask: np.ndarray
    polyline: Polyline  # through the data, as padded (excursions.data_segments)


class Batch(NamedTuple):
    """One program call's host arrays, every one with a leading curve axis, the batch
    padded with copies of its first curve; or a part of it (some of its swarms)."""

    num: int  # the real curves (the rest is padding)
    space: Layout
    pairs: list
    groups: tuple
    draws: tuple  # each swarm's run key data and initial draws (:mod:`~swarmcurves_jax.draws`)
    pair_ids: np.ndarray  # (swarms, 2): each swarm's (degree, count)
    state: pso.PSOState  # placeholder (step 0): the program initialises it
    inputs: Inputs
    polish_inputs: Inputs  # the inputs at the polish's padding (:func:`_polish_inputs`)
    bases: tuple  # the search's span bases, one per degree group
    seeds: np.ndarray  # (curves, swarms, 2, size): the seed and the classic fit, float64


class Progress(NamedTuple):
    """A swarm loop after a chunk: what the host needs to go on, stop, or collect."""

    state: pso.PSOState
    feet: object  # the last search's starts when ``search_every > 1``, else ()
    history: tuple  # each chunk's best fitness, (curves, swarms, steps)
    done: int  # iterations run
    stopped: np.ndarray  # per curve, the iteration after which it reached tol (-1: not yet)


class Launched(NamedTuple):
    """A program call in flight: its device arrays and what the host needs to finish it."""

    preps: list
    opts: FitOptions
    place: Placement
    progress: Progress
    polished: tuple | None  # the polish's results (polish.polish_program), device arrays
    seeds: np.ndarray  # (curves, swarms, 2, size): the seed and the classic fit, float64
    stop_reason: str
    start: float
    timings: dict


#: A dealt call's parts trace their programs one at a time: tracing is Python, so two
#: threads tracing at once share one core and both start compiling late, while a part
#: that has traced compiles (outside Python's lock) as the next one traces.
TRACING = threading.Lock()

#: A progress bar's label ends with this until its first iterations (or curves) are done:
#: a first call's wait is mostly compilation.
COMPILING = ": compiling"


@in_one_chunk
def launch(
    preps,
    opts: FitOptions,
    *,
    callback=None,
    bar=None,
    catch_interrupt=False,
    place=Placement(),
    size=None,
    start=None,
    split=None,
) -> Launched:
    """Launch curves of one shape bucket (equal :func:`~swarmcurves_jax.prepare.group_key`)
    as one program call.

    The batch is padded with copies of its first curve (their results dropped) to ``size``
    curves (default: a multiple of the devices, ``place.multiple``), so equal calls reuse
    one compiled program.  ``callback(iteration, best (curves, solutions))`` runs after
    every chunk.  ``split``: CPU devices (:func:`~swarmcurves_jax.devices.cpu_devices`) to
    deal the swarms over (without a mesh), one program each, run at once from threads; the
    polish is one program, and every result equals the undealt call's.  The polish is
    queued behind the swarm; its program is traced while the swarm's compiles and
    compiled while the swarm runs (:class:`_EarlyPolish`), unless ``opts.stage_timings``
    asks to time each.
    """
    start = time.perf_counter() if start is None else start
    compile_cache.ensure()
    num = len(preps)
    size = num + (-num % place.multiple) if size is None else size
    _check_memory(preps[0], opts, min(place.batch, size) * place.multiple)
    padded = preps + [preps[0]] * (size - num)  # the padding repeats the first curve
    keys = np.stack([p.key_data for p in padded])
    pair_ids = np.array(preps[0].pairs, np.int32)
    batch = _host_batch(padded, num, keys, pair_ids, opts)
    timings = {"setup": time.perf_counter() - start}  # the host's draws, seeds, boxes, bases
    report = _reporter(batch, opts, callback, bar)
    stop_reason, interrupted, early = "iterations", False, None
    try:
        parts = _deal(batch, split) if split and place.mesh is None else []
        early = _EarlyPolish(batch, opts, place)  # made while the swarm compiles
        if len(parts) > 1:
            progress, interrupted = run_dealt(batch, parts, split, opts, report, place, early.start)
        else:
            loop = chunks(batch, place, opts, threading.Event(), early.start)
            progress, interrupted = follow(loop, batch.num, opts, place, report)
    except KeyboardInterrupt:
        progress = None
    if interrupted or progress is None:
        if not catch_interrupt or progress is None:
            raise KeyboardInterrupt
        stop_reason = "interrupted"
    elif opts.tol is not None and np.all(progress.stopped >= 0):
        stop_reason = "tol"
    if opts.stage_timings:
        place.get(progress.state.best_fitness)
        timings["swarm"] = time.perf_counter() - start
    polished = None
    if opts.method is not None and stop_reason != "interrupted":
        polished = _polish(batch, progress, opts, place, early)
    return Launched(
        preps, opts, place, progress, polished, batch.seeds, stop_reason, start, timings
    )


def _in_thread(fn, *args, **kwargs) -> Future:
    """``fn(*args, **kwargs)`` started in a thread of its own; its result as a future."""
    pool = ThreadPoolExecutor(1)
    future = pool.submit(in_one_chunk(fn), *args, **kwargs)
    pool.shutdown(wait=False)
    return future


def _host_batch(padded, num: int, keys, pair_ids, opts: FitOptions) -> Batch:
    """The call's host arrays, ``padded`` with repeats of its first curve (their seeds built
    once) after the ``num`` real ones."""
    first = padded[0]
    space, pairs, groups = first.space, first.pairs, first.groups
    built = {}
    for p in padded:
        if id(p) not in built:
            built[id(p)] = (
                search_boxes(pairs, space, opts.weight_bounds, p.ends, opts.dtype),
                seed_positions(pairs, space, p.fit_pts, p.closed, p.ends, np.float64),
            )
    boxes = pso.Box(*(np.stack(parts) for parts in zip(*(built[id(p)][0] for p in padded))))
    stack = lambda field: np.stack([getattr(p, field) for p in padded])  # noqa: E731
    seeds = np.stack([built[id(p)][1] for p in padded])
    inputs = _inputs(boxes, seeds[:, :, 0].astype(opts.dtype), stack("data"), stack("mask"), space)
    return Batch(
        num=num,
        space=space,
        pairs=pairs,
        groups=groups,
        draws=initial_draws(
            keys, pair_ids, num_particles=opts.particles, size=space.size, dtype=opts.dtype
        ),
        pair_ids=pair_ids,
        state=empty_state(len(padded), len(pairs), opts.particles, space.size, opts.dtype),
        inputs=inputs,
        polish_inputs=_polish_inputs(inputs, space),
        bases=tuple(
            stack_bases(pairs[i:j], space.closed, samples, space.n_pad, opts.dtype)
            for _, i, j, samples in groups
        ),
        seeds=seeds,
    )


def empty_state(num_curves, num_swarms, num_particles, dim, dtype) -> pso.PSOState:
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


def chunks(
    batch: Batch, place: Placement, opts: FitOptions, stop, traced=None
) -> Iterator[Progress]:
    """The swarm loop of ``batch`` on ``place``: one :class:`Progress` per chunk, queued
    (not waited for), until the iterations are done or ``stop`` is set.  ``traced()``, if
    given, is called once the program has traced (before it compiles)."""
    dtype, lead = opts.dtype, batch.inputs.seeds.shape[:2]
    feet = ()  # the last search's starts, carried only when a search is reused
    if opts.search_every > 1:
        feet = np.zeros((*lead, opts.particles, batch.inputs.data.shape[1]), dtype)
    state, feet, draws, inputs = place.curves((batch.state, feet, batch.draws, batch.inputs))
    tol = np.asarray(-1.0 if opts.tol is None else opts.tol, dtype)
    params = pso.PSOParams(*(np.asarray(p, dtype) for p in opts.params))
    max_steps = np.asarray(opts.iterations, np.int32)
    shared = place.shared((batch.pair_ids, params, batch.bases, tol, max_steps))
    steps = opts.chunk_size  # the program skips steps past the iterations: one length
    static = dict(
        space=batch.space,
        num_steps=steps,
        seeded=opts.init == "lsq",
        groups=batch.groups,
        search_every=opts.search_every,
        mesh=place.mesh,
        batch=place.batch,
    )
    progress = Progress(state, feet, (), 0, np.full(batch.num, -1))
    run = None
    while progress.done < opts.iterations and not (stop.is_set() and progress.history):
        args = (*draws, progress.state, progress.feet, np.int32(progress.done), *inputs, shared)
        if run is None:
            with TRACING:  # the first call's trace and lowering, kept for it
                run = compile_cache.program(swarm_program, SWARM_COMPILER_OPTIONS, *args, **static)
            if traced is not None:
                traced()
        state, feet, info = run(*args)
        history = progress.history + (info.best_fitness,)
        progress = progress._replace(
            state=state, feet=feet, history=history, done=progress.done + steps
        )
        yield progress


def follow(loop: Iterator[Progress], num: int, opts: FitOptions, place, report):
    """Run a swarm loop's chunks, reporting each (``report`` None: quiet) and stopping once
    every real curve (the first ``num``) reached ``tol``.  Returns the last
    :class:`Progress` (None if no chunk ran), its ``stopped`` filled in, and whether
    Ctrl-C stopped the loop.

    Without ``tol`` a chunk is reported after the next one is queued, so the device never
    waits for the host."""
    last, pending, stopped = None, None, np.full(num, -1)
    best_of = lambda p: np.asarray(place.get(p.state.best_fitness))  # noqa: E731
    try:
        for progress in loop:
            if opts.tol is None:
                if report is not None and pending is not None:
                    report(pending.done, best_of(pending))
                last = pending = progress
                continue
            best = best_of(progress)
            if report is not None:
                report(progress.done, best)
            reached = np.all(best[:num] <= opts.tol, axis=1)
            stopped = np.where(reached & (stopped < 0), progress.done, stopped)
            last = progress._replace(stopped=stopped)
            if np.all(reached):
                break
    except KeyboardInterrupt:
        return last, True
    if report is not None and pending is not None:
        report(pending.done, best_of(pending))
    return last, False


def _deal(batch: Batch, devices) -> list[np.ndarray]:
    """The swarms of ``batch`` dealt into sets of similar cost, one per device."""
    space = batch.space
    cost = swarm_costs(batch.pairs, batch.groups, space.closed, space.dim + space.rational)
    return split_swarms(batch.groups, len(devices), cost)


def _part(batch: Batch, chosen: np.ndarray) -> Batch:
    """The swarms ``chosen`` of ``batch``, each degree group keeping its search samples."""
    groups, taken = part_groups(batch.groups, chosen)
    pick = lambda tree: jax.tree_util.tree_map(lambda a: a[:, chosen], tree)  # noqa: E731
    return batch._replace(
        pairs=[batch.pairs[i] for i in chosen],
        groups=groups,
        pair_ids=batch.pair_ids[chosen],
        draws=pick(batch.draws),
        state=pick(batch.state),
        inputs=batch.inputs._replace(
            boxes=pick(batch.inputs.boxes), seeds=batch.inputs.seeds[:, chosen]
        ),
        bases=tuple(jax.tree_util.tree_map(lambda a, w=w: a[w], batch.bases[g]) for g, w in taken),
        seeds=batch.seeds[:, chosen],
    )


def run_dealt(batch: Batch, parts, devices, opts: FitOptions, report, place, traced=None):
    """The swarm loop with the swarms ``parts[i]`` on ``devices[i]``, one thread each,
    their chunks reported in call order (each once every part has reached it); then the
    parts' states merged on the host in call order and placed on ``place``.  Returns the
    merged :class:`Progress` and whether Ctrl-C stopped it (the parts then stop after
    their current chunk).  ``traced()``, if given, is called as each part's program has
    traced (:func:`chunks`)."""
    events, stop = queue.Queue(), threading.Event()
    order = np.argsort(np.concatenate(parts))

    def run_part(i):
        chosen = widen(parts[i], batch.groups)  # sorted, a lone swarm's copy next to it
        kept = np.unique(chosen, return_index=True)[1]  # the copies' results are dropped
        keep = lambda tree: jax.tree_util.tree_map(lambda a: a[:, kept], tree)  # noqa: E731

        say = None if report is None else (lambda at, best: events.put((i, at, best[:, kept])))
        device = Placement(device=devices[i])
        try:
            progress, _ = follow(
                chunks(_part(batch, chosen), device, opts, stop, traced),
                batch.num,
                opts,
                device,
                say,
            )
        finally:
            events.put((i, None, None))  # this part is done (or failed)
        history = np.concatenate([np.asarray(h) for h in progress.history], axis=2)
        state = keep(jax.device_get(progress.state))
        return progress._replace(state=state, history=history[:, kept])

    merged = lambda *a: np.concatenate(a, axis=1)[:, order]  # noqa: E731
    interrupted = False
    with ThreadPoolExecutor(len(parts)) as pool:
        futures = [pool.submit(in_one_chunk(run_part), i) for i in range(len(parts))]
        try:
            _relay(events, len(parts), opts.chunk_size, report, merged)
        except KeyboardInterrupt:
            stop.set()
            interrupted = True
        ran = [f.result() for f in futures]
    done = max(r.done for r in ran)
    # A part that reached tol sooner stopped sooner; the undealt loop would have gone on
    # recording its swarms' (frozen) best until the last part stopped.
    pad = lambda h: np.pad(h, ((0, 0), (0, 0), (0, done - h.shape[2])), mode="edge")  # noqa: E731
    stopped = np.stack([r.stopped for r in ran])
    progress = Progress(
        state=place.curves(jax.tree_util.tree_map(merged, *(r.state for r in ran))),
        feet=(),
        history=(merged(*(pad(r.history) for r in ran)),),
        done=done,
        stopped=np.where(np.all(stopped >= 0, axis=0), stopped.max(axis=0), -1),
    )
    return progress, interrupted


def _relay(events: queue.Queue, count: int, steps: int, report, merged):
    """Report the parts' chunks in order, each once every part has reached it (a part
    that stopped at tol stays at its last, frozen best), until every part is done."""
    seen, last, finished, shown = [{} for _ in range(count)], [None] * count, set(), 0
    while len(finished) < count:
        i, at, best = events.get()
        if at is None:
            finished.add(i)
        else:
            seen[i][at], last[i] = best, best
        while any(shown + steps in x for x in seen) and all(
            shown + steps in seen[j] or (j in finished and last[j] is not None)
            for j in range(count)
        ):
            shown += steps
            report(shown, merged(*(x.pop(shown, last[j]) for j, x in enumerate(seen))))


def _polish(batch: Batch, progress: Progress, opts: FitOptions, place: Placement, early=None):
    """Queue the polish of every swarm's solution (:mod:`swarmcurves_jax.polish`), with
    the program ``early`` (an :class:`_EarlyPolish`) made if it was started."""
    inputs = place.curves(batch.polish_inputs)
    args = (progress.state, *inputs, place.shared(_polish_shared(batch, opts)))
    run = early.result() if early is not None else None
    if run is None:
        run = compile_cache.program(
            polish_program, POLISH_COMPILER_OPTIONS, *args, **_polish_static(batch, opts, place)
        )
    return run(*args)


def _polish_inputs(inputs: Inputs, space: Layout) -> Inputs:
    """The host's ``inputs`` as the polish takes them: the points padded further, to
    :func:`~swarmcurves_jax.prepare.polish_length`."""
    data, mask = pad_points(inputs.data, inputs.mask, polish_length(inputs.data.shape[1]))
    return _inputs(inputs.boxes, inputs.seeds, data, mask, space)


def _inputs(boxes, seeds, data, mask, space: Layout) -> Inputs:
    """The programs' per-curve inputs, with the polyline through each curve's ``data``."""
    return Inputs(boxes, seeds, data, mask, data_polylines(data, mask, space.closed))


def _polish_shared(batch: Batch, opts: FitOptions):
    """The polish's arguments every curve shares, on the host: the pairs and their span
    bases."""
    return batch.pair_ids, polish_bases(batch.pairs, batch.groups, batch.space, opts.dtype)


def _polish_static(batch: Batch, opts: FitOptions, place: Placement) -> dict:
    """The polish program's static arguments (what its trace depends on besides shapes)."""
    return dict(
        space=batch.space,
        method=opts.method,
        seeded=opts.init == "lsq",
        groups=batch.groups,
        mesh=place.mesh,
        batch=place.batch,
    )


class _EarlyPolish:
    """The polish program of a call, traced, lowered and compiled in a thread from the
    arguments' shapes once the swarm program has traced (a dealt call's first part's):
    its tracing then overlaps the swarm's compilation and its compilation the swarm's
    run, instead of both waiting for the swarm's last chunk to be queued.  Not started
    without a polish, for a mesh (``fit_many``'s calls already overlap one call's host
    work with another's device work: no gain measured, docs/performance.md), or when
    ``stage_timings`` times each stage."""

    def __init__(self, batch: Batch, opts: FitOptions, place: Placement):
        self.batch, self.opts, self.place = batch, opts, place
        self.future: Future | None = None
        self._once = threading.Lock()

    def start(self) -> None:
        """Start making the program; later calls (the other parts') do nothing."""
        opts, place = self.opts, self.place
        if opts.method is None or place.mesh is not None or opts.stage_timings:
            return
        with self._once:
            if self.future is None:
                self.future = _in_thread(self._make)

    def _make(self):
        batch, opts, place = self.batch, self.opts, self.place
        abstract = lambda a: place.abstract(np.shape(a), np.asarray(a).dtype)  # noqa: E731
        state, inputs, shared = jax.tree_util.tree_map(
            abstract, (batch.state, batch.polish_inputs, _polish_shared(batch, opts))
        )
        args, static = (state, *inputs, shared), _polish_static(batch, opts, place)
        with TRACING:  # traced and lowered under the lock; compiled (the kept lowering) outside
            compile_cache.program(polish_program, POLISH_COMPILER_OPTIONS, *args, **static)
        return compile_cache.program(
            polish_program, POLISH_COMPILER_OPTIONS, *args, compile_now=True, **static
        )

    def result(self):
        """The program, or None if it was not started."""
        return None if self.future is None else self.future.result()


def _reporter(batch: Batch, opts: FitOptions, callback, bar):
    """``report(iteration, best (curves, swarms))`` for the progress bar and the
    callback, or None when neither is given."""
    if callback is None and bar is None:
        return None

    def report(at, best):
        at = min(at, opts.iterations)
        if bar is not None:
            if bar.n == 0:  # compiled: the bar now counts iterations
                bar.set_description(bar.desc.removesuffix(COMPILING), refresh=False)
            bar.update(at - bar.n)
            bar.set_postfix_str(_best_per_degree(batch.pairs, best.min(axis=0)))
        if callback is not None:
            callback(at, best[: batch.num])

    return report


def _best_per_degree(pairs, best) -> str:
    out = {}
    for (k, _), f in zip(pairs, best):
        out[k] = min(out.get(k, np.inf), float(f))
    return " ".join(f"d{k}={v:.2e}" for k, v in out.items())


def _available_memory() -> int | None:
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _check_memory(prep, opts: FitOptions, curves: int):
    """Refuse up front, with the estimate, a run whose device arrays cannot fit in memory
    (a device holds ``curves`` curves' temporaries at a time)."""
    space, dim = prep.space, prep.space.dim
    num_swarms, num_points = curves * len(prep.pairs), len(prep.data)
    num_samples = max(g[3] for g in prep.groups)
    per_particle = (
        num_points * (4 * dim + 9)  # Newton temporaries and the carried search result
        + num_samples * (4 * dim + 4)  # curve samples and derivatives
        + 7 * space.size  # position, velocity, pbest, draws, restart candidates, initial draws
    )
    itemsize = jnp.dtype(opts.dtype).itemsize
    need = 2 * num_swarms * opts.particles * per_particle * itemsize  # x2: XLA temporaries
    free = _available_memory()
    if free is not None and need > 0.8 * free:
        raise ValueError(
            f"fit would need about {need / 2**30:.1f} GiB of memory for {num_swarms} swarms x "
            f"{opts.particles} particles x {num_points} points, but {free / 2**30:.1f} GiB are "
            "free; lower particles, the number of (degree, cps) pairs, or max_fitness_points"
        )
