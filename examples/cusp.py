"""A cusp between two samples: where the polyline through the data cuts a corner.

    python examples/cusp.py [--out docs/figures]

The paper's f3 has a cusp whose tip lies between two of its 200 samples, 0.045 above the
chord between them.  A curve that follows the data's slopes up to the tip leaves that
polyline there, so by the polyline alone (``max_deviation``) it looks farther from the data
than a curve that rounds the tip off.  The selection allows for such corners
(``info["corner_max_deviation"]``, ``swarmcurves_jax.measures.corners``).  Fits f3 at 11
and 16 control points, prints each curve's measures and its distance to the true curve
beside scipy's least-squares spline on the same knots (``make_lsq_spline``, chord-length
parameters), and draws ``cusp.png``: each curve over the data and the true curve, and
enlarged at the tip.  Then fits f3 as Table 1's benchmark does (``cps=range(4, 20)``),
where the polished curve at 14 rises past the true tip and the host refuses it, and
draws ``cusp-shortened.png``: the curve reported at 14 with the polish's step shortened
(``selection.SHORTENED``) and without (``SHORTENED = ()``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.interpolate import make_lsq_spline  # noqa: E402

from swarmcurves_jax import fit, make_knots, selection  # noqa: E402
from swarmcurves_jax.datasets import analytic_points  # noqa: E402
from swarmcurves_jax.paper import hausdorff_distance  # noqa: E402
from swarmcurves_jax.plotting import save_figure  # noqa: E402


def scipy_lsq(points: np.ndarray, n: int) -> np.ndarray:
    """scipy's cubic least-squares spline with ``n`` coefficients on our knots, sampled."""
    u = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    spline = make_lsq_spline(u / u[-1], points, make_knots(n, 3, False), k=3)
    return spline(np.linspace(0.0, 1.0, 20_001))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs/figures"))
    args = parser.parse_args()
    points, truth = analytic_points("f3"), analytic_points("f3", 100_001)
    result = fit(points, cps=[11, 16], seed=0)
    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for (whole, tip), c in zip(axes.T, result.solutions):
        curve = c.evaluate(np.linspace(0.0, 1.0, 20_001))
        away = hausdorff_distance(curve, truth)
        print(f"n={c.n_ctrl}: {c.info['source']}, max_deviation {c.max_deviation:.2e} "
              f"(corners allowed for: {c.info['corner_max_deviation']:.2e}), "
              f"Hausdorff distance to the true f3 {away:.2e}; scipy's least squares: "
              f"{hausdorff_distance(scipy_lsq(points, c.n_ctrl), truth):.2e}")  # fmt: skip
        for ax in (whole, tip):
            ax.plot(*truth.T, "-", color="0.75", lw=4, label="true f3")
            ax.plot(*points.T, "k.-", lw=0.5, ms=3, label="data")
            ax.plot(*curve.T, "C3-", lw=1.2, label=f"{c.n_ctrl} control points")
        whole.set_title(f"{c.n_ctrl} control points: {away:.1e} from the true f3", fontsize=9)
        tip.set_xlim(0.46, 0.54)
        tip.set_ylim(0.75, 1.05)
        tip.set_title("at the tip", fontsize=9)
        tip.legend(fontsize=8, loc="lower center")
    fig.tight_layout()
    print(f"wrote {save_figure(fig, Path(args.out) / 'cusp.png')}")
    shortened(points, truth, Path(args.out) / "cusp-shortened.png")


def shortened(points: np.ndarray, truth: np.ndarray, path: Path, n: int = 14) -> None:
    """Table 1's call at ``n`` control points, reported with and without the polish's
    shortened step: drawn whole and at the tip."""
    kept, curves = selection.SHORTENED, {}
    for label, steps in (("without the shortened step", ()), ("shortened", kept)):
        selection.SHORTENED = steps
        try:
            c = fit(points, cps=range(4, 20), seed=0)[3, n]
        finally:
            selection.SHORTENED = kept
        curve = c.evaluate(np.linspace(0.0, 1.0, 20_001))
        curves[label] = (c, curve, hausdorff_distance(curve, truth))
        print(f"cps=range(4, 20), n={n}, {label}: {c.info['source']}, mean_deviation "
              f"{c.mean_deviation:.2e}, crossings {c.info['self_crossings']}, Hausdorff "
              f"distance to the true f3 {curves[label][2]:.2e}")  # fmt: skip
    fig, axes = plt.subplots(1, 2, figsize=(10, 5))
    for ax in axes:
        ax.plot(*truth.T, "-", color="0.75", lw=4, label="true f3")
        ax.plot(*points.T, "k.-", lw=0.5, ms=3, label="data")
        for (label, (c, curve, away)), color in zip(curves.items(), ("C0", "C3")):
            ax.plot(*curve.T, f"{color}-", lw=1.2, label=f"{c.info['source']}: {away:.1e}")
    axes[0].set_title(f"f3 at {n} control points, cps=range(4, 20)", fontsize=9)
    axes[1].set_xlim(0.46, 0.54)
    axes[1].set_ylim(0.75, 1.05)
    axes[1].set_title("at the tip (legend: Hausdorff distance to the true f3)", fontsize=9)
    axes[1].legend(fontsize=8, loc="lower center")
    fig.tight_layout()
    print(f"wrote {save_figure(fig, path)}")


if __name__ == "__main__":
    main()
