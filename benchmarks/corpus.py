"""A corpus of curves: the command line's memory and time from 1,000 to 10,000 curves, a
run killed half way and resumed, and a Dask cluster against one process.

    python benchmarks/corpus.py [--sizes 1000,10000] [--cps 4-5] [--particles 16]
                                [--iterations 10] [--dask-curves 200] [--skip resume,dask]
                                [--out DIR]

- **Streaming**: random open cubics (6-9 control points, 150-250 points, seeds 0...)
  written to one .npz, fitted by ``python -m swarmcurves_jax.run`` into a folder (cubics at
  ``--cps`` control points, ``--particles``, ``--iterations`` each, the polish on, NPZ and
  JSON files, no figures; light settings, so that 10,000 curves take minutes on 2 cores and
  the per-curve host work weighs most), each size in a fresh process: seconds, curves per
  second, and the
  peak resident memory of the process (``ru_maxrss`` from ``os.wait4``).  Targets: peak
  memory at the largest size within 1.5x the smallest's, seconds within 11x per 10x curves.
- **Resume**: the smallest size again, killed (SIGKILL) once half of its curves are written,
  then ``--resume``: the curves kept, that none of them was written again (their files'
  times), and that every file equals the uninterrupted run's (the JSON's run time and
  folder aside, summary.csv's ``call`` column aside).
- **Dask**: ``--dask-curves`` curves, the same options, through
  ``swarmcurves_jax.cluster.fit_on_cluster`` on a ``LocalCluster`` of 2 single-thread
  worker processes against ``fit_many`` in this process (one CPU device, JAX's default),
  both warm (a first pass compiles every bucket): curves per second, the ratio (target
  >= 0.8), and whether every curve is the same bit for bit.

The compiled programs are kept in a folder of the run (the processes share it), so every
size but the first reads them back.  Writes report.md (also printed) and report.json into
``--out`` (default ``benchmarks/results/corpus``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from swarmcurves_jax.datasets import random_bspline_points

REPO = Path(__file__).resolve().parents[1]
DEGREE = 3


def corpus(count: int) -> list[np.ndarray]:
    """``count`` random open cubics of 6-9 control points at 150-250 points."""
    rng = np.random.default_rng(0)
    sizes = rng.integers(150, 251, count)
    return [
        random_bspline_points(6 + i % 4, 3, num_points=int(n), seed=i)[0]
        for i, n in enumerate(sizes)
    ]


def write_corpus(path: Path, count: int) -> None:
    np.savez(path, **{f"c{i:05d}": p for i, p in enumerate(corpus(count))})


def fit_options(settings) -> dict:
    """The keywords of ``fit_many`` for the run's settings (``--cps A-B``, particles,
    iterations)."""
    low, high = (int(c) for c in settings["cps"].split("-"))
    return dict(
        cps=range(low, high + 1),
        degrees=DEGREE,
        particles=settings["particles"],
        iterations=settings["iterations"],
    )


def command(config: Path, npz: Path, out: Path, settings) -> list[str]:
    """The command line fitting ``npz`` into ``out`` with the run's settings."""
    return [
        sys.executable,
        "-m",
        "swarmcurves_jax.run",
        str(config),
        "--input",
        str(npz),
        "--cps",
        settings["cps"],
        "--degrees",
        str(DEGREE),
        "--particles",
        str(settings["particles"]),
        "--iterations",
        str(settings["iterations"]),
        "--out",
        str(out),
        "--quiet",
    ]


def spawn(args, env, stderr=subprocess.PIPE) -> subprocess.Popen:
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=stderr)


def run_measured(args, env) -> dict:
    """Run the command line to its end: seconds, peak resident memory, exit code."""
    begun = time.perf_counter()
    proc = spawn(args, env)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - begun
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise RuntimeError(f"{' '.join(args)} exited {code}: {proc.stderr.read()[-2000:]!r}")
    proc.stderr.close()
    return {"seconds": seconds, "peak_mib": usage.ru_maxrss / 1024}


def streaming(sizes, settings, work: Path, env, config: Path) -> list[dict]:
    rows = []
    for size in sizes:
        npz = work / f"corpus{size}.npz"
        write_corpus(npz, size)
        row = {
            "curves": size,
            **run_measured(command(config, npz, work / f"out{size}", settings), env),
        }
        row["curves_per_s"] = size / row["seconds"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _files(out: Path) -> dict:
    return {str(p.relative_to(out)): p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}


def _same_outputs(a: Path, b: Path) -> bool:
    """Every file of two batch folders equal, but the run's time, folder and call index."""
    if sorted(_files(a)) != sorted(_files(b)):
        return False
    for name in _files(a):
        if name.endswith(".npz"):
            with np.load(a / name) as x, np.load(b / name) as y:
                if x.files != y.files or not all(np.array_equal(x[k], y[k]) for k in x.files):
                    return False
        elif name.endswith("solutions.json"):
            docs = [json.loads((root / name).read_text()) for root in (a, b)]
            for doc in docs:
                doc.pop("wall_time"), doc["config"].pop("out")
            if docs[0] != docs[1]:
                return False
        elif name == "summary.csv":
            rows = [(root / name).read_text().splitlines() for root in (a, b)]
            cut = [[",".join(r.split(",")[:-2] + r.split(",")[-1:]) for r in x] for x in rows]
            if cut[0] != cut[1]:
                return False
    return True


def resume(size, settings, work: Path, env, config: Path) -> dict:
    """Kill a run once half its curves are written, resume it, compare."""
    npz, out = work / f"corpus{size}.npz", work / "killed"
    args = command(config, npz, out, settings)
    begun = time.perf_counter()
    proc = spawn(args, env, subprocess.DEVNULL)
    while len(list(out.glob("*/summary.json"))) < size // 2:
        if proc.poll() is not None:
            raise RuntimeError("the run ended before half of its curves")
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_after = time.perf_counter() - begun
    done = {p.parent.name for p in out.glob("*/summary.json")}
    before = _files(out)
    resumed = run_measured([*args, "--resume"], env)
    after = _files(out)
    kept = [f for f in before if f.split("/")[0] in done]
    row = {
        "curves": size,
        "killed_after_s": killed_after,
        "complete_at_kill": len(done),
        "resume_s": resumed["seconds"],
        "kept_untouched": all(after.get(f) == before[f] for f in kept),
        "identical_to_uninterrupted": _same_outputs(work / f"out{size}", out),
    }
    print(json.dumps(row), flush=True)
    return row


def dask_vs_local(count, settings) -> dict:
    from distributed import Client, LocalCluster

    from swarmcurves_jax import fit_many
    from swarmcurves_jax.cluster import fit_on_cluster

    sets = corpus(count)
    options = fit_options(settings)
    fit_many(sets, **options)  # compile every bucket
    start = time.perf_counter()
    local = fit_many(sets, **options)
    local_s = time.perf_counter() - start
    with (
        # ":0": a free port (None still binds the scheduler's HTTP server to 8787, which a
        # dashboard or another cluster on this machine may hold)
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
        ) as cluster,
        Client(cluster) as client,
    ):
        dict(fit_on_cluster(client, sets, **options))  # compile every bucket on each worker
        start = time.perf_counter()
        far = dict(fit_on_cluster(client, sets, **options))
        far_s = time.perf_counter() - start
    same = all(
        np.array_equal(a.control_points, b.control_points)
        for i, r in enumerate(local)
        for a, b in zip(r.solutions, far[i].solutions)
    )
    row = {
        "curves": count,
        "local_s": local_s,
        "dask_s": far_s,
        "local_curves_per_s": count / local_s,
        "dask_curves_per_s": count / far_s,
        "ratio": local_s / far_s,
        "identical": same,
    }
    print(json.dumps(row), flush=True)
    return row


def markdown(report) -> str:
    lines = [
        "# A corpus of curves",
        "",
        f"{report['machine']}; cubics at {report['cps']} control points, "
        f"{report['particles']} particles, "
        f"{report['iterations']} iterations, the polish on; "
        "`python benchmarks/corpus.py` (commit " + report["commit"] + ").",
        "",
    ]
    rows = report.get("streaming", [])
    if rows:
        lines += [
            "## The command line streaming a corpus",
            "",
            "| curves | seconds | curves / s | peak memory (MiB) |",
            "|---|---|---|---|",
        ]
        for r in rows:
            cells = (r["curves"], f"{r['seconds']:.1f}", f"{r['curves_per_s']:.1f}")
            lines.append(f"| {' | '.join(map(str, cells))} | {r['peak_mib']:.0f} |")
        if len(rows) > 1:
            a, b = rows[0], rows[-1]
            lines += [
                "",
                f"{b['curves']} against {a['curves']} curves: memory "
                f"{b['peak_mib'] / a['peak_mib']:.2f}x "
                f"(target <= 1.5x), time {b['seconds'] / a['seconds']:.2f}x for "
                f"{b['curves'] / a['curves']:.0f}x the curves (target <= 11x per 10x).",
            ]
    if "resume" in report:
        r = report["resume"]
        lines += [
            "",
            "## Killed half way and resumed",
            "",
            f"{r['curves']} curves, SIGKILL after {r['killed_after_s']:.1f} s with "
            f"{r['complete_at_kill']} complete; `--resume` fitted the other "
            f"{r['curves'] - r['complete_at_kill']} in {r['resume_s']:.1f} s (process start and "
            f"compiled programs read back included). Kept curves untouched: "
            f"{r['kept_untouched']}; every file identical to the uninterrupted run's: "
            f"{r['identical_to_uninterrupted']}.",
        ]
    if "dask" in report:
        r = report["dask"]
        lines += [
            "",
            "## A Dask LocalCluster (2 worker processes, 1 thread each) against one process",
            "",
            f"{r['curves']} curves, warm: one process's `fit_many` {r['local_s']:.1f} s "
            f"({r['local_curves_per_s']:.1f} curves/s), the cluster {r['dask_s']:.1f} s "
            f"({r['dask_curves_per_s']:.1f} curves/s): **{r['ratio']:.2f}x** (target >= 0.8x); "
            f"the same curves bit for bit: {r['identical']}.",
        ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1000,10000")
    ap.add_argument("--cps", default="4-5", help="a range A-B")
    ap.add_argument("--particles", type=int, default=16)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--dask-curves", type=int, default=200)
    ap.add_argument("--skip", default="", help="comma-separated: resume, dask")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "corpus")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    settings = {"cps": args.cps, "particles": args.particles, "iterations": args.iterations}
    fit_options(settings)  # a malformed --cps fails here, before anything runs
    skip = set(filter(None, args.skip.split(",")))
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=REPO
    ).stdout.strip()
    report = {
        "commit": commit,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
        **settings,
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        config = work / "job.yaml"
        config.write_text("figures: []\nexports: [json, npz]\n")
        env = dict(os.environ, SWARMCURVES_CACHE_DIR=str(work / "programs"))
        report["streaming"] = streaming(sizes, settings, work, env, config)
        if "resume" not in skip:
            report["resume"] = resume(sizes[0], settings, work, env, config)
    if "dask" not in skip:
        report["dask"] = dask_vs_local(args.dask_curves, settings)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=1))
    text = markdown(report)
    (args.out / "report.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
