"""Which local polish: Levenberg-Marquardt (default) or optax L-BFGS, against none.

    python benchmarks/refine_methods.py [--iterations 2000]

f1-f5 (N = 200), cubic, n = 8, 11, 15, 19, 25, seed 0: the same swarm, then ``refine=False``,
``"lm"`` and ``"lbfgs"``.  Prints the errors and the refinement's time (``FitResult.timings``),
cold (compiling its program) and warm (a second call), and the median ratio to the pure swarm.
"""

from __future__ import annotations

import argparse

import numpy as np

from swarmcurves_jax import fit
from swarmcurves_jax.datasets import ANALYTIC, analytic_points

CPS = (8, 11, 15, 19, 25)
METHODS = (False, "lm", "lbfgs")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=2000)
    args = ap.parse_args(argv)
    errors = {m: [] for m in METHODS}
    cold, warm = {m: 0.0 for m in METHODS}, {m: 0.0 for m in METHODS}
    print(f"n = {CPS}; errors per method, then refine seconds cold / warm")
    for name in ANALYTIC:
        pts = analytic_points(name)
        for m in METHODS:
            kw = dict(cps=CPS, refine=m, iterations=args.iterations, stage_timings=True)
            first, again = fit(pts, **kw), fit(pts, **kw)
            errors[m] += [c.error for c in first.solutions]
            cold[m] += first.timings.get("refine", 0.0)
            warm[m] += again.timings.get("refine", 0.0)
            cells = " ".join(f"{c.error:.2e}" for c in first.solutions)
            print(
                f"{name} {str(m):6s} {cells}   refine {cold[m]:.1f} / {warm[m]:.1f} s", flush=True
            )
    err = {m: np.array(e) for m, e in errors.items()}
    both = np.minimum(err["lm"], err["lbfgs"])
    for m in METHODS[1:]:
        print(
            f"{m}: median error / pure swarm {np.median(err[m] / err[False]):.3f}, the better "
            f"polish in {np.sum(err[m] <= both)}/{len(both)} rows; refine total "
            f"{cold[m]:.1f} s cold, {warm[m]:.1f} s warm"
        )


if __name__ == "__main__":
    main()
