"""A long scan: where a warm fit of many points spends its time.

    python benchmarks/large_input.py [--points 2000,20000,100000] [--iterations 100]

f4 sampled at each point count, ``cps=range(4, 11)``, the default polish.  The swarm's
fitness uses at most ``max_fitness_points`` (2000) of the points, so its time hardly
grows with the count; the reported errors and the selection's two-sided measures use
every point, on the host.  Prints per count the warm wall time (the lower of two calls
after a first that compiles), the time until the device's results are back (swarm and
polish), and the rest: measuring the candidates, selecting and building the curves.
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

from swarmcurves_jax import fit
from swarmcurves_jax.datasets import analytic_points


def measure(count: int, iterations: int) -> tuple[float, float]:
    """The warm call's wall time and its device share, seconds (the lower of two calls)."""
    points = analytic_points("f4", count)
    fit(points, cps=range(4, 11), iterations=iterations)
    runs = []
    for _ in range(2):
        start = time.perf_counter()
        result = fit(points, cps=range(4, 11), iterations=iterations)
        runs.append((time.perf_counter() - start, result.timings["call"]))
    return min(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", default="2000,20000,100000")
    parser.add_argument("--iterations", type=int, default=100)
    args = parser.parse_args()
    counts = [int(c) for c in args.points.split(",")]
    print(f"JAX {jax.__version__} on {jax.default_backend()}, {platform.processor() or ''}")
    print("| points | warm fit (s) | swarm and polish (s) | host measures and assembly (s) |")
    print("|---:|---:|---:|---:|")
    for count in counts:
        wall, device = measure(count, args.iterations)
        print(f"| {count:,} | {wall:.2f} | {device:.2f} | {wall - device:.2f} |", flush=True)


if __name__ == "__main__":
    main()
