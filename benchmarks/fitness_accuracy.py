"""How close the swarm's fitness is to the true mean distance, against samples per span.

    python benchmarks/fitness_accuracy.py [--per-span 2,4,8,16] [--seeds 6]

The fitness (``swarmcurves_jax.fitness``) searches a few samples per knot span for each
point's span and start, then runs Newton on the span's exact polynomial; it is a distance to
a true point of the curve, so it can only over-estimate.  Two sets of curves, each measured
against the exact projection (``swarmcurves_jax.projection``, float64):

- **smooth**: W1's data (f4, N = 200) and the least-squares curves of its 21 swarms
  (degrees 1-3, cps 4-10), each also perturbed (control points + N(0, 1e-3 ... 0.3));
  relative over-estimate of the mean distance: median, 90th percentile, max;
- **random**: random cubics, quadrics and quintics with loops and cusps (control points
  U[-1, 1], open and closed, rational too), 200 points sampled on them, fitness of the true
  curve (the exact distance is 0): worst mean over ``--seeds`` seeds per case.

The defaults of ``fit`` (``SAMPLES_PER_SPAN`` for the swarm, ``REFINE_SAMPLES_PER_SPAN`` for
the refinement) were chosen from this table.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from swarmcurves_jax import make_knots, normalise
from swarmcurves_jax.datasets import analytic_points, random_bspline_points, random_nurbs_points
from swarmcurves_jax.seeds import least_squares_ctrl
from swarmcurves_jax.fitness import point_distances
from swarmcurves_jax.span_basis import SpanBasis, make_span_basis
from swarmcurves_jax.projection import project_points

RANDOM_CASES = [  # closed, n, degree, rational
    (False, 6, 3, False),
    (True, 8, 3, False),
    (False, 9, 2, False),
    (True, 9, 5, False),
    (False, 6, 3, True),
    (True, 7, 2, True),
    (False, 10, 3, False),
    (True, 10, 3, False),
]


def _basis(n, k, closed, per_span):
    spans = n if closed else n - k
    host = make_span_basis(n, k, closed, spans * (1 if k == 1 else per_span))
    return SpanBasis(*(jnp.asarray(a) for a in host))


def _fitness(ctrl, weights, basis, points, k):
    w = None if weights is None else jnp.asarray(weights, jnp.float32)
    d = point_distances(jnp.asarray(ctrl, jnp.float32), w, basis, points, degree=k)
    return float(jnp.mean(d))


def smooth(per_span):
    pts = normalise(analytic_points("f4"))[0]
    data = jnp.asarray(pts, jnp.float32)
    rng = np.random.default_rng(0)
    rel = []
    for k in (1, 2, 3):
        for n in range(4, 11):
            basis = _basis(n, k, False, per_span)
            seed = least_squares_ctrl(pts, n, k, False)
            t = make_knots(n, k, False)
            for eps in (0.0, 1e-3, 1e-2, 0.1, 0.3):
                ctrl = seed + eps * rng.standard_normal(seed.shape)
                exact = project_points(pts, ctrl, np.ones(n), t, k, False)[0].mean()
                rel.append(_fitness(ctrl, None, basis, data, k) / exact - 1.0)
    rel = np.array(rel)
    return np.median(rel), np.quantile(rel, 0.9), rel.max(), rel.min()


def random_curve(n, k, closed, seed, rational):
    """Normalised points, control points and weights (None: a B-spline) of a random curve."""
    if rational:
        x, ctrl, w = random_nurbs_points(n, k, closed, seed=seed)
    else:
        (x, ctrl), w = random_bspline_points(n, k, closed, seed=seed), None
    xn, c, s = normalise(x)
    return xn, (ctrl - c) / s, w


def random(per_span, seeds):
    worst = []
    for closed, n, k, rational in RANDOM_CASES:
        basis = _basis(n, k, closed, per_span)
        values = []
        for seed in range(seeds):
            xn, ctrl, w = random_curve(n, k, closed, seed, rational)
            values.append(_fitness(ctrl, w, basis, jnp.asarray(xn, jnp.float32), k))
        worst.append(max(values))
    return worst


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-span", default="2,4,8,16")
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args(argv)
    per_spans = [int(x) for x in args.per_span.split(",")]
    print(f"device: {jax.devices()[0].device_kind}, jax {jax.__version__}, float32\n")
    print("smooth (W1's least-squares curves, perturbed): fitness / exact - 1")
    print("| samples per span | median | 90th percentile | max | min |")
    print("|---:|---:|---:|---:|---:|")
    for c in per_spans:
        med, p90, top, low = smooth(c)
        print(f"| {c} | {med:.1e} | {p90:.1e} | {top:.1e} | {low:.1e} |")
    names = [
        f"{'closed' if cl else 'open'} {n}-cp deg {k}{' NURBS' if r else ''}"
        for cl, n, k, r in RANDOM_CASES
    ]
    print(f"\nrandom curves, fitness of the true curve (worst of {args.seeds} seeds):")
    print("| samples per span | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(names))
    for c in per_spans:
        print(f"| {c} | " + " | ".join(f"{v:.1e}" for v in random(c, args.seeds)) + " |")


if __name__ == "__main__":
    main()
