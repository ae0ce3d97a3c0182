"""``fit_many``: many point sets, one compiled program per shape bucket, over every device.

Curves are grouped by what fixes a program's shapes: dimension, open or closed, and the
bucket length their points are padded to (:func:`swarmcurves_jax.prepare.bucket_length`,
less than 12.5 % padding; the padding is masked out, never resampled).  A group runs in
calls of equal size, so it compiles once; inside a call the curves are split over the
devices (:mod:`swarmcurves_jax.devices`) and each device loops over its share.  Every
curve runs the very program a lone :func:`swarmcurves_jax.fit` runs, with the same key,
so ``fit_many(sets, seed=s)[i]`` equals ``fit(sets[i], seed=s)`` exactly.
:func:`fit_stream` does the same for an iterable read as it goes (a corpus too large to
hold): it keeps at most one call's curves per bucket waiting, and yields each result as
its call finishes.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Callable, Iterable, Iterator, NamedTuple, Sequence

import jax
import numpy as np

from ._validation import check_bool, check_positive_int
from .assemble import collect
from .devices import Placement
from .launch import COMPILING, launch
from .options import FitOptions
from .prepare import Prepared, group_key, prepare
from .results import FitResult

__all__ = ["CURVES_PER_DEVICE", "call_size", "fit_many", "fit_stream", "padding_waste"]

#: Curves per program call and device when ``batch_size`` is not given.
CURVES_PER_DEVICE = 32


def fit_many(
    point_sets,
    cps=FitOptions.cps,
    degrees=FitOptions.degrees,
    *,
    closed: bool | Sequence[bool] = False,
    seed: int | jax.Array | Sequence = 0,
    devices=None,
    batch_size: int | None = None,
    vmap_curves: int | None = None,
    on_result: Callable[[int, FitResult], object] | None = None,
    **options,
) -> list[FitResult]:
    """Fit every point set with every requested degree and control-point count.

    The options are :func:`swarmcurves_jax.fit`'s, shared by every curve, and the result
    for ``point_sets[i]`` is exactly ``fit(point_sets[i], closed=closed[i], seed=seed[i],
    ...)``: batching and sharding change where the work runs, not what it computes.

    Parameters
    ----------
    point_sets : sequence of array_like, each (N_i, 2) or (N_i, 3)
        The curves' points, of any lengths; or one array (B, N, D).
    closed : bool or sequence of bool
        One flag for all, or one per point set.
    seed : int, JAX key, or a sequence of them
        One seed for all (every curve gets the key a lone ``fit`` would), or one each.
    devices : sequence of jax.Device, optional
        Where to run: the batch is split over them (default: every device JAX sees, on
        every host after ``jax.distributed.initialize``).
    batch_size : int, optional
        Curves per program call (default: 32 per device); the last calls of a group are
        evened out, so each group compiles once.  Results do not depend on it.
    vmap_curves : int, optional
        Curves a device runs side by side (vmapped) per trip of its loop.  Default 1 on
        CPUs, where vmapping curves is slower and one at a time is bit-identical to
        ``fit``; 16 on GPUs, which need the width (results then equal ``fit``'s to
        rounding, not bit for bit).
    on_result : callable, optional
        ``on_result(i, result)`` as soon as ``point_sets[i]`` is done (results arrive
        group by group, not in input order): write files as you go.
    **options
        Any field of :class:`~swarmcurves_jax.options.FitOptions`, as for
        :func:`~swarmcurves_jax.fit`; ``progress`` shows a bar over the curves.

    Returns
    -------
    list of FitResult, in the order of ``point_sets``; each ``result.batch`` says which
    call ran it and its bucket.
    """
    opts = FitOptions.from_keywords(dict(options, cps=cps, degrees=degrees), "fit_many")
    sets = _point_sets(point_sets)
    num = len(sets)
    each = isinstance(closed, (list, tuple, np.ndarray))
    closed_flags = [
        check_bool(c, f"closed[{i}]" if each else "closed")
        for i, c in enumerate(_per_curve(closed, num, "closed"))
    ]
    seeds = _per_curve(seed, num, "seed")
    if on_result is not None and not callable(on_result):
        raise ValueError(f"on_result must be callable or None, got {on_result!r}")
    place, per_call = _placement(devices, batch_size, vmap_curves)
    preps = [
        prepare(points, flag, opts, seed_i, f"point_sets[{i}]")
        for i, (points, flag, seed_i) in enumerate(zip(sets, closed_flags, seeds))
    ]
    groups: dict[tuple, list[int]] = {}
    for i, prep in enumerate(preps):
        groups.setdefault(group_key(prep), []).append(i)
    calls = (
        (chosen, [preps[i] for i in chosen], size)
        for chosen, size in _calls(groups, per_call, place.multiple)
    )
    results: list[FitResult | None] = [None] * num
    for i, result in _run_calls(calls, opts, place, num if opts.progress else None):
        results[i] = result
        if on_result is not None:
            on_result(i, result)
    return results


def fit_stream(
    point_sets: Iterable,
    cps=FitOptions.cps,
    degrees=FitOptions.degrees,
    *,
    closed: bool | Iterable[bool] = False,
    seed: int | jax.Array | Iterable = 0,
    devices=None,
    batch_size: int | None = None,
    vmap_curves: int | None = None,
    **options,
) -> Iterator[tuple[int, FitResult]]:
    """Fit point sets read from any iterable as it goes, yielding ``(i, result)`` for
    ``point_sets``'s i-th item as soon as its program call finishes (not in input order).

    For a corpus too large to hold: a point set is read when it is needed, each shape
    bucket runs once it holds ``batch_size`` curves (the rest at the end), and at most one
    call's curves per bucket wait, so memory does not grow with the corpus.  Every result
    equals :func:`fit_many`'s and a lone :func:`~swarmcurves_jax.fit`'s bit for bit on
    CPUs.  A bucket compiles a second program for its last, smaller call.

    ``closed`` and ``seed``: one value for every curve, or an iterable read alongside
    ``point_sets`` (a list, or a generator).  The other parameters are :func:`fit_many`'s;
    ``progress`` shows a bar over the curves done.
    """
    opts = FitOptions.from_keywords(dict(options, cps=cps, degrees=degrees), "fit_stream")
    place, per_call = _placement(devices, batch_size, vmap_curves)
    calls = (
        ([m.index for m in c], [m.prep for m in c], len(c) + (-len(c) % place.multiple))
        for c in bucketed(point_sets, closed, seed, opts, per_call)
    )
    yield from _run_calls(calls, opts, place, None)


class Member(NamedTuple):
    """A streamed point set as read and prepared: its index, its inputs, its preparation."""

    index: int
    points: object
    closed: bool
    seed: object
    prep: Prepared


def bucketed(point_sets: Iterable, closed, seed, opts: FitOptions, size: int):
    """The point sets of a stream, read, checked and prepared one at a time, gathered into
    program calls: a shape bucket's :class:`Member` list once it holds ``size`` of them,
    then each bucket's rest.  ``closed`` and ``seed``: one value or an iterable read
    alongside."""
    if isinstance(point_sets, (str, bytes, np.ndarray)) or not isinstance(point_sets, Iterable):
        raise ValueError(
            "point_sets must be an iterable of (N, 2) or (N, 3) point arrays, got "
            f"{type(point_sets).__name__}"
        )
    closed_flags, seeds = _each(closed), _each(seed)
    waiting: dict[tuple, list[Member]] = {}
    for i, points in enumerate(point_sets):
        flag = check_bool(_next(closed_flags, "closed", i), f"closed[{i}]")
        key = _next(seeds, "seed", i)
        prep = prepare(points, flag, opts, key, f"point_sets[{i}]")
        members = waiting.setdefault(group_key(prep), [])
        members.append(Member(i, points, flag, key, prep))
        if len(members) == size:
            yield members.copy()
            members.clear()
    yield from (members for members in waiting.values() if members)


def _placement(devices, batch_size, vmap_curves) -> tuple[Placement, int]:
    """Where a batch runs and its curves per program call."""
    if batch_size is not None:
        batch_size = check_positive_int(batch_size, "batch_size")
    place = Placement.over(devices, batch=1)
    if vmap_curves is None:
        vmap_curves = 1 if _platform(place) == "cpu" else 16
    place = place._replace(batch=check_positive_int(vmap_curves, "vmap_curves"))
    per_call = batch_size or CURVES_PER_DEVICE * place.multiple
    return place, per_call + (-per_call % place.multiple)


def _run_calls(calls, opts: FitOptions, place: Placement, total):
    """Launch each ``(indices, preps, size)`` call and yield its ``(index, result)``
    pairs, collecting a call on the host (its true projections) while the next one runs
    on the devices.  ``total``: the curves of a progress bar (None: the count is open)."""
    bar = _progress_bar(total) if opts.progress else None

    def finish(chosen, launched, call):
        for i, prep, result in zip(chosen, launched.preps, collect(launched)):
            info = {
                "call": call,
                "curves": len(chosen),
                "bucket": len(prep.data),
                "points": int(prep.mask.sum()),
                "devices": place.multiple,
            }
            yield i, dataclasses.replace(result, batch=info)
        if bar is not None:
            bar.set_description(bar.desc.removesuffix(COMPILING), refresh=False)
            bar.update(len(chosen))

    previous = None
    try:
        for call, (chosen, curves, size) in enumerate(calls):
            launched = launch(curves, opts, place=place, size=size)
            if previous is not None:
                yield from finish(*previous)
            previous = (chosen, launched, call)
        if previous is not None:
            yield from finish(*previous)
    finally:
        if bar is not None:
            bar.close()


def _calls(groups: dict, per_call: int, multiple: int):
    """The curve indices of every program call: a group split into calls of equal size
    (at most ``per_call``, a multiple of the devices), so it compiles once."""
    for members in groups.values():
        size = call_size(len(members), per_call, multiple)
        for part in range(math.ceil(len(members) / size)):
            yield members[part * size : (part + 1) * size], size


def call_size(count: int, per_call: int, multiple: int = 1) -> int:
    """The curves of each program call for a group of ``count`` curves of one shape: at
    most ``per_call``, evened out over the group's calls (so the group compiles one
    program), and a multiple of ``multiple`` (every device gets a share)."""
    size = math.ceil(count / math.ceil(count / per_call))
    return size + (-size % multiple)


def padding_waste(results: Sequence[FitResult]) -> float:
    """The fraction of the fitness's point slots that were padding, over a batch."""
    slots = sum(r.batch["bucket"] for r in results)
    real = sum(r.batch["points"] for r in results)
    return 1.0 - real / slots if slots else 0.0


def _point_sets(point_sets) -> list:
    if isinstance(point_sets, np.ndarray):
        if point_sets.ndim == 3:
            return list(point_sets)
        raise ValueError(
            f"point_sets must be a list of point arrays or one (B, N, D) array, got one array "
            f"of shape {point_sets.shape}; for a single curve call fit(points)"
        )
    if isinstance(point_sets, (str, bytes)) or not isinstance(point_sets, Sequence):
        raise ValueError(
            "point_sets must be a list of (N, 2) or (N, 3) point arrays or one (B, N, D) "
            f"array, got {type(point_sets).__name__}"
        )
    if len(point_sets) == 0:
        raise ValueError("point_sets is empty: give at least one point set")
    return list(point_sets)


def _per_curve(value, num: int, name: str) -> list:
    """``value`` for every curve: one value repeated, or a sequence of ``num`` values."""
    if isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim == 1):
        if len(value) != num:
            raise ValueError(
                f"{name} must be one value or {num} values (one per point set), got {len(value)}"
            )
        return list(value)
    return [value] * num


def _each(value) -> Iterator:
    """Per-curve values: an iterable's items (a list, an array, a generator) in turn, or
    one value (a bool, an int, a JAX key) for every curve."""
    one = isinstance(value, (str, bytes, jax.Array)) or not isinstance(value, Iterable)
    one = one or (isinstance(value, np.ndarray) and value.ndim == 0)
    return itertools.repeat(value) if one else iter(value)


def _next(values: Iterator, name: str, i: int):
    """Point set ``i``'s value from an :func:`_each` iterator."""
    try:
        return next(values)
    except StopIteration:
        raise ValueError(f"{name} ran out at point set {i}: give one value per point set") from None


def _platform(place: Placement) -> str:
    return (jax.devices()[0] if place.mesh is None else place.mesh.devices.flat[0]).platform


def _progress_bar(total):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=f"curves{COMPILING}", unit="curve", leave=False)
