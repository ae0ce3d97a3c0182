"""Workload W1: f4 data (N = 200), degrees {1, 2, 3}, cps 4-10 (21 swarms),
64 particles, 2000 iterations, float32.

    python benchmarks/bench_w1.py [--iterations 2000] [--repeats 3] [--refine lm]
                                  [--cpu-devices N] [--search-every N] [--workload w64]
                                  [--cache empty|default]

``--workload w64`` is the GPU workload on the same data: degrees {2, 3, 4, 5} x cps
10-25 (64 swarms) x 512 particles, 2000 iterations (24x W1's particles, at costlier degrees).

W1 is the swarm alone (``refine=False``), the workload peers are compared on; ``--refine lm``
adds the default refinement and prints its share (``FitResult.timings``).  Prints the cold
time (first call: tracing + XLA compilation + run, with an empty compilation cache unless
``--cache default``), the warm time (a second call of the same
shapes, which compiles nothing), peak resident memory, particle evaluations per second, the
device and the JAX version; and, per warm run, the process's CPU time and the CPU time the
machine's hypervisor stole (Linux ``/proc/stat``): on a shared virtual machine the wall time
of the same program varies by 2x with the steal, so compare code by CPU time or at low steal.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import resource
import tempfile
import time

import jax
import jax.numpy as jnp

from swarmcurves_jax import compile_cache, fit
from swarmcurves_jax.datasets import analytic_points
from swarmcurves_jax.devices import cpu_devices


def cpu_seconds() -> float:
    """User + system CPU time of this process (every thread)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def cpu_model() -> str:
    """The processor's model name and widest vector extension (Linux ``/proc/cpuinfo``).
    Figures name it: this project's machine is not always the same processor (the same W1
    code ran 1.9x slower on a 2-core AVX2 EPYC than on the earlier AVX-512 one)."""
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read()
    except OSError:
        return platform.processor() or platform.machine()
    names = [ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")]
    flags = set(info.split())
    vector = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"{names[0] if names else platform.machine()}, {vector}"


def stolen_seconds() -> float:
    """CPU time stolen from this machine by its hypervisor so far (NaN off Linux)."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def matmul_flops(size: int = 4096, repeats: int = 2) -> float:
    """FLOP/s of a ``size``² float32 matrix product (``precision="highest"``: float32 on a
    GPU too, whose default is TF32), the best of ``repeats`` calls after one that compiles.
    A gauge of the machine's window: on this shared machine the same W1 code's CPU time
    moves by 30 % and more between windows, and this product's speed with it, though not in
    proportion (docs/performance.md, "The machine")."""
    a = jax.random.normal(jax.random.key(0), (size, size), jnp.float32)
    product = jax.jit(lambda x: jnp.matmul(x, x, precision="highest"))
    jax.block_until_ready(product(a))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(product(a))
        best = min(best, time.perf_counter() - t0)
    return 2 * size**3 / best


#: (degrees, cps, particles) of each workload; both fit f4's 200 points for 2000 iterations.
WORKLOADS = {
    "w1": ((1, 2, 3), range(4, 11), 64),
    "w64": ((2, 3, 4, 5), range(10, 26), 512),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workload", choices=sorted(WORKLOADS), default="w1")
    ap.add_argument("--iterations", type=int, default=2000)
    ap.add_argument("--particles", type=int, help="default: the workload's")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--progress",
        action="store_true",
        help="also time warm runs with the progress bar on (its overhead)",
    )
    ap.add_argument("--refine", choices=("none", "lm", "lbfgs"), default="none")
    ap.add_argument("--search-every", type=int, default=1, help="fit's search_every")
    ap.add_argument(
        "--cpu-devices",
        type=int,
        default=os.cpu_count(),
        help="CPU devices JAX makes (fit deals its swarms over them); default: one per core",
    )
    ap.add_argument(
        "--cache",
        choices=("empty", "default"),
        default="empty",
        help="the compilation cache of the cold call: a new, empty folder (default), or "
        "the user's (what a later session reads back)",
    )
    args = ap.parse_args(argv)
    jax.config.update("jax_num_cpu_devices", args.cpu_devices)
    if args.cache == "empty":
        compile_cache.use_cache(tempfile.mkdtemp(prefix="w1-cache-"))
    degrees, cps, particles = WORKLOADS[args.workload]
    particles = args.particles or particles
    pts = analytic_points("f4")
    kwargs = dict(
        cps=cps,
        degrees=degrees,
        particles=particles,
        iterations=args.iterations,
        seed=0,
        refine=False if args.refine == "none" else args.refine,
        search_every=args.search_every,
    )
    t0 = time.perf_counter()
    result = fit(pts, **kwargs)
    cold = time.perf_counter() - t0
    warm, cpu, stolen = [], [], []
    machine = [matmul_flops()]
    for _ in range(args.repeats):
        t0, c0, s0 = time.perf_counter(), cpu_seconds(), stolen_seconds()
        fit(pts, **kwargs)
        warm.append(time.perf_counter() - t0)
        cpu.append(cpu_seconds() - c0)
        stolen.append(stolen_seconds() - s0)
    machine.append(matmul_flops())
    t0 = time.perf_counter()
    stages = fit(pts, stage_timings=True, **kwargs).timings  # the swarm waited for, to time it
    staged = time.perf_counter() - t0  # that run's own total: its stages add up to it
    with_bar = []
    if args.progress:
        import io
        from contextlib import redirect_stderr

        for _ in range(args.repeats):
            t0 = time.perf_counter()
            with redirect_stderr(io.StringIO()):
                fit(pts, progress=True, **kwargs)
            with_bar.append(time.perf_counter() - t0)
    evals = len(result.solutions) * particles * args.iterations
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"device        : {jax.devices()[0].device_kind} ({jax.default_backend()}), "
        f"{cpu_model()}, jax {jax.__version__}; "
        f"{len(cpu_devices()) or 1} program(s) at once (--cpu-devices {args.cpu_devices}), "
        f"search_every={args.search_every}"
    )
    print(
        f"workload      : {args.workload}, {len(result.solutions)} swarms x {particles} "
        f"particles x {args.iterations} iterations, N = {len(pts)}, float32"
    )
    print(f"cold (compile): {cold:.2f} s")
    print(
        f"warm          : {min(warm):.2f} s (min of {args.repeats}; all: "
        f"{', '.join(f'{w:.2f}' for w in warm)})"
    )
    print(
        f"warm CPU time : {min(cpu):.2f} s (min; all: {', '.join(f'{c:.2f}' for c in cpu)}); "
        f"stolen: {', '.join(f'{x:.1f}' for x in stolen)} s"
    )
    print(
        f"machine now   : a 4096² float32 matmul at {machine[0] / 1e9:.1f} GFLOP/s before the "
        f"warm runs, {machine[1] / 1e9:.1f} after (a gauge of the window: docs/performance.md, The machine)"
    )
    if with_bar:
        print(
            f"warm, progress: {min(with_bar):.2f} s (min of {args.repeats}): overhead "
            f"{100 * (min(with_bar) / min(warm) - 1):+.1f} %"
        )
    parts = [  # FitResult.timings of a warm run that waits between the stages
        f"host setup (least-squares seeds, bases) {stages['setup']:.2f} s",
        f"swarm program {stages['swarm'] - stages['setup']:.2f} s",
    ]
    if args.refine != "none":
        parts.append(f"refine ({args.refine}) {stages['refine']:.2f} s")
    rest = staged - stages["swarm"] - stages.get("refine", 0.0)
    parts.append(f"host projections and the rest {rest:.2f} s")
    print("  stages      : " + ", ".join(parts))
    print(f"throughput    : {evals / min(warm):.3e} particle-evaluations/s")
    print(f"peak RSS      : {peak_mib:.0f} MiB (whole process)")
    print("best per degree:")
    for k in degrees:
        best = min((c for c in result.solutions if c.degree == k), key=lambda c: c.error)
        print(
            f"  degree {k}: n={best.n_ctrl:2d} error={best.error:.3e} "
            f"({best.error_pct_diag:.4f} % of diagonal)"
        )


if __name__ == "__main__":
    main()
