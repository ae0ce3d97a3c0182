"""Does refinement over-fit noise?  Error against the clean curve, refined vs pure swarm.

    python benchmarks/noise_refinement.py [--sigma 0.04] [--seeds 3] [--iterations 1000]

Cases: f1, f4 and a random open 6-cp cubic (seed 101), N = 200, Gaussian offsets of standard
deviation ``sigma`` along the normal in the normalised frame (the paper's Fig. 7a), fitted at
6, 8 and 11 control points with ``refine=False`` and with the default refinement, same seed.
Prints, per case, the mean distance from the dense clean curve (5,000 points) to each fit, and
the ratio refined / pure: below 1 the refinement moved the curve towards the truth.
"""

from __future__ import annotations

import argparse

import numpy as np

from swarmcurves_jax import fit, normalise
from swarmcurves_jax.datasets import analytic_points, normal_noise, random_bspline_points
from swarmcurves_jax.projection import project_points

CPS = (6, 8, 11)


def clean_curves():
    """name -> (clean points, dense clean points)."""
    return {
        "f1": (analytic_points("f1"), analytic_points("f1", 5000)),
        "f4": (analytic_points("f4"), analytic_points("f4", 5000)),
        "random 6-cp": (
            random_bspline_points(6, seed=101)[0],
            random_bspline_points(6, seed=101, num_points=5000)[0],
        ),
    }


def clean_error(curve, dense, center, scale):
    """Mean distance from the dense clean curve to ``curve``, in the clean data's frame."""
    ctrl = (curve.control_points - center) / scale
    dense_n = (dense - center) / scale
    return float(project_points(dense_n, ctrl, curve.weights, curve.knots, 3, False)[0].mean())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigma", type=float, default=0.04)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=1000)
    args = ap.parse_args(argv)
    ratios = []
    print(
        f"sigma {args.sigma}, cps {CPS}, {args.iterations} iterations; clean error pure -> refined"
    )
    for name, (clean, dense) in clean_curves().items():
        clean_n, center, scale = normalise(clean)
        for seed in range(args.seeds):
            noisy = center + scale * normal_noise(clean_n, args.sigma, seed=seed)
            runs = [
                fit(noisy, cps=CPS, refine=r, iterations=args.iterations) for r in (False, True)
            ]
            errs = [[clean_error(c, dense, center, scale) for c in r.solutions] for r in runs]
            ratios += [b / a for a, b in zip(*errs)]
            cells = "  ".join(f"n={n}: {a:.2e} -> {b:.2e}" for n, a, b in zip(CPS, *errs))
            print(f"{name:12s} seed {seed}  {cells}", flush=True)
    r = np.array(ratios)
    print(
        f"refined / pure over {len(r)} fits: mean {r.mean():.3f}, median {np.median(r):.3f}, "
        f"worse (> 1.001) in {np.sum(r > 1.001)}, largest {r.max():.3f}"
    )


if __name__ == "__main__":
    main()
