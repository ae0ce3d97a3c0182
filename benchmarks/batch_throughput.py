"""Throughput of ``fit_many`` against a loop of ``fit``, a process pool, and a loop of
scipy's ``make_splprep``.

    python benchmarks/batch_throughput.py [--iterations 200] [--sizes 100,1000]
                                          [--skip pool,sharding] [--out DIR]

- **Throughput**, curves per second, for 100 and 1,000 curves (``--sizes``; 10,000 works,
  in hours at the defaults) of 150-250 points (random open cubics with 6-9 control points,
  seeds 0...), fitted with cps 4-10, degree 3, 64 particles, the refinement on,
  ``--iterations`` each (default 200, not the paper's 2000, so the loop stays within
  minutes; the swarm's share of the time grows with it).  In the same run, on the same
  curves and options: ``fit_many`` (warm: its programs compiled by a first call of the
  shape the timed run uses); ``fit`` in a loop (warm); a ``multiprocessing`` pool (spawn)
  of ``fit`` calls with one worker per core, each worker warmed by one fit first; and the
  peer a user would otherwise script, scipy's ``make_splprep`` on the same clamped uniform
  knots for every count, in a loop.  The ``fit`` loop and the pool are timed up to
  ``--loop-max`` curves (default 100) and scaled linearly beyond, which the table says.
  ``fit_many``'s first curves are checked equal to the loop's, bit for bit.
- **Two-sided error**, on the first ``--loop-max`` curves: per curve the lowest
  ``mean_deviation`` (SPEC §1, both ways) over the counts, ours and scipy's (the same
  host measures), their medians, and in how many curves ours is no worse.
- **Sharding**: the same ``fit_many`` of ``--shard-curves`` curves in fresh processes with
  ``XLA_FLAGS=--xla_force_host_platform_device_count=1,2,4,8``: seconds, the curves each
  device computed, whether the swarm stage and the refined curves equal the one-device
  run bit for bit, and the largest control-point difference (0 when they do).
  Forced host devices share this machine's cores, so this shows the split and the equality,
  not a speed-up; on a machine with several GPUs the same call splits over them.

Writes report.md (also printed) and report.json into ``--out`` (default
``benchmarks/results/batch``).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

import jax
import numpy as np
from scipy.interpolate import make_splprep

from swarmcurves_jax import fit, fit_many, make_knots, normalise
from swarmcurves_jax.batch import CURVES_PER_DEVICE, call_size, padding_waste
from swarmcurves_jax.datasets import random_bspline_points
from swarmcurves_jax.measures import deviations
from swarmcurves_jax.prepare import bucket_length
from swarmcurves_jax.projection import project_points

REPO = Path(__file__).resolve().parents[1]
OPTIONS = dict(cps=range(4, 11), degrees=3, particles=64, seed=0)


def curves(count: int) -> list[np.ndarray]:
    """``count`` random open cubics (6-9 control points) at 150-250 points."""
    sizes = np.random.default_rng(0).integers(150, 251, count)
    return [
        random_bspline_points(6 + i % 4, 3, False, num_points=int(n), seed=i)[0]
        for i, n in enumerate(sizes)
    ]


def scipy_fits(points: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """scipy's ``make_splprep`` at every count: least squares on our clamped uniform knots
    (given knots and a large ``s``: FITPACK's fit on fixed knots)."""
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # FITPACK notes that s is not reached
        for n in OPTIONS["cps"]:
            spl, _ = make_splprep(points.T, k=3, t=make_knots(n, 3, False), s=1e12)
            out.append((np.asarray(spl.c), np.asarray(spl.t)))
    return out


def best_mean_deviation(points, fits) -> float:
    """The lowest two-sided ``mean_deviation`` (normalised frame) over ``(ctrl, t)`` fits."""
    _, _, scale = normalise(points)
    best = np.inf
    for ctrl, t in fits:
        ones = np.ones(len(ctrl))
        dist, _ = project_points(points, ctrl, ones, t, 3, False)
        best = min(best, deviations(points, ctrl, ones, t, 3, False, dist).mean_deviation)
    return best / scale


def _fit_one(args):
    points, options = args
    result = fit(points, **options)
    return [c.control_points for c in result.solutions]


def _worker_warmup(options):
    fit(curves(1)[0], **options)


def time_pool(point_sets, options, workers):
    """``(warm-up seconds, seconds)`` of a spawn pool mapping ``fit`` over the curves."""
    ctx = multiprocessing.get_context("spawn")
    start = time.perf_counter()
    with ctx.Pool(workers, initializer=_worker_warmup, initargs=(options,)) as pool:
        pool.map(_fit_one, [(p, options) for p in point_sets[:workers]], chunksize=1)
        warm = time.perf_counter() - start
        start = time.perf_counter()
        pool.map(_fit_one, [(p, options) for p in point_sets], chunksize=1)
        return warm, time.perf_counter() - start


def throughput(sizes, iterations, loop_max, skip):
    options = dict(OPTIONS, iterations=iterations)
    everything = curves(max(sizes))
    rows = []
    fit(everything[0], **options)  # compile the lone fit
    loop_rate = pool_rate = None
    for size in sizes:
        sets = everything[:size]
        # warm fit_many: compile its programs by one call of each bucket, of the size the
        # timed run's calls of that bucket have (a bucket's calls are evened out)
        buckets = {}
        for p in sets:
            buckets.setdefault(bucket_length(len(p)), []).append(p)
        devices = len(jax.devices())
        warm = []
        for members in buckets.values():
            warm += members[: call_size(len(members), CURVES_PER_DEVICE * devices, devices)]
        start = time.perf_counter()
        fit_many(warm, **options)
        cold = time.perf_counter() - start
        start = time.perf_counter()
        many = fit_many(sets, **options)
        batched = time.perf_counter() - start
        row = {
            "curves": size,
            "fit_many_s": batched,
            "fit_many_first_call_s": cold,
            "padding": padding_waste(many),
            "calls": 1 + max(r.batch["call"] for r in many),
        }
        start = time.perf_counter()
        peer = [scipy_fits(p) for p in sets]
        row["scipy_s"] = time.perf_counter() - start
        if size <= loop_max:
            for p in {bucket_length(len(p)): p for p in sets}.values():
                fit(p, **options)  # compile the lone fit of every bucket: the loop runs warm
            start = time.perf_counter()
            lone = [fit(p, **options) for p in sets]
            row["loop_s"] = time.perf_counter() - start
            loop_rate = row["loop_s"] / size
            row["equal"] = all(
                np.array_equal(a.control_points, b.control_points)
                for x, y in zip(lone, many)
                for a, b in zip(x.solutions, y.solutions)
            )
            ours = [min(c.mean_deviation for c in r.solutions) for r in many]
            theirs = [best_mean_deviation(p, f) for p, f in zip(sets, peer)]
            row["ours_median_mean_deviation"] = float(np.median(ours))
            row["scipy_median_mean_deviation"] = float(np.median(theirs))
            row["ours_no_worse"] = int(sum(a <= b for a, b in zip(ours, theirs)))
        else:
            row["loop_s"] = loop_rate * size
            row["loop_scaled"] = True
        if "pool" not in skip:
            workers = os.cpu_count() or 1
            if size <= loop_max:
                row["pool_warmup_s"], row["pool_s"] = time_pool(sets, options, workers)
                pool_rate = row["pool_s"] / size
            else:
                row["pool_s"] = pool_rate * size
                row["pool_scaled"] = True
            row["pool_workers"] = workers
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


SHARD_SCRIPT = """
import json, sys, time, jax, numpy as np
sys.path.insert(0, {bench!r})
from batch_throughput import curves, OPTIONS
from swarmcurves_jax import fit_many
from swarmcurves_jax.devices import Placement
sets = curves({count})
opts = dict(OPTIONS, iterations={iterations})
fit_many(sets, **opts)  # compile
start = time.perf_counter()
many = fit_many(sets, **opts)
seconds = time.perf_counter() - start
share = Placement.over().curves(np.zeros(len(sets) + (-len(sets) % jax.device_count())))
print(json.dumps({{
    "devices": jax.device_count(),
    "seconds": seconds,
    "per_device": [s.data.shape[0] for s in share.addressable_shards],
    "solutions": [[c.control_points.tolist() for c in r.solutions] for r in many],
    "histories": [r.history.tolist() for r in many],
}}))
"""


def sharding(count, iterations, device_counts):
    rows, reference = [], None
    for n in device_counts:
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}")
        code = SHARD_SCRIPT.format(
            bench=str(REPO / "benchmarks"), count=count, iterations=iterations
        )
        proc = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False
        )
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        got = json.loads(proc.stdout.splitlines()[-1])
        reference = got if reference is None else reference
        diff = max(
            float(np.max(np.abs(np.array(a) - np.array(b))))
            for x, y in zip(got["solutions"], reference["solutions"])
            for a, b in zip(x, y)
        )
        row = {
            "devices": got["devices"],
            "seconds": got["seconds"],
            "per_device": got["per_device"],
            "swarm_equal_to_one_device": got["histories"] == reference["histories"],
            "curves_equal_to_one_device": got["solutions"] == reference["solutions"],
            "max_control_point_difference": diff,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def report(rows, shards, args) -> str:
    cpu = platform.processor() or platform.machine()
    lines = [
        "# fit_many throughput",
        "",
        f"Machine: {os.cpu_count()} cores ({cpu}), JAX {jax.__version__} on "
        f"{jax.devices()[0].platform}. Curves: 150-250 points, cps 4-10, degree 3, 64 "
        f"particles, {args.iterations} iterations, refinement on. Command: "
        f"`python benchmarks/batch_throughput.py --iterations {args.iterations}`.",
        "",
        "| curves | fit_many s | curves/s | fit loop s | pool s | scipy loop s | "
        "fit_many / loop | fit_many / pool | fit_many / scipy | padding | calls |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        loop = f"{r['loop_s']:.1f}" + (" (scaled)" if r.get("loop_scaled") else "")
        pool = (
            f"{r['pool_s']:.1f}" + (" (scaled)" if r.get("pool_scaled") else "")
            if "pool_s" in r
            else "-"
        )
        vs_pool = f"{r['pool_s'] / r['fit_many_s']:.2f}x" if "pool_s" in r else "-"
        lines.append(
            f"| {r['curves']} | {r['fit_many_s']:.1f} | {r['curves'] / r['fit_many_s']:.2f} | "
            f"{loop} | {pool} | {r['scipy_s']:.2f} | {r['loop_s'] / r['fit_many_s']:.2f}x | "
            f"{vs_pool} | {r['scipy_s'] / r['fit_many_s']:.3f}x | {100 * r['padding']:.1f} % | "
            f"{r['calls']} |"
        )
    for r in rows:
        if "ours_median_mean_deviation" in r:
            lines.append(
                f"\nTwo-sided error, {r['curves']} curves, the best count of each: median "
                f"mean_deviation {r['ours_median_mean_deviation']:.2e} (ours) against "
                f"{r['scipy_median_mean_deviation']:.2e} (scipy); ours no worse in "
                f"{r['ours_no_worse']} of {r['curves']}."
            )
    by_size = {r["curves"]: r for r in rows}
    if 100 in by_size and 1000 in by_size:
        ratio = by_size[1000]["fit_many_s"] / by_size[100]["fit_many_s"]
        lines += ["", f"1,000 curves took {ratio:.2f}x the time of 100 (linear: 10x)."]
    equal = [r["equal"] for r in rows if "equal" in r]
    lines.append(
        f"fit_many equal to the fit loop bit for bit: {all(equal)} ({len(equal)} sizes checked)."
    )
    if shards:
        lines += [
            "",
            f"## Sharding over forced host devices ({args.shard_curves} curves)",
            "",
            "| devices | seconds | curves per device | swarm = 1 device, bit for bit | "
            "curves = 1 device, bit for bit | largest control-point difference |",
            "|---:|---:|---|---|---|---:|",
        ]
        for s in shards:
            lines.append(
                f"| {s['devices']} | {s['seconds']:.1f} | {s['per_device']} | "
                f"{s['swarm_equal_to_one_device']} | {s['curves_equal_to_one_device']} | "
                f"{s['max_control_point_difference']:.1e} |"
            )
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--sizes", default="1,10,100,1000")
    ap.add_argument("--loop-max", type=int, default=100)
    ap.add_argument("--shard-curves", type=int, default=16)
    ap.add_argument("--devices", default="1,2,4,8")
    ap.add_argument("--skip", default="", help="comma list of: pool, sharding")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "batch"))
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = throughput(sizes, args.iterations, args.loop_max, skip)
    shards = []
    if "sharding" not in skip:
        counts = [int(d) for d in args.devices.split(",")]
        shards = sharding(args.shard_curves, args.iterations, counts)
    text = report(rows, shards, args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.md").write_text(text)
    (out / "report.json").write_text(json.dumps({"throughput": rows, "sharding": shards}, indent=1))
    print(text)


if __name__ == "__main__":
    main()
