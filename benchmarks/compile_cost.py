"""What each program of one call costs to make, and to run: its trace, lowering and XLA
compilation, each taken afresh several times in one process, the least of them reported.

    python benchmarks/compile_cost.py [--call "fit(f4)"] [--reps 3] [--iterations 50]

The call (one of ``benchmarks/first_answer.py``'s, ``W1``, or one of :data:`MORE_CALLS`)
runs once with the compilation cache off, and the first program of each kind it makes
(the swarm, the polish; ``fit_many`` makes one of each per bucket) is
kept with the arguments of its first run; each is then traced, lowered and compiled
``--reps`` times, JAX's in-memory caches cleared before each, as a fit makes them (on one
chunk of CPython's frame stack, :mod:`swarmcurves_jax.pystack`), and run ``--reps`` times
on those arguments.  Per program: the least wall time of each stage, the compilation's CPU
time (XLA compiles on every core), one run (the swarm's: one chunk of ``--iterations``;
the polish's: all of it) and the size of the lowered program (lines of StableHLO).  A
program that compiles for longer than it runs is where a first call waits.  A fresh
process's compile events vary by 15 % from run to run on a busy 2-core machine; the least
of a few repeats in one process, after the imports and the host's first work, is the
steadier gauge for a change to a program.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

#: Calls beyond the first-answer benchmark's: programs whose run is long beside the
#: defaults' (a rational curve's polish, free knots, a polish of 44 swarms).
MORE_CALLS = ("rational", "free knots", "44 swarms")


def _the_call(name: str, iterations: int):
    """The call ``name`` as a function of no arguments: :data:`MORE_CALLS` or
    ``benchmarks/first_answer.py``'s."""
    from first_answer import _call

    if name not in MORE_CALLS:
        return _call(name, iterations)
    from swarmcurves_jax import fit
    from swarmcurves_jax.datasets import analytic_points

    f1, f4 = analytic_points("f1"), analytic_points("f4")
    return {
        "rational": lambda: fit(f4, rational=True, iterations=iterations),
        "free knots": lambda: fit(f4, free_knots=True, iterations=iterations),
        "44 swarms": lambda: fit(f1, cps=range(4, 26), degrees=(2, 3), iterations=iterations),
    }[name]


def capture(call_name: str, iterations: int) -> dict:
    """Run the call once; the first program of each name it made, with the arguments of
    its first run: ``(jitted, args, static)``."""
    from swarmcurves_jax import compile_cache, launch

    programs = {}
    program = compile_cache.program

    def keep(jitted, options, *args, compile_now=False, **static):
        run = program(jitted, options, *args, compile_now=compile_now, **static)

        def first_run(*call_args):
            programs.setdefault(jitted.__name__, (jitted, call_args, static))
            return run(*call_args)

        return first_run

    launch.compile_cache.program = keep
    try:
        _the_call(call_name, iterations)()
    finally:
        launch.compile_cache.program = program
    return programs


def stages(jitted, args, static) -> dict:
    """One trace, lowering and compilation of ``jitted`` from scratch, then one run: wall
    seconds of each, the compilation's CPU seconds and the lowered program's lines."""
    import jax

    jax.clear_caches()
    t0 = time.perf_counter()
    traced = jitted.trace(*args, **static)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2, c2 = time.perf_counter(), time.process_time()
    compiled = lowered.compile()
    t3, c3 = time.perf_counter(), time.process_time()
    jax.block_until_ready(compiled(*args))
    t4 = time.perf_counter()
    lines = lowered.as_text().count("\n")
    return {
        "trace": t1 - t0,
        "lower": t2 - t1,
        "compile": t3 - t2,
        "cpu": c3 - c2,
        "run": t4 - t3,
        "lines": lines,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--call", default="fit(f4)")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=50)
    args = parser.parse_args(argv)
    if args.reps < 1:
        parser.error(f"--reps must be at least 1, got {args.reps}")
    os.environ["SWARMCURVES_CACHE_DIR"] = "off"  # before the package is imported

    programs = capture(args.call, args.iterations)
    from swarmcurves_jax.pystack import in_one_chunk

    # as a fit makes them: on one chunk of CPython's frame stack (swarmcurves_jax.pystack)
    made = in_one_chunk(stages)
    print(f"{args.call}: the least of {args.reps} (median in brackets), {os.cpu_count()} cores")
    print(
        "| program | trace (s) | lower (s) | compile (s) | compile (CPU-s) | run (s) "
        "| StableHLO lines |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, (jitted, call_args, static) in programs.items():
        runs = [made(jitted, call_args, static) for _ in range(args.reps)]
        cells = [
            f"{min(r[k] for r in runs):.2f} ({statistics.median(r[k] for r in runs):.2f})"
            for k in ("trace", "lower", "compile", "cpu", "run")
        ]
        print(f"| {name} | {' | '.join(cells)} | {runs[-1]['lines']} |")


if __name__ == "__main__":
    main()
