"""Speed of the swarm: W1 against peers in the same run, scaling curves, roofline.

    python benchmarks/speed.py [--quick] [--out DIR] [--skip peers,scaling,compile,memory,roofline]
                               [--only memory,...]   # rerun sections into the last report
                               [--cpu-devices N]     # default: one per core
                               [--search-every N]    # fit's search_every, peers too

Ours runs with one JAX CPU device per core (``--cpu-devices``), so ``fit`` deals its swarms
over them, one program each (docs/method.md, "Several CPU devices"); the peers run as before.

What it measures, all with ``refine=False`` (the swarm alone, the workload peers share):

- **W1** (f4, N = 200, degrees 1-3, cps 4-10: 21 swarms x 64 particles x 2000 iterations,
  float32): cold (first call, compilation included) and warm (min of 3) seconds, particle
  evaluations per second; and **W1-wide**: degrees {1, 2, 3, 5}, cps 4-16 (50 swarms).
- **Peers on the same fitness and swarm settings** (ψ, φ_l, φ_g, v_max, 64 particles, the
  same 21 (degree, n) swarms, the same normalised f4 points and sample bases):
  a straightforward NumPy PSO with the same fitness written in NumPy (:func:`numpy_fitness`,
  vectorised over particles, one swarm at a time); pyswarms ``GlobalBestPSO`` with that
  NumPy fitness, one run per swarm; and evosax's ``PSO``, vmapped over each degree's swarms
  and scanned, jit-compiled, twice: on that same fitness code in ``jax.numpy`` (what a JAX
  user writes: a dense ``argmin`` search and gathers) and on our fitness kernel
  (:func:`swarmcurves_jax.fitness.point_distances`, so that its ratio measures only what
  lies outside the fitness).  ``tests/test_peer_fitness.py`` checks that all of them
  compute ``fit``'s fitness.  With ``--search-every N`` (``fit``'s ``search_every``,
  default 1) ours and every peer search every N-th evaluation and reuse the last search in
  between.  NumPy and pyswarms run 63 iterations (64 evaluations: whole search periods),
  evosax on the plain fitness 199, and are scaled linearly by evaluations to 2000
  iterations, which the table says; evosax on our kernel runs the full 2000.  Ratios are
  peer time / ours (warm).
- **Scaling** (warm seconds and CPU seconds, min of 2, at 100 and 300 iterations, the
  difference scaled to 2000): against N (100 ... 5,000 points, every point in the
  fitness), particles (16 ... 512), swarms (1 ... 64; degree 2-5 pairs with n <= 25 and
  128 samples, so every swarm costs the same) and iterations (W1 at 100 ... 2000); the
  cold compile time against the swarms.
- **Compile time at fixed degrees**: the first call less the second, both at 2 iterations,
  against the swarms (1-16 cubics; 4-64 over degrees 2-5), so that neither the run nor a
  part running beside the other's compilation is counted.
- **Memory**: peak RSS of W1 and of a 100,000-point fit, each in a fresh process.
- **Roofline**: the fitness's FLOPs per particle-evaluation counted from its shapes, the
  achieved FLOP/s on W1, and this CPU's float32 peak measured by a 4096² matmul.

The peers come with ``pip install ".[bench]"`` (pyswarms, evosax); a missing one is reported
as nan.  Writes report.md (also printed), report.json and scaling.png / roofline.png into ``--out``
(default ``benchmarks/results/speed``).  ``--quick`` shrinks everything for a smoke test.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from bench_w1 import cpu_model, cpu_seconds, matmul_flops  # a sibling script: run from benchmarks/

from swarmcurves_jax import fit
from swarmcurves_jax.datasets import analytic_points
from swarmcurves_jax.devices import cpu_devices
from swarmcurves_jax.objective import stack_bases
from swarmcurves_jax.prepare import degree_groups, normalise
from swarmcurves_jax.fitness import (
    NEWTON_STEPS,
    foot_samples,
    point_distances,
    starts_on_segment,
)
from swarmcurves_jax.pso import default_params

REPO = Path(__file__).resolve().parents[1]
W1 = dict(cps=range(4, 11), degrees=(1, 2, 3), particles=64, refine=False, seed=0)
W1_PAIRS = [(k, n) for k in (1, 2, 3) for n in range(4, 11)]
FULL_ITERATIONS = 2000


def timed(fn, repeats=1):
    """(first call's seconds, min of ``repeats`` later calls' seconds, last result)."""
    t0 = time.perf_counter()
    out = fn()
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        warm.append(time.perf_counter() - t0)
    return cold, min(warm) if warm else math.nan, out


# --------------------------------------------------------------------------- the fitness
def w1_problem(dtype=np.float32):
    """The normalised f4 points and, per W1 degree group, its stacked span bases (padded
    to n = 10, as ``fit`` builds them) and the group's ``(k, first, stop)``."""
    pts = normalise(analytic_points("f4"))[0].astype(dtype)
    groups = degree_groups(W1_PAIRS, False)
    bases = [stack_bases(W1_PAIRS[i:j], False, m, 10, dtype) for _, i, j, m in groups]
    return pts, groups, bases


def searches(evaluation, k, every):
    """Whether ``fit``'s swarm searches the nearest samples at this evaluation (0: the
    first) of a degree-``k`` swarm, or reuses the last search's (``search_every``)."""
    return k == 1 or evaluation % every == 0


def numpy_fitness(positions, basis, points, k, feet=None, every=1, xp=np):
    """Our fitness (:func:`swarmcurves_jax.fitness.point_distances`: nearest tangent-segment
    sample, in 2D the foot on that segment, then safeguarded Newton on the span's exact
    polynomial, extended into its neighbours) for one swarm of degree ``k``, vectorised
    over particles and written the plain way: a dense (N, M) ``argmin`` and gathers.
    ``xp``: NumPy (the NumPy and pyswarms peers) or ``jax.numpy`` (evosax's plain-JAX peer:
    the same code, jit-compiled).  ``feet`` (P, N): an earlier search's starts (in samples,
    :func:`swarmcurves_jax.fitness.search_starts`) instead of searching; ``every``: ``fit``'s
    ``search_every``, above 1 all :data:`NEWTON_STEPS` from a start that may be stale.
    Returns the fitness (P,) and the feet."""
    num, dim = positions.shape[0], points.shape[1]
    ctrl = positions.reshape(num, -1, dim)
    n = ctrl.shape[1]
    table, lo_s, hi_s = basis.table[:, :, :n], basis.lo, basis.hi
    on_segment = starts_on_segment(basis.sample_value.shape[-2], dim)
    if feet is None:
        samples = xp.einsum("mn,pnd->pmd", basis.sample_value[:, :n], ctrl)
        tang = xp.einsum("mn,pnd->pmd", basis.sample_tangent[:, :n], ctrl)
        diff = points[None, :, None, :] - samples[:, None, :, :]  # (P, N, M, D)
        along = xp.einsum("pnmd,pmd->pnm", diff, tang)
        len2 = xp.maximum(xp.sum(tang**2, axis=2), 1e-30)[:, None, :]
        s = xp.clip(along / len2, -1.0, 1.0)
        j = xp.argmin(xp.sum(diff**2, axis=3) - s * (2.0 * along - s * len2), axis=2)
        feet = j + 0.5  # (P, N), the sample's centre; in 2D its segment's foot
        if on_segment:
            feet = feet + 0.5 * xp.take_along_axis(s, j[:, :, None], axis=2)[:, :, 0]
    per = basis.per_span  # arrays, not ints: jax.numpy's peer vmaps over swarms
    span = xp.minimum(xp.floor(feet) // per, basis.num_spans - 1).astype(np.int32)
    tau = xp.clip((feet - span * per) / per, 0.0, 1.0)
    coef = xp.einsum("srn,pnd->psrd", table, ctrl)[xp.arange(num)[:, None], span]  # (P,N,R,D)
    lo, hi = lo_s[span], hi_s[span]
    top = table.shape[1] - 3

    def curve(t):
        tt = t[..., None]
        v = sum(coef[:, :, r] * tt**r for r in range(top + 1))
        d1 = sum(r * coef[:, :, r] * tt ** (r - 1) for r in range(1, top + 1))
        d2 = sum(r * (r - 1) * coef[:, :, r] * tt ** (r - 2) for r in range(2, top + 1))
        if k > 1:
            past, before = tt > 1, tt < 0
            e = xp.where(past, tt - 1, xp.minimum(tt, 0))
            jump = xp.where(past, coef[:, :, top + 1], coef[:, :, top + 2])
            on = past | before
            v = v + jump * e**k
            d1 = d1 + xp.where(on, jump * k * e ** (k - 1), 0)
            d2 = d2 + xp.where(on, jump * k * (k - 1) * e ** (k - 2), 0)
        return v, d1, d2

    start = None
    for _ in range(1 if k == 1 else NEWTON_STEPS - (on_segment and every == 1)):
        c0, c1, c2 = curve(tau)
        q = c0 - points[None]
        start = q if start is None else start
        g = xp.sum(q * c1, axis=2)
        gauss = xp.sum(c1 * c1, axis=2)
        h = xp.maximum(gauss + xp.sum(q * c2, axis=2), gauss)
        tau = xp.clip(tau - xp.clip(g / xp.maximum(h, 1e-30), -0.5, 0.5), lo, hi)
    q2 = xp.sum((curve(tau)[0] - points[None]) ** 2, axis=2)
    dist = xp.sqrt(xp.minimum(q2, xp.sum(start**2, axis=2)) + 1e-30)
    return dist.mean(axis=1), feet


def numpy_pso(basis, points, dim, k, iterations, every=1, particles=64, seed=0):
    """The paper's PSO update with our defaults, in plain NumPy."""
    p = default_params()
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1, 1, (particles, dim)).astype(np.float32)
    v = np.zeros_like(q)
    f, feet = numpy_fitness(q, basis, points, k, every=every)
    pbest, pbest_f = q.copy(), f.copy()
    for i in range(1, iterations + 1):
        g = pbest[np.argmin(pbest_f)]
        r1, r2 = rng.random((2, particles, dim), dtype=np.float32)
        v = p.inertia * v + p.cognitive * r1 * (pbest - q) + p.social * r2 * (g - q)
        v = np.clip(v, -p.v_max, p.v_max)
        q = q + v
        feet = None if searches(i, k, every) else feet
        f, feet = numpy_fitness(q, basis, points, k, feet, every)
        better = f < pbest_f
        pbest[better], pbest_f[better] = q[better], f[better]
    return float(pbest_f.min())


def pyswarms_run(basis, points, dim, k, iterations, every=1, particles=64, seed=0):
    import pyswarms as ps

    p = default_params()
    rng = np.random.default_rng(seed)
    carried = {"evaluation": 0, "feet": None}

    def cost(x):  # pyswarms evaluates the whole swarm, in a fixed order, once per iteration
        i = carried["evaluation"]
        feet = None if searches(i, k, every) else carried["feet"]
        f, carried["feet"] = numpy_fitness(x.astype(np.float32), basis, points, k, feet, every)
        carried["evaluation"] = i + 1
        return f

    opt = ps.single.GlobalBestPSO(
        n_particles=particles,
        dimensions=dim,
        options={"c1": p.cognitive, "c2": p.social, "w": p.inertia},
        velocity_clamp=(-p.v_max, p.v_max),
        init_pos=rng.uniform(-1, 1, (particles, dim)),
    )
    # pyswarms evaluates once per iteration, with no separate first evaluation
    cost, _ = opt.optimize(cost, iters=iterations + 1, verbose=False)
    return float(cost)


def evosax_program(groups, iterations, every=1, particles=64, plain=False):
    """evosax PSO vmapped over the swarms of each degree group (as ``fit`` runs them), one
    jit-compiled program of scans under JAX's default compiler options; the search runs
    every ``every`` evaluations, reused in between as ``fit`` does (evosax keeps its
    particles in order).  The fitness: our kernel (:func:`point_distances`), or with
    ``plain`` the NumPy peers' :func:`numpy_fitness` in ``jax.numpy``, the same fitness
    as a JAX user writes it."""
    from evosax.algorithms import PSO

    p = default_params()
    dim = 10 * 2
    es = PSO(population_size=particles, solution=jnp.zeros(dim, jnp.float32))
    params = es.default_params.replace(
        inertia_coeff=p.inertia, cognitive_coeff=p.cognitive, social_coeff=p.social
    )

    def one_swarm(key, basis, points, k):
        def distance(q, foot):
            ctrl = q.reshape(10, 2)
            distances = point_distances(ctrl, None, basis, points, foot, k, stale=every > 1)
            return jnp.mean(distances)

        def evaluate(pop, feet):
            """(fitness (P,), feet), searching first where ``feet`` is None."""
            if plain:
                return numpy_fitness(pop, basis, points, k, feet, every, xp=jnp)
            if feet is None:
                feet = jax.vmap(
                    lambda q: foot_samples(q.reshape(10, 2), None, basis, points, dense=False)
                )(pop)
            return jax.vmap(distance)(pop, feet), feet

        def fitness(pop, feet, evaluation):
            if every == 1 or k == 1:  # a search at every evaluation (ours fused, as fit's)
                return (evaluate(pop, None)[0] if plain else jax.vmap(distance)(pop, None)), feet
            search = searches(evaluation, k, every)
            return jax.lax.cond(
                search, lambda f: evaluate(pop, None), lambda f: evaluate(pop, f), feet
            )

        k0, k1, k2 = jax.random.split(key, 3)
        pop = jax.random.uniform(k0, (particles, dim), jnp.float32, -1.0, 1.0)
        fit0, feet = fitness(pop, jnp.zeros((particles, points.shape[0]), jnp.float32), 0)
        state = es.init(k1, pop, fit0, params)

        def step(carry, xs):
            state, feet = carry
            key, evaluation = xs
            ka, kt = jax.random.split(key)
            pop, state = es.ask(ka, state, params)
            fit_pop, feet = fitness(pop, feet, evaluation)
            state, _ = es.tell(kt, pop, fit_pop, state, params)
            return (state, feet), None

        xs = (jax.random.split(k2, iterations), jnp.arange(1, iterations + 1))
        (state, _), _ = jax.lax.scan(step, (state, feet), xs)
        return state.best_fitness

    def program(keys, bases, points):
        # float32 products on a GPU too (its default is TF32): the fitness our kernel computes
        with jax.default_matmul_precision("highest"):
            return jnp.concatenate(
                [
                    jax.vmap(lambda key, b, k=k: one_swarm(key, b, points, k))(keys[i:j], basis)
                    for (k, i, j, _), basis in zip(groups, bases)
                ]
            )

    return jax.jit(program)


# --------------------------------------------------------------------------- sections
def section_w1(args, report):
    pts = analytic_points("f4")
    it = args.iterations
    cold, warm, res = timed(lambda: fit(pts, iterations=it, **W1), args.repeats)
    evals = 21 * 64 * it
    report["w1"] = {
        "programs": len(cpu_devices()) or 1,
        "search_every": args.search_every,
        "iterations": it,
        "cold_s": cold,
        "warm_s": warm,
        "evals_per_s": evals / warm,
        "best_cubic": min(c.error for c in res.solutions if c.degree == 3),
    }
    # fit refuses n < degree + 1, so degree 5 (n >= 6) is its own call: two programs
    low = dict(W1, cps=range(4, 17), degrees=(1, 2, 3))
    high = dict(W1, cps=range(6, 17), degrees=5)

    def wide():
        return fit(pts, iterations=it, **low).solutions + fit(pts, iterations=it, **high).solutions

    cold_w, warm_w, sols = timed(wide, 1)
    report["w1_wide"] = {"swarms": len(sols), "cold_s": cold_w, "warm_s": warm_w}
    print(
        f"W1 cold {cold:.2f} s, warm {warm:.2f} s; wide cold {cold_w:.2f} warm {warm_w:.2f}",
        file=sys.stderr,
    )


#: The two evosax rows: the NumPy peers' fitness in plain ``jax.numpy`` (as a JAX user
#: writes it), and our fitness kernel (so that the ratio measures only the rest).
EVOSAX_PEERS = {
    "evosax PSO, vmapped, the same fitness in plain jax.numpy": True,
    "evosax PSO, vmapped, on our fitness kernel": False,
}


def section_peers(args, report):
    pts, groups, bases = w1_problem()
    it_full, it_peer = args.iterations, args.peer_iterations
    rows = {}

    def per_swarm(run):
        """Seconds for one ``run`` per W1 swarm at ``it_peer`` iterations, scaled to 2000."""
        t0 = time.perf_counter()
        for (k, i, j, _), basis in zip(groups, bases):
            for s, (_, n) in enumerate(W1_PAIRS[i:j]):
                one = jax.tree_util.tree_map(lambda a, s=s: np.asarray(a)[s], basis)
                run(one, pts, n * 2, k, it_peer, args.search_every)
        return (time.perf_counter() - t0) * (it_full + 1) / (it_peer + 1), it_peer

    rows["NumPy (same fitness)"] = per_swarm(numpy_pso)
    try:
        import pyswarms  # noqa: F401

        rows["pyswarms GlobalBestPSO"] = per_swarm(pyswarms_run)
    except ImportError:
        rows["pyswarms GlobalBestPSO"] = (math.nan, it_peer)
    keys = jax.random.split(jax.random.key(0), len(W1_PAIRS))
    device_bases = jax.tree_util.tree_map(jnp.asarray, bases)
    data = jnp.asarray(pts)
    for name, plain in EVOSAX_PEERS.items():
        it = args.plain_iterations if plain else it_full  # plain: 20x slower, so scaled
        try:
            program = evosax_program(groups, it, args.search_every, plain=plain)
            cold, warm, best = timed(
                lambda run=program: jax.block_until_ready(run(keys, device_bases, data)),
                args.repeats,
            )
            rows[name] = warm * (it_full + 1) / (it + 1), it
            report.setdefault("evosax", {})[name] = {
                "cold_s": cold,
                "iterations": it,
                "best_cubic_fitness": float(np.min(np.asarray(best)[14:])),
            }
        except ImportError:
            rows[name] = (math.nan, it)
    ours = report["w1"]["warm_s"]
    report["peers_ours_s"] = ours  # what the ratios are against, if w1 is rerun alone
    report["peers"] = {
        name: {"seconds": s, "scaled_from": scaled, "ratio": s / ours}
        for name, (s, scaled) in rows.items()
    }
    for name, r in report["peers"].items():
        print(f"{name}: {r['seconds']:.1f} s, {r['ratio']:.1f}x ours", file=sys.stderr)


def section_scaling(args, report):
    it = args.scale_iterations
    scale = FULL_ITERATIONS / (2 * it)
    pts_f4 = analytic_points("f4")

    def warm_time(points, **kw):
        """(compile seconds, marginal wall seconds and CPU seconds per 2000 iterations):
        the swarm stage timed warm at ``it`` and ``3 it`` iterations (min of 2), so per-call
        costs (seeds, bases, the host's error projections) cancel; compile = first call -
        warm call.  The CPU time (every thread of this process) is the steadier figure on
        a shared machine: time stolen by the hypervisor is not charged to it."""
        kwargs = {**W1, **kw}

        def run(n_it):
            cpu = cpu_seconds()
            wall = fit(points, iterations=n_it, stage_timings=True, **kwargs).timings["swarm"]
            return wall, cpu_seconds() - cpu

        cold = run(it)[0]
        once = [min(t) for t in zip(run(it), run(it))]  # (wall, cpu), each the min of 2
        thrice = [min(t) for t in zip(run(3 * it), run(3 * it))]
        return cold - once[0], (thrice[0] - once[0]) * scale, (thrice[1] - once[1]) * scale

    out = {"iterations_used": it, "N": [], "particles": [], "swarms": [], "iterations": []}
    for n_pts in args.sizes:
        x = np.linspace(-2, 2, n_pts)
        pts = np.c_[x, 0.5 * np.sin(x) + np.exp(-30 * x**2)]
        cold, warm, cpu = warm_time(pts, max_fitness_points=n_pts)
        out["N"].append({"x": n_pts, "warm_s": warm, "cpu_s": cpu, "compile_s": cold})
    for p in args.particle_counts:
        cold, warm, cpu = warm_time(pts_f4, particles=p)
        out["particles"].append({"x": p, "warm_s": warm, "cpu_s": cpu, "compile_s": cold})
    for s in args.swarm_counts:
        cps, degrees = _swarm_layout(s)
        cold, warm, cpu = warm_time(pts_f4, cps=cps, degrees=degrees, num_samples=128)
        out["swarms"].append({"x": s, "warm_s": warm, "cpu_s": cpu, "compile_s": cold})
    for n_it in args.iteration_counts:
        cold, warm, _ = timed(lambda: fit(pts_f4, **{**W1, "iterations": n_it}), 1)
        out["iterations"].append({"x": n_it, "warm_s": warm})
    report["scaling"] = out
    for key in ("N", "particles", "swarms", "iterations"):
        pairs = ", ".join(f"{r['x']}: {r['warm_s']:.2f}" for r in out[key])
        print(f"scaling {key}: {pairs}", file=sys.stderr)


def section_compile(args, report):
    """The first call's extra time against the number of swarms, at fixed degrees: the
    first call less the second at 2 iterations (so neither the run nor a part running
    beside another part's compilation is in it), in this process, for one degree (cubics)
    and for four (2-5, the swarms dealt evenly)."""
    pts = analytic_points("f4")
    out = {}
    for name, degrees, counts in (
        ("one degree (3)", (3,), args.compile_counts[0]),
        ("four degrees (2-5)", (2, 3, 4, 5), args.compile_counts[1]),
    ):
        out[name] = []
        for s in counts:
            per = s // len(degrees)
            kw = {**W1, "cps": range(26 - per, 26), "degrees": degrees, "num_samples": 128}
            first, second, _ = timed(lambda kw=kw: fit(pts, iterations=2, **kw), 2)
            out[name].append({"x": s, "compile_s": first - second})
        cells = ", ".join(f"{r['x']}: {r['compile_s']:.1f}" for r in out[name])
        print(f"compile against swarms, {name}: {cells}", file=sys.stderr)
    report["compile"] = out


def _swarm_layout(s):
    """``s`` swarms of equal cost: (cps, degrees) with n <= 25 and always n = 25 present."""
    if s <= 16:
        return range(26 - s, 26), (3,)
    per = s // 4 if s >= 64 else s // 2
    degrees = (2, 3, 4, 5) if s >= 64 else (2, 3)
    return range(26 - per, 26), degrees


MEMORY_SNIPPET = """
import sys, numpy as np
from swarmcurves_jax import fit
from swarmcurves_jax.datasets import analytic_points
n = int(sys.argv[1]); it = int(sys.argv[2])
if n == 200:
    pts = analytic_points("f4")
else:
    x = np.linspace(-2, 2, n); pts = np.c_[x, 0.5 * np.sin(x) + np.exp(-30 * x**2)]
fit(pts, cps=range(4, 11), degrees=(1, 2, 3), refine=False, iterations=it)
# VmHWM, not ru_maxrss: Linux keeps ru_maxrss across fork + exec, so a child would report
# the benchmark's own peak.
hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")][0]
print(int(hwm.split()[1]) / 1024)
"""


def section_memory(args, report):
    out = {}
    for n in (200, 100_000):
        proc = subprocess.run(
            [sys.executable, "-c", MEMORY_SNIPPET, str(n), str(args.memory_iterations)],
            capture_output=True,
            text=True,
            check=True,
        )
        out[str(n)] = float(proc.stdout.strip().splitlines()[-1])
    report["peak_rss_mib"] = out
    print(f"peak RSS MiB: {out}", file=sys.stderr)


def fitness_flops(n_pts, groups, bases, n_pad, dim, particles, every=1):
    """(mean FLOPs per particle-evaluation, FLOPs of one iteration of every swarm), counted
    from the fitness's shapes; a select or a comparison counts as one operation.  The
    search (and its samples) counts once per ``every`` evaluations, as it runs."""
    total, swarms = 0, 0
    for (k, i, j, samples), basis in zip(groups, bases):
        spans, rows = basis.table.shape[1], basis.table.shape[2]
        top = rows - 3
        every_k = 1 if k == 1 else every
        table = 0 if k == 1 else spans * rows  # a polygon's fitness needs no span table
        matmuls = 2 * n_pad * dim * (2 * samples / every_k + table)  # samples, table
        # diff, along, clip, offset to the foot, its square, tag (not a polygon's) or the
        # index's select, min, and where the search starts Newton on the segment its select
        on_segment = k > 1 and starts_on_segment(samples, dim)
        search = n_pts * samples * (7 * dim + (1 if k == 1 else 3 + on_segment)) / every_k
        update = 12 * n_pad * dim  # the PSO update
        if k == 1:  # a polygon's search is its distance (fitness.polyline_distances)
            rest = n_pts  # a sqrt; no Newton
        else:
            select = n_pts * spans * (rows * dim + 3)  # a where per row and column, lo, hi
            jump = 25 + 8 * dim  # the neighbour's polynomial past either end
            step = 6 * top * dim + jump + 10 * dim + 12  # Horner (3 orders), Newton update
            final = 2 * top * dim + jump + 3 * dim + 4  # the foot point and the distance
            # the first step starts inside its span: no jump terms
            rest = select + n_pts * ((NEWTON_STEPS - on_segment) * step - jump + final)
        total += (j - i) * particles * (matmuls + search + rest + update)
        swarms += j - i
    return total / (swarms * particles), total


def section_roofline(args, report):
    peak = matmul_flops(4096, 3)
    _, groups, bases = w1_problem()
    samples = "/".join(str(g[3]) for g in groups)
    # 200 points padded to 208
    per_eval, per_iter = fitness_flops(208, groups, bases, 10, 2, 64, args.search_every)
    warm = report["w1"]["warm_s"]
    achieved = per_iter * report["w1"]["iterations"] / warm
    report["roofline"] = {
        "matmul_peak_flops": peak,
        "flops_per_eval": per_eval,
        "flops_per_iteration": per_iter,
        "achieved_flops": achieved,
        "fraction_of_peak": achieved / peak,
        "samples": samples,
    }
    print(f"roofline: {achieved / 1e9:.1f} GFLOP/s of {peak / 1e9:.1f} peak", file=sys.stderr)


# --------------------------------------------------------------------------- report
def figures(report, out: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from swarmcurves_jax.plotting import save_figure

    sc = report.get("scaling")
    if sc:
        fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
        labels = {
            "N": "points N",
            "particles": "particles",
            "swarms": "swarms",
            "iterations": "iterations",
        }
        for ax, key in zip(axes, labels):
            xs = [r["x"] for r in sc[key]]
            ys = [r["warm_s"] for r in sc[key]]
            ax.loglog(xs, ys, "o-", label="warm")
            if "cpu_s" in sc[key][0]:
                ax.loglog(xs, [r["cpu_s"] for r in sc[key]], "^-", label="CPU time")
            ax.loglog(xs, [ys[0] * x / xs[0] for x in xs], ":", color="0.5", label="linear")
            if key == "swarms":
                ax.loglog(xs, [r["compile_s"] for r in sc[key]], "s--", label="compile")
            ax.set_xlabel(labels[key])
            ax.set_ylabel("seconds (2000 iterations)" if key != "iterations" else "seconds")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize="small")
        fig.tight_layout()
        save_figure(fig, out / "scaling.png")
    rf = report.get("roofline")
    if rf:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        ax.bar(
            ["matmul peak", "W1 fitness"],
            [rf["matmul_peak_flops"] / 1e9, rf["achieved_flops"] / 1e9],
            color=["0.6", "C0"],
        )
        ax.set_ylabel("GFLOP/s (float32)")
        ax.set_title(f"W1 runs at {100 * rf['fraction_of_peak']:.0f} % of the matmul peak")
        fig.tight_layout()
        save_figure(fig, out / "roofline.png")


def markdown(report) -> str:
    w1 = report["w1"]
    lines = [
        "# Swarm speed",
        "",
        f"`python benchmarks/speed.py` on {report['machine']}.",
        "",
        "| W1 (21 swarms x 64 particles x 2000 iterations, N = 200) | |",
        "|---|---|",
        f"| warm (min of {report['repeats']}) | {w1['warm_s']:.2f} s |",
        f"| swarm programs at once (one per CPU device) | {w1.get('programs', 1)} |",
        f"| search every (fit's `search_every`, peers too) | {w1.get('search_every', 1)} |",
        f"| cold (with compilation) | {w1['cold_s']:.2f} s |",
        f"| particle-evaluations / s | {w1['evals_per_s']:.3g} |",
        f"| best cubic error | {w1['best_cubic']:.2e} |",
    ]
    if "w1_wide" in report:
        ww = report["w1_wide"]
        lines.append(
            f"| W1-wide (degrees 1, 2, 3 with cps 4-16 and 5 with 6-16: {ww['swarms']} "
            f"swarms, two calls) | warm "
            f"{ww['warm_s']:.2f} s, cold {ww['cold_s']:.2f} s |"
        )
    if "peak_rss_mib" in report:
        m = report["peak_rss_mib"]
        lines.append(f"| peak RSS, W1 (fresh process) | {m['200']:.0f} MiB |")
        lines.append(f"| peak RSS, N = 100,000 (fresh process) | {m['100000']:.0f} MiB |")
    if "peers" in report:
        ours = report.get("peers_ours_s", w1["warm_s"])
        ours_note = "warm" if ours == w1["warm_s"] else "warm, the run the peers were timed with"
        lines += [
            "",
            "| W1, same fitness and settings | seconds | peer / ours | note |",
            "|---|---:|---:|---|",
            f"| **ours** (`fit`, refine=False) | {ours:.2f} | 1 | {ours_note} |",
        ]
        for name, r in report["peers"].items():
            note = (
                f"{r['scaled_from']} iterations timed, scaled to {w1['iterations']}"
                if r["scaled_from"] != w1["iterations"]
                else "warm, full run"
            )
            lines.append(f"| {name} | {r['seconds']:.1f} | {r['ratio']:.1f}x | {note} |")
    if "scaling" in report:
        sc = report["scaling"]
        lines += [
            "",
            "Scaling: marginal seconds per 2000 iterations of the swarm stage, wall (CPU time "
            f"of both cores) (timed warm at {sc['iterations_used']} and "
            f"{3 * sc['iterations_used']} iterations, min of 2; swarms: equal-cost swarms, "
            "128 samples); iterations: whole warm `fit` calls:",
            "",
        ]
        for key in ("N", "particles", "swarms", "iterations"):
            cells = ", ".join(
                f"{r['x']}: {r['warm_s']:.2f} s" + (f" ({r['cpu_s']:.1f})" if "cpu_s" in r else "")
                for r in sc[key]
            )
            lines.append(f"- {key}: {cells}")
        cells = ", ".join(f"{r['x']}: {r['compile_s']:.1f} s" for r in sc["swarms"])
        lines.append(
            f"- compile time against swarms: {cells} (1-16 swarms are cubics, 32 are degrees "
            "2-3, 64 degrees 2-5: each degree compiles its own specialised fitness, so the "
            "compile time follows the degrees, not the swarms)"
        )
    if "compile" in report:
        lines += [
            "",
            "Compile time against swarms at fixed degrees (first call less the second, at 2 "
            "iterations; n <= 25, 128 samples, 64 particles):",
            "",
        ]
        for name, rows in report["compile"].items():
            cells = ", ".join(f"{r['x']}: {r['compile_s']:.1f} s" for r in rows)
            lines.append(f"- {name}: {cells}")
    if "roofline" in report:
        rf = report["roofline"]
        lines += [
            "",
            f"Roofline: the fitness costs {rf['flops_per_eval']:.3g} FLOPs per "
            f"particle-evaluation ({rf['samples']} samples), W1 achieves "
            f"{rf['achieved_flops'] / 1e9:.1f} GFLOP/s; a 4096² float32 matmul reaches "
            f"{rf['matmul_peak_flops'] / 1e9:.1f} GFLOP/s: "
            f"{100 * rf['fraction_of_peak']:.0f} % of that peak.",
        ]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--skip", default="", help="comma-separated: peers,scaling,compile,memory,roofline"
    )
    ap.add_argument(
        "--only",
        default="",
        help="comma-separated sections to rerun into the existing report (w1 first if given)",
    )
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "speed")
    ap.add_argument(
        "--cpu-devices",
        type=int,
        default=os.cpu_count(),
        help="CPU devices JAX makes: fit deals its swarms over them (docs/method.md); default one "
        "per core, 1 for one program",
    )
    ap.add_argument(
        "--search-every",
        type=int,
        default=1,
        help="fit's search_every, for ours and the peers alike (default 1: every iteration)",
    )
    args = ap.parse_args(argv)
    jax.config.update("jax_num_cpu_devices", args.cpu_devices)
    W1["search_every"] = args.search_every
    skip = set(filter(None, args.skip.split(",")))
    args.iterations = 100 if args.quick else FULL_ITERATIONS
    args.repeats = 1 if args.quick else 3
    args.peer_iterations = 7 if args.quick else 63  # evaluations: whole search periods
    args.plain_iterations = 15 if args.quick else 199  # evosax's plain-JAX fitness
    args.scale_iterations = 20 if args.quick else 100
    args.memory_iterations = 20 if args.quick else FULL_ITERATIONS
    args.sizes = (100, 500) if args.quick else (100, 200, 500, 1000, 2000, 5000)
    args.particle_counts = (16, 64) if args.quick else (16, 32, 64, 128, 256, 512)
    args.swarm_counts = (1, 4) if args.quick else (1, 2, 4, 8, 16, 32, 64)
    args.iteration_counts = (20, 40) if args.quick else (100, 250, 500, 1000, 2000)
    args.compile_counts = ((1, 4), (4, 8)) if args.quick else ((1, 2, 4, 8, 16), (4, 8, 16, 32, 64))
    sections = {
        "w1": section_w1,
        "peers": section_peers,
        "scaling": section_scaling,
        "compile": section_compile,
        "memory": section_memory,
        "roofline": section_roofline,
    }
    only = set(filter(None, args.only.split(",")))
    if only - set(sections):
        ap.error(f"--only: unknown sections {sorted(only - set(sections))}; have {list(sections)}")
    if only:  # rerun some sections, keep the others of the last report
        previous = args.out / "report.json"
        if not previous.is_file():
            ap.error(f"--only needs an earlier full run's {previous}")
        report = json.loads(previous.read_text())
    else:
        report = {
            "machine": f"{cpu_model()}, {os.cpu_count()} cores, "
            f"{jax.devices()[0].platform} ({jax.devices()[0].device_kind}), JAX {jax.__version__}",
            "repeats": args.repeats,
        }
    for name, run in sections.items():
        if name in (only or set(sections) - skip):
            run(args, report)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=1))
    text = markdown(report)
    (args.out / "report.md").write_text(text)
    figures(report, args.out)
    print(text)


if __name__ == "__main__":
    main()
