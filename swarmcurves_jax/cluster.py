"""Fitting a corpus on a Dask cluster: whole program calls as tasks, results streamed back.

``jax.distributed`` splits one batch over several hosts' accelerators, every process holding
every input and receiving every result.  For a corpus, :func:`fit_on_cluster` instead
hands each Dask worker whole program calls: up to ``batch_size`` curves of one shape bucket
(:func:`~swarmcurves_jax.prepare.group_key`), so a worker compiles a bucket's program once
and reuses it for every later call of that bucket.  The client reads the point sets as it
goes, keeps a bounded number of calls in flight, and yields each curve's result as its
call finishes.  Every result equals a lone :func:`~swarmcurves_jax.fit`'s, bit for bit on
CPU workers.  Needs the ``dask`` extra (``pip install "swarmcurves_jax[dask]"``).
"""

from __future__ import annotations

from typing import Iterable, Iterator

import jax

from ._validation import check_positive_int
from .batch import bucketed, fit_many
from .options import FitOptions
from .results import FitResult

__all__ = ["fit_on_cluster", "connect"]


def fit_on_cluster(
    client,
    point_sets: Iterable,
    cps=FitOptions.cps,
    degrees=FitOptions.degrees,
    *,
    closed: bool | Iterable[bool] = False,
    seed: int | jax.Array | Iterable = 0,
    batch_size: int = 32,
    in_flight: int | None = None,
    **options,
) -> Iterator[tuple[int, FitResult]]:
    """Fit point sets on the workers of a ``dask.distributed`` ``client``, yielding
    ``(i, result)`` for ``point_sets``'s i-th item as its task finishes.

    Each task is one :func:`~swarmcurves_jax.fit_many` call of up to ``batch_size`` curves
    of one shape bucket, run on one worker.  Curves are checked and bucketed on the client
    (a bad point set raises before its task is sent, naming ``point_sets[i]``); at most
    ``in_flight`` tasks (default: two per worker thread) are out at once, so the client's
    memory does not grow with the corpus.  ``closed``, ``seed`` and the options are
    :func:`~swarmcurves_jax.fit_stream`'s; ``progress`` shows a bar on the client.
    Workers should run one thread each (``dask worker --nthreads 1``): a worker's JAX
    already uses its cores.
    """
    as_completed = _distributed().as_completed
    opts = FitOptions.from_keywords(dict(options, cps=cps, degrees=degrees), "fit_on_cluster")
    batch_size = check_positive_int(batch_size, "batch_size")
    if in_flight is None:
        in_flight = 2 * max(1, sum(client.nthreads().values()))
    in_flight = check_positive_int(in_flight, "in_flight")
    task = dict(options, cps=cps, degrees=degrees, progress=False)
    running = as_completed()
    bar = _progress_bar() if opts.progress else None

    def finished(count):  # the results of tasks as they finish, until ``count`` are out
        while running.count() > count:
            for i, result in next(running).result():
                yield i, result
                if bar is not None:
                    bar.update(1)

    try:
        for members in bucketed(point_sets, closed, seed, opts, batch_size):
            yield from finished(in_flight - 1)
            index, points, flags, keys, _ = zip(*members)
            running.add(client.submit(_fit_call, index, points, flags, keys, task, pure=False))
        yield from finished(0)
    finally:
        for future in running.futures:
            future.cancel()
        if bar is not None:
            bar.close()


def _fit_call(index, points, closed, seeds, options) -> list[tuple[int, FitResult]]:
    """A task: one program call on the worker (every curve of one bucket)."""
    results = fit_many(
        list(points), closed=list(closed), seed=list(seeds), batch_size=len(points), **options
    )
    return list(zip(index, results))


def connect(address: str, timeout: str = "20s"):
    """A ``dask.distributed`` client of the scheduler at ``address`` ('tcp://host:8786')."""
    return _distributed().Client(address, timeout=timeout)


def _distributed():
    try:
        import distributed
    except ImportError:
        raise ImportError(
            "fitting on a Dask cluster needs the dask extra: pip install 'swarmcurves_jax[dask]'"
        ) from None
    return distributed


def _progress_bar():
    from tqdm.auto import tqdm

    return tqdm(desc="curves", unit="curve", leave=False)
