"""The SwarmCurves paper's experiments as cases a script or a notebook can run.

A :class:`Case` holds the data, what to fit, the truth where one is known and the paper's
figure where it gives one; :func:`run_case` fits it and measures every solution against the
data and the truth.  ``benchmarks/paper_suite.py`` runs them all and writes the report.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .curves import Curve
from .datasets import (
    ANALYTIC,
    butterfly_nurbs,
    circular_arc_points,
    normal_noise,
    outlines_path,
    random_bspline_points,
    read_outlines,
    remove_points,
)
from .fit import fit, normalise
from .knots import make_knots
from .measures import data_polyline
from .projection import distance_to_polyline, project_points
from .results import FitResult

__all__ = [
    "Case",
    "CaseRun",
    "TABLE1",
    "paper_cases",
    "run_case",
    "symmetric_distance",
    "hausdorff_distance",
    "arc_length_samples",
]

#: Paper Table 1, SwarmCurves column: name -> (control points or None where the source is not
#: legible, mean error).
TABLE1 = {
    "f1": (11, 5.2e-3),
    "f2": (19, 4.5e-4),
    "f3": (11, 9.7e-2),
    "f4": (None, 1.98e-5),
    "f5": (None, 1.3e-4),
}
#: The paper's claim for clean data: mean error below this % of the bounding-box diagonal.
PAPER_PCT_DIAG = 0.35
TRUTH_SAMPLES = 10_000  # the symmetric distance samples each curve this densely


@dataclasses.dataclass(frozen=True, eq=False)
class Case:
    """One experiment: fit ``points`` with ``fit(points, closed=closed, **fit_kwargs)``.

    ``truth`` is the generating spline when there is one (its control polygon is drawn
    beside the fitted one); ``truth_samples`` are dense points of the true curve (symmetric
    distance); ``clean`` the clean dense data that noisy or sparse ``points`` came from
    (errors against it); ``show`` the (degree, n) the figure shows (``None``: the best).
    All coordinates are in the case's own frame.
    """

    name: str
    figure: str
    points: np.ndarray
    closed: bool
    fit_kwargs: dict[str, Any]
    truth: Curve | None = None
    truth_samples: np.ndarray | None = None
    clean: np.ndarray | None = None
    show: tuple[int, int] | str = "best"
    note: str = ""


@dataclasses.dataclass(frozen=True, eq=False)
class CaseRun:
    """A fitted case: the :class:`FitResult` and one row of measures per solution."""

    case: Case
    result: FitResult
    rows: list[dict[str, Any]]

    @property
    def shown(self) -> Curve:
        """The solution the case's figure shows."""
        show = self.case.show
        if show == "sparsest":
            return self.result.sparsest() or self.result.best
        return self.result.best if show == "best" else self.result[show]

    def row(self, degree: int, n: int) -> dict[str, Any]:
        for r in self.rows:
            if (r["degree"], r["n_ctrl"]) == (degree, n):
                return r
        raise KeyError(f"{self.case.name}: no solution with degree {degree} and n={n}")


def arc_length_samples(polyline: np.ndarray, count: int, closed: bool = False) -> np.ndarray:
    """``count`` points evenly spaced by arc length along a polyline (closed: back to the
    start), so a mean over them is a mean over the curve."""
    p = np.asarray(polyline, dtype=np.float64)
    if closed:
        p = np.vstack([p, p[:1]])
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    at = np.linspace(0.0, s[-1], count, endpoint=not closed)
    return np.stack([np.interp(at, s, p[:, j]) for j in range(p.shape[1])], axis=1)


def _to_polyline(points: np.ndarray, polyline: np.ndarray, closed: bool) -> np.ndarray:
    """Exact distance from every point to a polyline (closed: back to its first vertex):
    the segments beside a point's few nearest vertices can miss its nearest segment where
    other vertices crowd in."""
    return distance_to_polyline(points, data_polyline(polyline, closed))


def symmetric_distance(a: np.ndarray, b: np.ndarray, closed: bool = False) -> float:
    """The symmetric mean distance between two curves given as dense ordered samples:
    the mean of (mean distance from ``a`` to ``b``) and (from ``b`` to ``a``), each curve
    resampled at 10,000 points evenly spaced by arc length and measured against the other
    as a polyline."""
    ab, ba = _both_ways(a, b, closed)
    return 0.5 * float(ab.mean() + ba.mean())


def hausdorff_distance(a: np.ndarray, b: np.ndarray, closed: bool = False) -> float:
    """The Hausdorff distance between two curves given as dense ordered samples, measured as
    :func:`symmetric_distance` measures: the largest distance either way."""
    ab, ba = _both_ways(a, b, closed)
    return float(max(ab.max(), ba.max()))


def _both_ways(a: np.ndarray, b: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Each curve resampled at :data:`TRUTH_SAMPLES` points evenly spaced by arc length,
    and those points' distances to the other as a polyline: ``a`` to ``b``, ``b`` to ``a``."""
    pa = arc_length_samples(a, TRUTH_SAMPLES, closed)
    pb = arc_length_samples(b, TRUTH_SAMPLES, closed)
    return _to_polyline(pa, pb, closed), _to_polyline(pb, pa, closed)


# --------------------------------------------------------------------------- cases
def _spline(ctrl, degree, closed) -> Curve:
    n = len(ctrl)
    return Curve(degree, ctrl, np.ones(n), make_knots(n, degree, closed), closed=closed)


def _dense(curve: Curve) -> np.ndarray:
    return curve.evaluate(np.linspace(0.0, 1.0, 4 * TRUTH_SAMPLES, endpoint=not curve.closed))


def _random(n, degree, closed, seed, num_points=200):
    pts, ctrl = random_bspline_points(n, degree, closed, num_points=num_points, seed=seed)
    return pts, _spline(ctrl, degree, closed)


def _known(name, figure, pts, truth: Curve, fit_kwargs, **extra) -> Case:
    """A case whose data come from the spline ``truth``."""
    return Case(
        name,
        figure,
        pts,
        truth.closed,
        fit_kwargs,
        truth=truth,
        truth_samples=_dense(truth),
        **extra,
    )


def _fig2():
    pts, truth = _random(6, 3, False, seed=0)
    fit_kwargs = {"cps": range(4, 9), "degrees": 3}
    return [_known("fig2 random open cubic, 6 cp", "Fig. 2", pts, truth, fit_kwargs, show=(3, 6))]


def _fig3():
    cases = []
    for closed in (False, True):
        for n in range(5, 11):
            pts, truth = _random(n, 3, closed, seed=100 + n)
            cases.append(
                _known(
                    f"fig3 random {'closed' if closed else 'open'} cubic, {n} cp",
                    "Fig. 3",
                    pts,
                    truth,
                    {"cps": range(4, 11), "degrees": 3},
                    note="best of the seven solutions n = 4..10",
                )
            )
    return cases


def _fig4(data_dir):
    butterfly = butterfly_nurbs()
    pts = butterfly.evaluate(np.linspace(0.0, 1.0, 200, endpoint=False))
    cases = [
        _known(
            "fig4 butterfly NURBS (stand-in)",
            "Fig. 4",
            pts,
            butterfly,
            {"cps": range(8, 21, 2), "degrees": 3, "rational": True},
            show="sparsest",
            note="a stand-in: the paper's Butterfly is not published with coordinates",
        )
    ]
    try:
        outlines = read_outlines(data_dir)
        cup = np.loadtxt(outlines_path(data_dir).parent / "Cup0_noisy.txt")
    except FileNotFoundError:
        return cases, "benchmark outlines not found (set data_dir or $SWARMCURVES_DATA)"
    for name, o in outlines.items():
        cases.append(
            Case(
                f"fig4 outline {name}",
                "Fig. 4",
                o["points"],
                o["closed"],
                {"cps": range(6, 21, 2), "degrees": (2, 3)},
                truth_samples=o["truth"],
                show="sparsest",
            )
        )
    cases.append(
        Case(
            "fig4 noisy cup Cup0 (roughly ordered)",
            "Fig. 4",
            cup,
            True,
            {"cps": range(6, 21, 2), "degrees": (2, 3)},
            show="sparsest",
            note="263 noisy points whose file order zig-zags on the left half; no ground truth",
        )
    )
    return cases, ""


def _fig5(theta=2 * math.pi / 3):
    pts = circular_arc_points(theta)
    dense = circular_arc_points(theta, TRUTH_SAMPLES)
    exact = math.cos(theta / 2)
    note = f"arc of {math.degrees(theta):.0f}°: exact middle weight cos(θ/2) = {exact:.4f}"
    return [
        Case(
            "fig5 circular arc, rational quadratic",
            "Fig. 5",
            pts,
            False,
            {"cps": 3, "degrees": 2, "rational": True},
            truth_samples=dense,
            note=note,
        ),
        Case(
            "fig5 circular arc, non-rational quadratic",
            "Fig. 5",
            pts,
            False,
            {"cps": 3, "degrees": 2},
            truth_samples=dense,
            note="the same arc without weights",
        ),
    ]


def _fig6():
    quintic_pts, quintic = _random(8, 5, False, seed=7)
    cubic_pts, cubic = _random(6, 3, False, seed=8)
    return [
        _known(
            "fig6 quintic (8 cp) fitted by cubics",
            "Fig. 6",
            quintic_pts,
            quintic,
            {"cps": range(6, 13), "degrees": (3, 5)},
            show=(3, 8),
            note="degree 5 at n = 8 is the true model",
        ),
        _known(
            "fig6 cubic (6 cp) fitted by polygons",
            "Fig. 6",
            cubic_pts,
            cubic,
            {"cps": range(4, 25, 2), "degrees": (1, 3)},
            show=(1, 24),
            note="degree 3 at n = 6 is the true model",
        ),
    ]


def _fig7():
    pts, truth = _random(6, 3, False, seed=0)
    clean, center, scale = normalise(pts)
    truth = dataclasses.replace(truth, control_points=(truth.control_points - center) / scale)
    dense = _dense(truth)
    common = dict(closed=False, truth=truth, truth_samples=dense, clean=clean, show=(3, 6))
    fit_kwargs = {"cps": range(4, 11), "degrees": 3}
    cases = [
        Case(
            f"fig7 noise σ = {sigma} (Fig. 2's cubic)",
            "Fig. 7",
            normal_noise(clean, sigma, seed=1),
            fit_kwargs=fit_kwargs,
            note="Gaussian offsets along the normal, normalised frame; errors vs the clean curve",
            **common,
        )
        for sigma in (0.04, 0.06)
    ]
    cases += [
        Case(
            f"fig7 sparse, {int(fraction * 100)} % removed (Fig. 2's cubic)",
            "Fig. 7",
            remove_points(clean, fraction, seed=2),
            fit_kwargs=fit_kwargs,
            note="random points removed, ends kept; errors vs the dense clean curve",
            **common,
        )
        for fraction in (0.5, 0.75, 0.9)
    ]
    return cases


def _fig8():
    cases = []
    for name, (fn, (lo, hi)) in ANALYTIC.items():
        x = np.linspace(lo, hi, 200)
        xd = np.linspace(lo, hi, 4 * TRUTH_SAMPLES)
        n_paper, err = TABLE1[name]
        cases.append(
            Case(
                f"fig8 {name}",
                "Fig. 8 / Table 1",
                np.c_[x, fn(x)],
                False,
                {"cps": range(4, 26), "degrees": (2, 3)},
                truth_samples=np.c_[xd, fn(xd)],
                show=(3, n_paper or 19),
                note=f"paper: {err:.3g} at {n_paper or '? (not legible)'} cp",
            )
        )
    return cases


FIGURES = ("Fig. 2", "Fig. 3", "Fig. 4", "Fig. 5", "Fig. 6", "Fig. 7", "Fig. 8 / Table 1")


def paper_cases(data_dir=None) -> tuple[list[Case], list[str]]:
    """Every experiment of the paper, in its figure order, and notes on what was skipped
    (the benchmark outlines when their folder is not found; see
    :func:`swarmcurves_jax.datasets.outlines_path`)."""
    fig4, skipped = _fig4(data_dir)
    cases = _fig2() + _fig3() + fig4 + _fig5() + _fig6() + _fig7() + _fig8()
    return cases, [skipped] if skipped else []


# --------------------------------------------------------------------------- running
def _in_frame(result: FitResult, curve: Curve) -> Curve:
    """``curve`` in the fit's normalised frame, where every error is measured."""
    return dataclasses.replace(
        curve, control_points=result.normalised(curve.control_points), residuals=None
    )


def _measure(case: Case, result: FitResult, curve: Curve) -> dict[str, Any]:
    row = {
        "case": case.name,
        "figure": case.figure,
        "degree": curve.degree,
        "n_ctrl": curve.n_ctrl,
        "rational": curve.rational,
        "error": curve.error,
        "max_error": curve.max_error,
        "rms_error": curve.rms_error,
        "error_pct_diag": curve.error_pct_diag,
        "mean_deviation": curve.mean_deviation,
        "max_deviation": curve.max_deviation,
        "error_vs_clean": math.nan,
        "symmetric_distance": math.nan,
        "wall_time": result.wall_time,
        "seed": result.seed,
    }
    local = _in_frame(result, curve)
    if case.clean is not None:
        d, _ = project_points(
            result.normalised(case.clean),
            local.control_points,
            local.weights,
            local.knots,
            local.degree,
            local.closed,
        )
        row["error_vs_clean"] = float(d.mean())
    if case.truth_samples is not None:
        row["symmetric_distance"] = symmetric_distance(
            _dense(local), result.normalised(case.truth_samples), case.closed
        )
    if curve.rational:
        w = curve.weights
        row["weights"] = [float(x) for x in w]
        if curve.degree == 2 and curve.n_ctrl == 3:  # the conic's invariant middle weight
            row["middle_weight"] = float(w[1] / math.sqrt(w[0] * w[2]))
    return row


def run_case(case: Case, *, iterations: int = 2000, seed: int = 0, **overrides) -> CaseRun:
    """Fit ``case`` (``overrides`` go to :func:`swarmcurves_jax.fit`) and measure every
    solution: the data errors, the error against the clean data and the
    symmetric distance to the truth where the case has them."""
    kwargs = {**case.fit_kwargs, **overrides}
    result = fit(case.points, closed=case.closed, iterations=iterations, seed=seed, **kwargs)
    return CaseRun(case, result, [_measure(case, result, c) for c in result.solutions])
