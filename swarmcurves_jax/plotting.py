"""Figures of a fit, in the paper's style.  matplotlib is imported lazily; every function
draws into given (or new) Axes and returns them, keeping no global state."""

from __future__ import annotations

import numpy as np

from .curves import Curve
from .measures import data_polyline
from .projection import distance_to_polyline, project_points
from .results import FitResult

__all__ = [
    "residual_along_curve",
    "plot_curve",
    "plot_control_polygon",
    "plot_solution",
    "plot_error_vs_cps",
    "plot_result",
    "save_figure",
]


def save_figure(fig, path, dpi: int = 90):
    """Write ``fig`` to ``path`` as a PNG, atomically (a reader finds the old file or the
    new one, whole), and close it; returns ``path``."""
    import matplotlib.pyplot as plt

    from .export import atomic_write

    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    plt.close(fig)
    return path


def _axes(ax, projection=None):
    if ax is not None:
        return ax
    import matplotlib.pyplot as plt

    return plt.figure().add_subplot(projection=projection)


def residual_along_curve(curve: Curve, points, u) -> np.ndarray:
    """Distance of the data to the curve, as a function of the curve parameter ``u``: each
    point's true distance, placed at its foot point and interpolated in between."""
    data = np.asarray(points, dtype=float)
    dist, foot = project_points(
        data, curve.control_points, curve.weights, curve.knots, curve.degree, curve.closed
    )
    order = np.argsort(foot)
    return np.interp(u, foot[order], dist[order], period=1.0 if curve.closed else None)


def plot_curve(curve: Curve, points=None, ax=None, samples: int = 1000, cmap: str = "viridis"):
    """Data points, and the curve coloured by how far it is from the data, both ways
    (caller's units): the larger of the data's distance to it and its distance to the
    polyline through the data, so a loop or a spike between the points shows."""
    from matplotlib.collections import LineCollection

    u = np.linspace(0, 1, samples)
    pts = curve.evaluate(u)
    ax = _axes(ax)
    if points is not None:
        data = np.asarray(points, dtype=float)
        ax.plot(data[:, 0], data[:, 1], ".", color="0.6", ms=3, label="data")
        strays = distance_to_polyline(pts, data_polyline(data, curve.closed))
        dist = np.maximum(residual_along_curve(curve, data, u), strays)
        segs = np.stack([pts[:-1, :2], pts[1:, :2]], axis=1)
        lc = LineCollection(segs, cmap=cmap, linewidths=2)
        lc.set_array(0.5 * (dist[:-1] + dist[1:]))
        ax.add_collection(lc)
        ax.figure.colorbar(lc, ax=ax, label="distance between curve and data, both ways")
    else:
        ax.plot(pts[:, 0], pts[:, 1], "-", lw=2)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_title(
        f"degree {curve.degree}, {curve.n_ctrl} control points\n"
        f"max deviation {curve.max_deviation_pct_diag:.3g} % of diagonal, "
        f"mean deviation {curve.mean_deviation:.2e}, error {curve.error:.2e}",
        fontsize="medium",
    )
    return ax


def plot_control_polygon(curve: Curve, ax=None, true_control_points=None):
    """The fitted control polygon, beside the true one where it is known."""
    ax = _axes(ax)
    ctrl = curve.control_points
    loop = np.vstack([ctrl, ctrl[:1]]) if curve.closed else ctrl
    ax.plot(loop[:, 0], loop[:, 1], "o-", color="C1", ms=4, lw=1, label="fitted")
    if true_control_points is not None:
        tc = np.asarray(true_control_points, dtype=float)
        tl = np.vstack([tc, tc[:1]]) if curve.closed else tc
        ax.plot(tl[:, 0], tl[:, 1], "s--", color="C2", ms=4, lw=1, label="true")
    pts = curve.evaluate(np.linspace(0, 1, 400))
    ax.plot(pts[:, 0], pts[:, 1], "-", color="0.7", lw=1)
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_solution(curve: Curve, points=None, true_control_points=None, fig=None):
    """The paper's layout: curve over data on top, control polygons below.  Returns the Figure."""
    import matplotlib.pyplot as plt

    fig = fig if fig is not None else plt.figure(figsize=(6, 8))
    top, bottom = fig.subplots(2, 1)
    plot_curve(curve, points, ax=top)
    plot_control_polygon(curve, ax=bottom, true_control_points=true_control_points)
    fig.tight_layout()
    return fig


def plot_error_vs_cps(
    result: FitResult, ax=None, metric: str = "mean_deviation", highlight: Curve | None = None
):
    """A measure (log scale; default the two-sided mean deviation) against the control-point count, one line per degree; the
    ``highlight`` solution (e.g. the one drawn beside it) is ringed."""
    ax = _axes(ax)
    for k in sorted({c.degree for c in result.solutions}):
        cs = sorted((c for c in result.solutions if c.degree == k), key=lambda c: c.n_ctrl)
        ax.semilogy(
            [c.n_ctrl for c in cs], [getattr(c, metric) for c in cs], "o-", label=f"degree {k}"
        )
    if highlight is not None:
        ax.semilogy(
            [highlight.n_ctrl], [getattr(highlight, metric)], "o", ms=12, mfc="none", mec="k"
        )
    ax.set_xlabel("control points")
    ax.set_ylabel(f"{metric} (normalised frame)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    return ax


def plot_result(
    result: FitResult,
    curve: Curve | None = None,
    true_control_points=None,
    fig=None,
    title: str | None = None,
):
    """One figure per fit, in the paper's style: the data and ``curve`` (default: the best
    solution) coloured by its distance to the data, the fitted control polygon below it
    beside the true one where known, and the error against the control-point count of
    every degree on the right.  Returns the Figure."""
    import matplotlib.pyplot as plt

    curve = result.best if curve is None else curve
    fig = fig if fig is not None else plt.figure(figsize=(11, 8))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.3, 1))
    plot_curve(curve, result.points, ax=fig.add_subplot(grid[0, 0]))
    plot_control_polygon(
        curve, ax=fig.add_subplot(grid[1, 0]), true_control_points=true_control_points
    )
    plot_error_vs_cps(result, ax=fig.add_subplot(grid[:, 1]), highlight=curve)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
