"""Soak: many consecutive fit() calls of mixed shapes in one process.

    python benchmarks/soak.py [--calls 1000]

Cycles through 8 shapes (N in {60, 150, 300, 600} x 2D/3D, open/closed alternating), 20
iterations, 16 particles, cps {5, 6}.  Reports resident memory (from /proc/self/statm) and the
time per call for every block of 100 calls, and checks that every repeat of a (shape, seed)
gives exactly the same control points as its first run.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from swarmcurves_jax import fit
from swarmcurves_jax.datasets import random_bspline_points


def rss_mib() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=1000)
    args = ap.parse_args(argv)
    if args.calls < 200:
        ap.error("--calls must be >= 200 (the first block of 100 fills the compile cache)")
    shapes = [
        (n, d, i % 2 == 1)
        for i, (n, d) in enumerate((n, d) for n in (60, 150, 300, 600) for d in (2, 3))
    ]
    data = {
        s: random_bspline_points(6, 3, s[2], num_points=s[0], dim=s[1], seed=i)[0]
        for i, s in enumerate(shapes)
    }
    first = {}
    mismatches = 0
    rows = []
    t_block, rss0 = time.perf_counter(), rss_mib()
    for call in range(1, args.calls + 1):
        shape = shapes[call % len(shapes)]
        seed = call % 3
        r = fit(data[shape], cps=[5, 6], closed=shape[2], iterations=20, particles=16, seed=seed)
        ctrl = np.concatenate([c.control_points.ravel() for c in r.solutions])
        key = (shape, seed)
        if key in first:
            mismatches += int(not np.array_equal(first[key], ctrl))
        else:
            first[key] = ctrl
        if call % 100 == 0:
            now = time.perf_counter()
            rows.append((call, rss_mib(), (now - t_block) / 100))
            print(
                f"calls {call:5d}: RSS {rows[-1][1]:7.1f} MiB, {1000 * rows[-1][2]:6.1f} ms/call",
                flush=True,
            )
            t_block = now
    print(
        f"start RSS {rss0:.1f} MiB; after the first block {rows[0][1]:.1f} MiB; "
        f"at the end {rows[-1][1]:.1f} MiB (growth after the compile cache filled: "
        f"{rows[-1][1] - rows[1][1]:+.1f} MiB over {args.calls - 200} calls)"
    )
    print(
        f"time per call: block 2 {1000 * rows[1][2]:.1f} ms, last block {1000 * rows[-1][2]:.1f} ms"
    )
    print(
        f"repeated (shape, seed) runs that differed from their first run: {mismatches} "
        f"of {args.calls - len(first)}"
    )


if __name__ == "__main__":
    main()
