"""``fit``: every (degree, n) swarm of a call, run as one compiled XLA program.

A fit is a pipeline of stages, each in its own module:

1. :mod:`~swarmcurves_jax.prepare` checks and normalises the points (options:
   :mod:`~swarmcurves_jax.options`);
2. :mod:`~swarmcurves_jax.seeds` builds one least-squares seed per swarm;
3. :mod:`~swarmcurves_jax.search` runs the swarms, launched in chunks by
   :mod:`~swarmcurves_jax.launch` (over devices: :mod:`~swarmcurves_jax.dealing`);
4. :mod:`~swarmcurves_jax.polish` refines every swarm's solution;
5. :mod:`~swarmcurves_jax.selection` measures every swarm's candidates both ways and
   keeps one;
6. :mod:`~swarmcurves_jax.assemble` builds the curves and the
   :class:`~swarmcurves_jax.results.FitResult`.
"""

from __future__ import annotations

import time
from typing import Callable

import jax

from ._validation import check_bool
from .assemble import collect
from .devices import cpu_devices
from .launch import COMPILING, launch
from .options import FitOptions
from .prepare import bucket_length, default_num_samples, normalise, prepare
from .results import FitResult

__all__ = ["fit", "normalise", "default_num_samples", "bucket_length", "FitOptions"]


def fit(
    points,
    cps=FitOptions.cps,
    degrees=FitOptions.degrees,
    *,
    closed: bool = False,
    seed: int | jax.Array = 0,
    callback: Callable[[int, object], object] | None = None,
    **options,
) -> FitResult:
    """Fit B-spline (or NURBS) curves with every requested degree and control-point count.

    Each (degree, n) pair is an independent particle swarm; all swarms of the call run in
    one jit-compiled program, on the default JAX device (a GPU if JAX sees one); when JAX
    has several CPU devices (``jax_num_cpu_devices``), the swarms are dealt over them, one
    program each, with the same results (:func:`~swarmcurves_jax.devices.cpu_devices`).
    Reported errors are true point-to-curve distances in the normalised frame, both ways.

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
    seed : int or jax PRNG key
        Same inputs and seed give the same curves.
    callback : callable, optional
        ``callback(iteration, best_fitness)`` after every chunk of iterations,
        ``best_fitness`` of shape (num_solutions,).
    **options
        Any field of :class:`~swarmcurves_jax.options.FitOptions`: ``rational``,
        ``free_knots``, ``fix_ends``, ``init``, ``refine``, ``particles``, ``iterations``,
        ``tol``, ``params``, ``weight_bounds``, ``num_samples``, ``search_every``,
        ``chunk_size``, ``progress``, ``max_fitness_points``, ``stage_timings``, ``dtype``.

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np
    >>> from swarmcurves_jax import fit
    >>> x = np.linspace(-1, 1, 200)
    >>> result = fit(np.c_[x, x**2], cps=[4, 5], iterations=300)  # a parabola is a cubic
    >>> result[3, 4].error < 1e-6
    True
    """
    start = time.perf_counter()
    opts = FitOptions.from_keywords(dict(options, cps=cps, degrees=degrees))
    closed = check_bool(closed, "closed")
    if callback is not None and not callable(callback):
        raise ValueError(f"callback must be callable or None, got {callback!r}")
    prep = prepare(points, closed, opts, seed, "points")
    bar = _progress_bar(opts.iterations, prep.pairs) if opts.progress else None
    try:
        launched = launch(
            [prep],
            opts,
            callback=None if callback is None else lambda at, best: callback(at, best[0]),
            bar=bar,
            catch_interrupt=True,
            start=start,
            split=cpu_devices(),
        )
        (result,) = collect(launched)
    finally:
        if bar is not None:
            bar.close()
    return result


def _progress_bar(iterations, pairs):
    from tqdm.auto import tqdm

    desc = f"{len(pairs)} swarms{COMPILING}"
    return tqdm(total=iterations, desc=desc, unit="it", leave=False)
