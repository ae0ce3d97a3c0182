"""How often fit() recovers a random cubic (mean error <= 2e-3 at the true count).

    python benchmarks/recovery_rates.py [--seeds 20]

Cases of the core tests: open 2D cubic with 6 cp (cps 4-8), closed 2D cubic with 8 cp
(cps 6-10), open 3D cubic with 6 cp (cps 4-8); control points U[-1, 1], 200 points.
"""

from __future__ import annotations

import argparse

import numpy as np

from swarmcurves_jax import fit
from swarmcurves_jax.datasets import random_bspline_points

CASES = [
    ("open 2D, 6 cp", 6, False, 2, range(4, 9)),
    ("closed 2D, 8 cp", 8, True, 2, range(6, 11)),
    ("open 3D, 6 cp", 6, False, 3, range(4, 9)),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first", type=int, default=100)
    args = ap.parse_args(argv)
    for name, n, closed, dim, cps in CASES:
        errs = []
        for seed in range(args.first, args.first + args.seeds):
            pts = random_bspline_points(n, 3, closed, dim=dim, seed=seed)[0]
            r = fit(pts, cps=cps, closed=closed)
            errs.append(r[3, n].error)
            print(f"  {name} seed {seed}: {errs[-1]:.2e}", flush=True)
        errs = np.array(errs)
        print(
            f"{name}: recovered (<= 2e-3) {np.sum(errs <= 2e-3)}/{len(errs)}, "
            f"median {np.median(errs):.2e}, worst {errs.max():.2e}",
            flush=True,
        )


if __name__ == "__main__":
    main()
