"""Sparse data with corners: a curve can loop in a corner and still have the lowest mean.

    python examples/sparse_corners.py [--out docs/figures]

An L-shaped outline given by 12 points (its corners and the middles of its edges), fitted
closed at 4-12 control points.  Prints each solution's deviations and self-crossings and
what ``best``, ``knee``, ``select("bic")`` and ``sparsest`` pick (the helpers pass over a
curve that crosses itself where the data do not), and draws ``sparse-corners.png``: the
10's curve, its loop at a corner enlarged, and the 11's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmcurves_jax import fit  # noqa: E402

L_OUTLINE = np.array(
    [[0, 0], [1, 0], [2, 0], [2, 0.5], [2, 1], [1.5, 1], [1, 1], [1, 1.5], [1, 2], [0.5, 2],
     [0, 2], [0, 1]],
    dtype=float,
)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs/figures"))
    args = parser.parse_args()
    result = fit(L_OUTLINE, cps=range(4, 13), closed=True)
    for c in result:
        print(f"n={c.n_ctrl:2d}  mean_dev {c.mean_deviation:.3e}  max_dev {c.max_deviation:.3e}"
              f"  crosses itself {c.info['self_crossings']}x")
    picks = {"best": result.best, "knee": result.knee(), "bic": result.select("bic"),
             "sparsest": result.sparsest()}  # fmt: skip
    print({name: c.n_ctrl if c else None for name, c in picks.items()})

    polygon = np.vstack([L_OUTLINE, L_OUTLINE[:1]])
    u = np.linspace(0.0, 1.0, 4001)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.8))
    for ax, n, zoom in ((axes[0], 10, False), (axes[1], 10, True), (axes[2], 11, False)):
        curve = result[3, n]
        ax.plot(*polygon.T, "k.-", lw=0.6, ms=5, label="data")
        ax.plot(*curve.evaluate(u).T, "C3-", lw=1.2, label=f"{n} control points")
        crossings = curve.info["self_crossings"]
        ax.set_title(f"{n} control points: mean {curve.mean_deviation:.4f}, "
                     f"crosses itself {crossings}x", fontsize=9)  # fmt: skip
        if zoom:
            ax.set_xlim(-0.12, 0.12)
            ax.set_ylim(1.88, 2.12)
            ax.set_title("the same, at the corner (0, 2)", fontsize=9)
        ax.set_aspect("equal")
    fig.tight_layout()
    path = Path(args.out) / "sparse-corners.png"
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
