"""Measure PSO coefficient choices on random B-spline recovery (how the defaults were chosen).

    python benchmarks/tune_pso.py [--cases 6] [--iterations 2000]

For every setting, fits the true control-point count of random open cubics (6 cp) and
closed cubics (8 cp) and prints the median and worst mean error (normalised frame).
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from swarmcurves_jax import PSOParams, fit
from swarmcurves_jax.datasets import random_bspline_points


def random_curve_points(rng, n, k, closed):
    return random_bspline_points(n, k, closed, seed=int(rng.integers(2**31)))[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=6)
    ap.add_argument("--iterations", type=int, default=2000)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(2024)
    cases = [("open", random_curve_points(rng, 6, 3, False), 6, False) for _ in range(args.cases)]
    cases += [("closed", random_curve_points(rng, 8, 3, True), 8, True) for _ in range(args.cases)]
    grid = [
        (PSOParams(w, c, c, v, pat), fe, ini)
        for (w, c), v, pat, fe, ini in itertools.product(
            [(0.7298, 1.49618), (0.6, 1.7)],
            [0.1],
            [50.0, 100.0, 200.0],
            [True],
            ["uniform", "lsq"],
        )
    ]
    print(
        f"{'inertia':>8} {'c1=c2':>7} {'v_max':>6} {'pat':>5} {'ends':>5} {'init':>7} | "
        f"{'open med':>9} {'open max':>9} | {'closed med':>10} {'closed max':>10} | time"
    )
    for params, fix_ends, init in grid:
        t0 = time.perf_counter()
        errs = {"open": [], "closed": []}
        for kind, pts, n, closed in cases:
            r = fit(
                pts,
                cps=n,
                degrees=3,
                closed=closed,
                iterations=args.iterations,
                params=params,
                seed=1,
                fix_ends=fix_ends,
                init=init,
            )
            errs[kind].append(r.best.error)
        o, c = np.array(errs["open"]), np.array(errs["closed"])
        print(
            f"{params.inertia:8.4f} {params.cognitive:7.4f} {params.v_max:6.2f} "
            f"{params.patience:5.0f} "
            f"{fix_ends!s:>5} {init:>7} | "
            f"{np.median(o):9.2e} {o.max():9.2e} | {np.median(c):10.2e} {c.max():10.2e} | "
            f"{time.perf_counter() - t0:.1f}s",
            flush=True,
        )


if __name__ == "__main__":
    main()
