"""Sparse corners and noisy points: where fits loop or fold, and what the helpers pick.

    python examples/loops.py [--out docs/figures]

Two inputs that invite a curve to loop or fold.  An L-shaped outline given by 12 points (its
corners and the middles of its edges), fitted closed at 4-12 control points: curves through
or near every point overshoot its corners (least-squares seeds from chord lengths or even
steps loop there; the centripetal seed does not).  And 100 noisy points along a straight
line (noise about their spacing), fitted at 4-7: a curve that folds back and forth along
the band of noise passes nearer the points than one that follows them (the swarm pays for
the arc its curve runs back against the points' order).  Prints each solution's deviations
and self-crossings and what ``best``, ``knee``, ``select("bic")`` and ``sparsest`` pick (the
helpers pass over a curve that crosses itself where the data do not), and draws
``loops.png``: the L's 8 and 12, the 10's small loop at the corner (0, 0) enlarged, and the
line's 5 and 6.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmcurves_jax import fit  # noqa: E402
from swarmcurves_jax.plotting import save_figure  # noqa: E402

L_OUTLINE = np.array(
    [[0, 0], [1, 0], [2, 0], [2, 0.5], [2, 1], [1.5, 1], [1, 1], [1, 1.5], [1, 2], [0.5, 2],
     [0, 2], [0, 1]],
    dtype=float,
)  # fmt: skip
NOISY_LINE = np.c_[np.linspace(0.0, 1.0, 100), 0.01 * np.random.default_rng(0).normal(size=100)]


def report(name: str, result) -> None:
    """Each solution's deviations and self-crossings, then the helpers' picks."""
    print(name)
    for c in result:
        print(f"  n={c.n_ctrl:2d}  mean_dev {c.mean_deviation:.3e}  max_dev {c.max_deviation:.3e}"
              f"  crosses itself {c.info['self_crossings']}x")  # fmt: skip
    picks = {"best": result.best, "knee": result.knee(), "bic": result.select("bic"),
             "sparsest": result.sparsest()}  # fmt: skip
    print("  picks:", {name: c.n_ctrl if c else None for name, c in picks.items()})


def draw(ax, points, curve, closed=False, title=None) -> None:
    polyline = np.vstack([points, points[:1]]) if closed else points
    ax.plot(*polyline.T, "k.-", lw=0.5, ms=3)
    ax.plot(*curve.evaluate(np.linspace(0.0, 1.0, 4001)).T, "C3-", lw=1.2)
    ax.set_title(title or f"{curve.n_ctrl} control points: mean {curve.mean_deviation:.4f}, "
                 f"crosses itself {curve.info['self_crossings']}x", fontsize=9)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs/figures"))
    args = parser.parse_args()
    outline = fit(L_OUTLINE, cps=range(4, 13), closed=True)
    report("L outline, closed, 4-12 control points", outline)
    line = fit(NOISY_LINE, cps=range(4, 8))
    report("noisy line, 4-7 control points", line)

    fig = plt.figure(figsize=(11, 7))
    top = [fig.add_subplot(2, 3, i) for i in (1, 2, 3)]
    bottom = [fig.add_subplot(4, 1, i) for i in (3, 4)]
    draw(top[0], L_OUTLINE, outline[3, 8], closed=True)
    draw(top[1], L_OUTLINE, outline[3, 12], closed=True)
    draw(top[2], L_OUTLINE, outline[3, 10], closed=True, title="the 10, at the corner (0, 0)")
    top[2].set_xlim(-0.03, 0.03)
    top[2].set_ylim(-0.03, 0.03)
    for ax in top:
        ax.set_aspect("equal")
    for ax, n in zip(bottom, (5, 6)):
        draw(ax, NOISY_LINE, line[3, n])
    fig.tight_layout()
    print(f"wrote {save_figure(fig, Path(args.out) / 'loops.png')}")


if __name__ == "__main__":
    main()
