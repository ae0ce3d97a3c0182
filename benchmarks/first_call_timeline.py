"""Where the cores go in one first call: the process's busy cores over time, beside JAX's
tracing, lowering and compiling of each program.

    python benchmarks/first_call_timeline.py [--call "fit(f4)"] [--iterations 2000]
                                             [--every 0.25] [--cache DIR]

Run it as a fresh process: the call (one of ``benchmarks/first_answer.py``'s, or ``W1``)
is made once with the compilation cache off (``--cache DIR``: that folder instead, to
see a later session), then once warm.  Prints, per interval of ``--every`` seconds from
the call's start, the cores busy (the process's CPU time over the interval, every
thread) and the programs whose tracing, lowering or compiling ended in it, with how long
each took.  A stretch near one core while the machine has more is work that nothing
overlaps: what a different order could still gain; a first call that keeps every core
busy is shortened only by less work.
"""

from __future__ import annotations

import argparse
import os
import threading
import time

#: JAX's event names, as the stages of a first call.
STAGES = {
    "jaxpr_trace_duration": "traced",
    "jaxpr_to_mlir_module_duration": "lowered",
    "backend_compile_duration": "compiled",
}


def sample_cores(every: float, out: list, stop: threading.Event) -> threading.Thread:
    """A thread appending ``(seconds since start, cores busy)`` every ``every`` seconds."""

    def loop():
        last, cpu = time.perf_counter(), time.process_time()
        while not stop.wait(every):
            now, used = time.perf_counter(), time.process_time()
            out.append((now, (used - cpu) / (now - last)))
            last, cpu = now, used

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--call", default="fit(f4)")
    parser.add_argument("--iterations", type=int, default=2000)
    parser.add_argument("--every", type=float, default=0.25)
    parser.add_argument("--cache", default="off", help="compilation cache folder (default off)")
    args = parser.parse_args(argv)
    os.environ["SWARMCURVES_CACHE_DIR"] = args.cache  # before the package is imported

    import jax.monitoring
    from first_answer import _call

    events = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, seconds, **kw: events.append(
            (time.perf_counter(), STAGES.get(event.rsplit("/", 1)[-1]), seconds, kw.get("fun_name"))
        )
    )
    call = _call(args.call, args.iterations)
    samples, stop = [], threading.Event()
    start, cpu = time.perf_counter(), time.process_time()
    sample_cores(args.every, samples, stop)
    call()
    first, cpu_first = time.perf_counter() - start, time.process_time() - cpu
    stop.set()
    warm_start, cpu = time.perf_counter(), time.process_time()
    call()
    warm, cpu_warm = time.perf_counter() - warm_start, time.process_time() - cpu

    print(
        f"{args.call}: first call {first:.2f} s ({cpu_first:.1f} CPU-s), warm {warm:.2f} s "
        f"({cpu_warm:.1f} CPU-s), {os.cpu_count()} cores"
    )
    print("   t (s)  cores  ended in this interval")
    lower = start
    for at, cores in samples:
        if at - start > first:
            break
        ended = [
            f"{fun} {stage} in {s:.2f} s"
            for t, stage, s, fun in events
            if stage and lower < t <= at and s >= 0.05
        ]
        print(f"{at - start:8.2f}  {cores:5.2f}  {'; '.join(ended)}")
        lower = at


if __name__ == "__main__":
    main()
