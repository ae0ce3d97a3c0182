"""The same calls and seeds give the same curves as the recorded ones.

``tests/data/same_curves.npz`` holds every solution's control points, weights, knots,
error and two-sided deviation of a fixed set of calls (open, closed, polygon, 3D,
rational, free knots, ``search_every``, ``tol``, and a ``fit_many`` batch).  Reorganising
the code must not change what a call computes: on the machine that recorded them the
curves agree bit for bit, and the tolerance below admits no more than rounding.  Another
kind of CPU (another vector width reorders float32 sums) or another JAX rounds
differently, and the swarm's search amplifies any difference into other curves, so there
the test is skipped with the reason (:func:`machine`).

Re-record (only for an intended change of results): ``python tests/test_same_curves.py``.
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import jax

import numpy as np
import pytest

from swarmcurves_jax import fit, fit_many
from swarmcurves_jax.datasets import analytic_points, random_bspline_points, random_nurbs_points

RECORD = Path(__file__).parent / "data" / "same_curves.npz"
SHORT = dict(particles=16, iterations=60, chunk_size=30)


def _helix(num=120):
    s = np.linspace(0, 4 * np.pi, num)
    return np.c_[np.cos(s), np.sin(s), 0.2 * s]


def machine() -> str:
    """What decides the float32 rounding of the compiled programs: JAX's version, the
    architecture and whether the CPU has 512-bit vectors (XLA:CPU then uses them)."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        flags = ""
    wide = "avx512f" if "avx512f" in flags else "no avx512f"
    return f"jax {jax.__version__}, {platform.machine()}, {wide}"


def calls():
    """name -> a function returning the FitResults of one call."""
    closed_pts = random_bspline_points(7, 3, closed=True, num_points=90, seed=41)[0]
    closed_80 = random_bspline_points(7, 3, closed=True, num_points=80, seed=41)[0]
    return {
        "open": lambda: [fit(analytic_points("f4", 120), cps=[5, 7], degrees=[1, 3], **SHORT)],
        "closed": lambda: [fit(closed_pts, cps=[6, 8], degrees=3, closed=True, seed=3, **SHORT)],
        "helix_3d": lambda: [fit(_helix(), cps=[8], degrees=[2, 3], seed=5, **SHORT)],
        "rational": lambda: [
            fit(
                random_nurbs_points(6, 2, num_points=100, seed=42)[0],
                cps=[6],
                degrees=2,
                rational=True,
                seed=7,
                **SHORT,
            )
        ],
        # the program of tests/test_free_knots.py's open curves
        "free_knots": lambda: [
            fit(analytic_points("f1", 200), cps=[9], free_knots=True, seed=9, iterations=200)
        ],
        "search_every_tol": lambda: [
            fit(
                analytic_points("f3", 100),
                cps=[6, 9],
                degrees=2,
                search_every=4,
                tol=1e-4,
                refine=False,
                seed=11,
                **SHORT,
            )
        ],
        # the shapes of tests/test_batch.py's batches (buckets of 64 and 80, its options)
        "fit_many": lambda: fit_many(
            [analytic_points("f2", 64), closed_80, analytic_points("f5", 60)],
            cps=[4, 6],
            closed=[False, True, False],
            seed=[1, 2, 3],
            iterations=60,
            particles=16,
        ),
    }


def arrays(results) -> dict[str, np.ndarray]:
    """Every solution's numbers, keyed ``curve/degree,n/field``."""
    out = {}
    for b, result in enumerate(results):
        for c in result:
            key = f"{b}/{c.degree},{len(c.control_points)}"
            out[f"{key}/control_points"] = c.control_points
            out[f"{key}/weights"] = c.weights
            out[f"{key}/knots"] = c.knots
            out[f"{key}/errors"] = np.array(
                [c.error, c.max_error, c.mean_deviation, c.max_deviation]
            )
    return out


@pytest.mark.parametrize("name", list(calls()))
def test_same_seeds_give_the_recorded_curves(name):
    with np.load(RECORD) as record:
        recorded = {k: record[k] for k in record.files}
    if str(recorded["machine"]) != machine():
        pytest.skip(f"recorded on {recorded['machine']}; this is {machine()}")
    got = arrays(calls()[name]())
    keys = sorted(k[len(name) + 1 :] for k in recorded if k.startswith(name + "/"))
    assert sorted(got) == keys
    for key in keys:
        want = recorded[f"{name}/{key}"]
        scale = max(1.0, float(np.abs(want).max()))
        np.testing.assert_allclose(got[key], want, rtol=0, atol=1e-5 * scale, err_msg=key)


if __name__ == "__main__":
    flat = {f"{name}/{k}": v for name, call in calls().items() for k, v in arrays(call()).items()}
    RECORD.parent.mkdir(exist_ok=True)
    tmp = RECORD.with_suffix(".tmp.npz")
    np.savez(tmp, machine=np.array(machine()), **flat)
    tmp.replace(RECORD)
    print(f"recorded {len(flat)} arrays to {RECORD}", file=sys.stderr)
