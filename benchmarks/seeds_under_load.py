"""The least-squares seeds' host time on idle cores and beside a busy one.

    python benchmarks/seeds_under_load.py [--repeats 3]

The seeds (:mod:`swarmcurves_jax.seeds`) are built on the host before the swarm starts.
A first call builds them before its programs trace, ``fit_many`` while the previous
call's program runs, and any other work on the machine takes cores too.  Their correction
rounds query pykdtree's k-d trees, which run on OpenMP threads.  Prints, for W1's 21
swarms (f4, 200 points, degrees 1-3, counts 4-10) and f4 at 2000 points (degree 3,
counts 4-10), the least of ``--repeats`` times of :func:`~swarmcurves_jax.seeds.seed_positions`
on idle cores and beside one busy core (a process spinning), with the queries on one OpenMP
thread (the package's choice) and on OpenMP's own pool size, the ratio of the two, and
whether both gave the same seeds (they must: the nearest samples are exact either way).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import subprocess
import sys
import time

import numpy as np

from swarmcurves_jax import seeds
from swarmcurves_jax.datasets import analytic_points
from swarmcurves_jax.options import FitOptions
from swarmcurves_jax.prepare import prepare

CASES = {
    "W1 (200 points, 21 swarms)": (200, (1, 2, 3)),
    "f4 at 2000 points (7 swarms)": (2000, (3,)),
}


def seed_args(num_points: int, degrees) -> tuple:
    """``seed_positions``'s arguments as ``fit`` makes them for f4."""
    opts = FitOptions.from_keywords(dict(cps=range(4, 11), degrees=degrees))
    prep = prepare(analytic_points("f4", num_points), False, opts, 0, "f4")
    return prep.pairs, prep.space, prep.fit_pts, prep.closed, prep.ends, np.float64


def timed(args, repeats: int, one_thread: bool):
    """(least time of ``repeats`` calls, the seeds), the queries on one OpenMP thread or
    on OpenMP's own pool size."""
    limit = seeds._one_openmp_thread
    if not one_thread:
        seeds._one_openmp_thread = contextlib.nullcontext
    try:
        out = seeds.seed_positions(*args)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            seeds.seed_positions(*args)
            times.append(time.perf_counter() - start)
    finally:
        seeds._one_openmp_thread = limit
    return min(times), out


@contextlib.contextmanager
def busy_core(busy: bool):
    """A process spinning on one core while the block runs (nothing if not ``busy``)."""
    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        time.sleep(0.3 if busy else 0.0)  # let it start
        yield
    finally:
        if spin is not None:
            spin.kill()
            spin.wait()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    print("# The seeds' host time, idle and beside a busy core\n")
    print(f"{platform.machine()}, {os.cpu_count()} CPU cores; least of {args.repeats}.\n")
    print("| seeds | cores | one OpenMP thread | OpenMP's pool | ratio | same seeds |")
    print("|---|---|---:|---:|---:|---|")
    for name, (num_points, degrees) in CASES.items():
        call = seed_args(num_points, degrees)
        for busy in (False, True):
            with busy_core(busy):
                one, first = timed(call, args.repeats, True)
                pool, second = timed(call, args.repeats, False)
            same = "yes" if np.array_equal(first, second) else "NO"
            cores = "one busy" if busy else "idle"
            print(f"| {name} | {cores} | {one:.3f} s | {pool:.3f} s | {pool / one:.2f}x | {same} |")


if __name__ == "__main__":
    main()
