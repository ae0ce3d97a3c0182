"""Draw README's two figures from the example outline that ships with the package.

    python examples/readme_figures.py [--out docs/figures]

``readme-fit.png``: the 119 points of ``examples/points.csv`` and the best closed cubic
over them, coloured by the distance between curve and data both ways, with its control
polygon.  ``readme-choose.png``: ``mean_deviation`` and ``max_deviation`` against the
control-point count, with the solutions ``best``, ``sparsest`` (1 % of the diagonal) and
``knee`` pick marked.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmcurves_jax import fit  # noqa: E402
from swarmcurves_jax.plotting import plot_control_polygon, plot_curve, save_figure  # noqa: E402

HERE = Path(__file__).resolve().parent


def draw_fit(result, points, path: Path) -> None:
    curve = result.best
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    plot_control_polygon(curve, ax=ax)
    plot_curve(curve, points, ax=ax)
    ax.set_title(
        f"closed cubic, {curve.n_ctrl} control points\n"
        f"largest deviation {curve.max_deviation_pct_diag:.2f} % of the diagonal",
        fontsize=10,
    )
    ax.set_aspect("equal")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def draw_choice(result, points, path: Path) -> None:
    cs = sorted(result.solutions, key=lambda c: c.n_ctrl)
    n = [c.n_ctrl for c in cs]
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    ax.semilogy(n, [c.mean_deviation for c in cs], "o-", label="mean_deviation")
    ax.semilogy(n, [c.max_deviation for c in cs], "s--", label="max_deviation")
    tol = 0.01 * np.linalg.norm(np.ptp(result.normalised(points), axis=0))  # 1 % of the diagonal
    ax.axhline(tol, color="grey", lw=0.8)
    ax.text(n[-1], tol * 1.12, "tolerance: 1 % of the diagonal", color="grey", fontsize=8,
            ha="right")
    picks = [  # (label, solution, the measure it is chosen on, label offset)
        ("best", result.best, "mean_deviation", 1.7),
        ("sparsest(pct_diag=1)", result.sparsest(pct_diag=1.0), "max_deviation", 2.6),
        ("knee()", result.knee(), "mean_deviation", 0.45),
    ]
    for label, c, measure, dy in picks:
        if c is None:
            continue
        y = getattr(c, measure)
        ax.semilogy([c.n_ctrl], [y], "o", ms=13, mfc="none", mec="k")
        ax.annotate(
            label, (c.n_ctrl, y), (c.n_ctrl, y * dy),
            ha="center", fontsize=9, arrowprops={"arrowstyle": "-", "lw": 0.6},
        )
    ax.set_xlabel("control points")
    ax.set_ylabel("normalised frame")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE.parent / "docs" / "figures")
    args = ap.parse_args(argv)
    points = np.loadtxt(HERE / "points.csv", delimiter=",", skiprows=1)
    result = fit(points, cps=range(5, 15), degrees=3, closed=True, seed=0)
    print(result.table())
    args.out.mkdir(parents=True, exist_ok=True)
    draw_fit(result, points, args.out / "readme-fit.png")
    draw_choice(result, points, args.out / "readme-choose.png")
    print(f"wrote {args.out / 'readme-fit.png'} and {args.out / 'readme-choose.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
