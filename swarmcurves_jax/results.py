"""``FitResult``: every solution of one ``fit`` call, and its summary table."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from .curves import Curve
from .measures import crossings

__all__ = ["FitResult", "Table", "DEFAULT_PCT_DIAG"]

#: :meth:`FitResult.sparsest`'s default tolerance: the largest deviation, as % of the
#: data's bounding-box diagonal.
DEFAULT_PCT_DIAG = 1.0

_COLUMNS = (
    ("degree", "d", "{:d}"),
    ("n_ctrl", "n", "{:d}"),
    ("mean_deviation", "mean_dev", "{:.3e}"),
    ("max_deviation", "max_dev", "{:.3e}"),
    ("max_deviation_units", "max_dev(units)", "{:.3g}"),
    ("error", "error", "{:.3e}"),
    ("max_error", "max_error", "{:.3e}"),
    ("error_pct_diag", "%diag", "{:.4f}"),
    ("bic", "bic", "{:.1f}"),
    ("iterations", "iters", "{:d}"),
)


class Table(list):
    """Rows (dicts) of a solution table; prints as aligned text, shows as Markdown."""

    def _lines(self, sep: str) -> list[str]:
        heads = [head for _, head, _ in _COLUMNS]
        cells = [[fmt.format(row[key]) for key, _, fmt in _COLUMNS] for row in self]
        widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, h in enumerate(heads)]
        line = lambda parts: sep.join(p.rjust(w) for p, w in zip(parts, widths))  # noqa: E731
        return [line(heads)] + [line(c) for c in cells]

    def __str__(self) -> str:
        return "\n".join(self._lines("  "))

    def _repr_markdown_(self) -> str:
        lines = self._lines(" | ")
        rule = "|" + "|".join("---:" for _ in _COLUMNS) + "|"
        return "\n".join([f"| {lines[0]} |", rule] + [f"| {ln} |" for ln in lines[1:]])


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """All solutions of a :func:`swarmcurves_jax.fit` call.

    Attributes
    ----------
    solutions : list of Curve
        One per (degree, n), ordered by degree then n.
    points : ndarray, shape (N, D)
        The points that were fitted, in the caller's frame (a closed input's repeated
        last point removed).
    center : ndarray, shape (D,)
    scale : float
        The normalisation: ``normalised = (points - center) / scale``.
    history : ndarray, shape (num_solutions, iterations_run)
        Best swarm fitness (normalised frame) after every iteration, per solution.
    stop_reason : str
        ``"iterations"`` (the limit was reached), ``"tol"`` (every swarm reached ``tol``)
        or ``"interrupted"`` (Ctrl-C; the best solutions found so far).
    seed : int or None
    wall_time : float
        Seconds spent in ``fit`` (compilation included).
    timings : dict
        Seconds per stage: ``"setup"`` (on the host: the checked points, least-squares
        seeds, boxes and bases) and ``"call"`` (from the start until the device's results
        are back: the swarm and the polish, queued together so that the polish compiles
        while the swarm runs); the rest of ``wall_time`` is the host's true-error
        projections.  With ``stage_timings=True`` the swarm is
        waited for before the polish is queued: ``"swarm"`` (from the start, compilation
        included) and, when refined, ``"refine"`` (its compilation included) instead of
        ``"call"``.
    batch : dict
        For :func:`swarmcurves_jax.fit_many`: ``"call"`` (which program call ran the
        curve), ``"curves"`` (how many real curves it ran), ``"bucket"`` (its padded
        point count), ``"points"`` (its real fitness points) and ``"devices"``.  Empty for
        :func:`swarmcurves_jax.fit`.
    """

    solutions: list[Curve]
    points: np.ndarray
    center: np.ndarray
    scale: float
    history: np.ndarray
    stop_reason: str
    seed: int | None
    wall_time: float
    timings: dict = dataclasses.field(default_factory=dict)
    batch: dict = dataclasses.field(default_factory=dict)

    @property
    def best(self) -> Curve:
        """The solution with the lowest two-sided ``mean_deviation`` of those that do not
        cross themselves where the data do not (of all, if every one does): a loop at a
        corner can have the lowest mean (:meth:`untangled`)."""
        return min(self.untangled() or self.solutions, key=_mean_deviation)

    def untangled(self) -> list[Curve]:
        """The solutions that cross themselves no more often than the polyline through
        the data (``curve.info["self_crossings"]``; noise can make the data cross
        themselves).  A curve that crosses itself more has looped where the data do not,
        often in a corner of sparse data, inside the room the fitness leaves a curve
        between the points: wrong there, whatever its mean.  The helpers pick from these
        (:meth:`sparsest` only from these)."""
        return self._untangled(self.solutions)

    def _untangled(self, curves: list[Curve]) -> list[Curve]:
        """Those of ``curves`` that cross themselves no more often than the data polyline."""
        return [c for c in curves if c.info.get("self_crossings", 0) <= self._data_crossings]

    @functools.cached_property
    def _data_crossings(self) -> int:
        """How often the polyline through the data crosses itself."""
        return crossings(self.points, self.solutions[0].closed)

    def sparsest(self, tolerance: float | None = None, *, pct_diag: float | None = None) -> Curve | None:
        """The solution with the fewest control points whose curve stays within a
        tolerance of the data and does not cross itself where they do not, or ``None``.

        Within: ``max_deviation`` (the Hausdorff distance between the curve and the
        polyline through the data, both ways) at most ``tolerance`` in the caller's units,
        or at most ``pct_diag`` % of the data's bounding-box diagonal (default 1 %).  A
        CAD tolerance is a bound on the largest deviation, as OpenCASCADE's approximation
        takes one.  A curve that crosses itself more often than the data polyline
        (``curve.info["self_crossings"]``) has looped, and a loop can stay within a coarse
        tolerance: it is passed over (:meth:`untangled`).  Ties on the count go to the lower
        ``mean_deviation``.
        """
        if tolerance is not None and pct_diag is not None:
            raise ValueError("give tolerance (caller's units) or pct_diag, not both")
        if tolerance is not None:
            if not tolerance >= 0:
                raise ValueError(f"tolerance must be a number >= 0, got {tolerance!r}")
            ok = [c for c in self.untangled() if c.max_deviation * self.scale <= tolerance]
        else:
            pct_diag = DEFAULT_PCT_DIAG if pct_diag is None else pct_diag
            if not pct_diag >= 0:
                raise ValueError(f"pct_diag must be a number >= 0, got {pct_diag!r}")
            ok = [c for c in self.untangled() if c.max_deviation_pct_diag <= pct_diag]
        return min(ok, key=lambda c: (c.n_ctrl, _mean_deviation(c))) if ok else None

    def knee(self, degree: int | None = None) -> Curve:
        """The knee of the deviation-versus-control-points curve of one degree (default:
        the best solution's): past it, more control points buy little.

        Kneedle's rule on ``log10(mean_deviation)`` against ``n``, both scaled to [0, 1]:
        the count furthest below the straight line from the fewest to the most control
        points; where that curve crosses itself and the data do not, the next count up that
        does not (down, if none above does; :meth:`untangled`).  Needs at least three
        counts of that degree.
        """
        curves = self._of_degree(self.best.degree if degree is None else degree)
        if len(curves) < 3:
            raise ValueError(
                f"knee needs at least 3 control-point counts of degree {curves[0].degree}, "
                f"got {len(curves)}"
            )
        n = np.array([c.n_ctrl for c in curves], dtype=np.float64)
        e = np.log10(np.maximum([_mean_deviation(c) for c in curves], 1e-300))
        x = (n - n[0]) / (n[-1] - n[0])
        span = e[0] - e[-1]
        y = (e - e[-1]) / span if span > 0 else np.zeros_like(e)
        below = (1.0 - x) - y  # the chord runs from (0, 1) to (1, 0)
        knee = curves[int(np.argmax(below))]
        untangled = self._untangled(curves)
        if not untangled or any(c is knee for c in untangled):
            return knee
        above = [c for c in untangled if c.n_ctrl > knee.n_ctrl]
        return above[0] if above else untangled[-1]

    def select(self, criterion: str = "bic", degree: int | None = None) -> Curve:
        """The solution with the lowest information criterion, ``"bic"`` or ``"aic"``.

        With Gaussian noise along the normal the orthogonal residuals give
        ``N log(RSS / N) + penalty * p``, ``p`` the curve's free numbers (``n D``, plus
        ``n - 1`` weights when rational; the foot-point parameters are the same for every
        solution and cancel), penalty ``log N`` (BIC) or 2 (AIC).  Both ways: ``RSS / N``
        is the points' mean squared distance to the curve plus the curve's arc-length mean
        squared distance to the data polyline, so a curve that leaves the data between
        the points scores as badly as one that misses them.  Meaningful on noisy data; on
        exact data RSS keeps falling to rounding and the choice is arbitrary.  ``degree``
        restricts the choice to one degree.  Curves that cross themselves where the data do
        not are passed over (unless every one does; :meth:`untangled`).
        """
        if criterion not in ("bic", "aic"):
            raise ValueError(f"criterion must be 'bic' or 'aic', got {criterion!r}")
        curves = self.solutions if degree is None else self._of_degree(degree)
        curves = self._untangled(curves) or curves
        return min(curves, key=lambda c: _criteria(c, len(self.points))[criterion])

    def _of_degree(self, degree: int) -> list[Curve]:
        curves = sorted((c for c in self.solutions if c.degree == degree), key=lambda c: c.n_ctrl)
        if not curves:
            have = sorted({c.degree for c in self.solutions})
            raise ValueError(f"degree must be one of {have}, got {degree!r}")
        return curves

    def __getitem__(self, key: tuple[int, int]) -> Curve:
        """``result[degree, n]``: the solution of that degree and control-point count."""
        try:
            degree, n = key
        except (TypeError, ValueError):
            raise KeyError(f"index a FitResult with (degree, n), got {key!r}") from None
        for curve in self.solutions:
            if curve.degree == degree and curve.n_ctrl == n:
                return curve
        have = ", ".join(f"({c.degree}, {c.n_ctrl})" for c in self.solutions)
        raise KeyError(f"no solution with degree {degree} and n={n}; have {have}")

    def __len__(self) -> int:
        return len(self.solutions)

    def __iter__(self):
        return iter(self.solutions)

    def table(self) -> Table:
        """One row per solution: degree, n_ctrl, the two-sided mean_deviation and
        max_deviation (normalised frame; max_deviation_units in the caller's, and as
        max_deviation_pct_diag), the one-sided error, max_error, rms_error,
        error_pct_diag, aic, bic (see :meth:`select`), iterations, ..."""
        rows = Table()
        for c in self.solutions:
            rows.append(
                {
                    "degree": c.degree,
                    "n_ctrl": c.n_ctrl,
                    "closed": c.closed,
                    "rational": c.rational,
                    "mean_deviation": c.mean_deviation,
                    "max_deviation": c.max_deviation,
                    "max_deviation_units": c.max_deviation * self.scale,
                    "max_deviation_pct_diag": c.max_deviation_pct_diag,
                    "error": c.error,
                    "max_error": c.max_error,
                    "rms_error": c.rms_error,
                    "error_pct_diag": c.error_pct_diag,
                    **_criteria(c, len(self.points)),
                    "iterations": int(c.info.get("iterations", 0)),
                }
            )
        return rows

    def __repr__(self) -> str:
        b = self.best
        return (
            f"FitResult({len(self.solutions)} solutions, {len(self.points)} points, "
            f"best: degree {b.degree}, n={b.n_ctrl}, mean_deviation={b.mean_deviation:.3g}, "
            f"max_deviation={b.max_deviation:.3g}; "
            f"stopped on {self.stop_reason})"
        )

    def normalised(self, points) -> np.ndarray:
        """``points`` (M, D) mapped into the normalised frame the errors are measured in."""
        return (np.asarray(points, dtype=np.float64) - self.center) / self.scale


def _mean_deviation(curve: Curve) -> float:
    """The ranking key of a solution: its two-sided mean (``nan`` ranks last)."""
    return math.inf if math.isnan(curve.mean_deviation) else curve.mean_deviation


def _criteria(curve: Curve, num_points: int) -> dict[str, float]:
    """AIC and BIC of a solution from its two-sided mean squared distance (see
    FitResult.select)."""
    p = curve.n_ctrl * curve.dim + (curve.n_ctrl - 1 if curve.rational else 0)
    strays = curve.info.get("rms_excursion", 0.0)
    rss = num_points * (curve.rms_error**2 + strays**2)
    fit_term = (
        num_points * math.log(max(rss / num_points, 1e-300)) if not math.isnan(rss) else math.inf
    )
    return {"aic": fit_term + 2 * p, "bic": fit_term + math.log(num_points) * p}
