"""``FitResult``: every solution of one ``fit`` call, and its summary table."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .curves import Curve

__all__ = ["FitResult", "Table"]

_COLUMNS = (
    ("degree", "d", "{:d}"),
    ("n_ctrl", "n", "{:d}"),
    ("error", "error", "{:.3e}"),
    ("max_error", "max_error", "{:.3e}"),
    ("rms_error", "rms_error", "{:.3e}"),
    ("error_pct_diag", "%diag", "{:.4f}"),
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
        The normalisation of SPEC §1: ``normalised = (points - center) / scale``.
    history : ndarray, shape (num_solutions, iterations_run)
        Best swarm fitness (normalised frame) after every iteration, per solution.
    stop_reason : str
        ``"iterations"`` (the limit was reached), ``"tol"`` (every swarm reached ``tol``)
        or ``"interrupted"`` (Ctrl-C; the best solutions found so far).
    seed : int or None
    wall_time : float
        Seconds spent in ``fit`` (compilation included).
    """

    solutions: list[Curve]
    points: np.ndarray
    center: np.ndarray
    scale: float
    history: np.ndarray
    stop_reason: str
    seed: int | None
    wall_time: float

    @property
    def best(self) -> Curve:
        """The solution with the lowest ``error``."""
        return min(self.solutions, key=lambda c: math.inf if math.isnan(c.error) else c.error)

    def sparsest(self, max_error_pct_diag: float = 0.35) -> Curve | None:
        """The solution with the fewest control points whose ``error_pct_diag`` is within
        ``max_error_pct_diag`` (ties: the lower error); ``None`` if none is.  The default
        0.35 % is the paper's typical error."""
        ok = [c for c in self.solutions if c.error_pct_diag <= max_error_pct_diag]
        return min(ok, key=lambda c: (c.n_ctrl, c.error)) if ok else None

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
        """One row per solution: degree, n_ctrl, error, max_error, rms_error, ..."""
        rows = Table()
        for c in self.solutions:
            rows.append(
                {
                    "degree": c.degree,
                    "n_ctrl": c.n_ctrl,
                    "closed": c.closed,
                    "rational": c.rational,
                    "error": c.error,
                    "max_error": c.max_error,
                    "rms_error": c.rms_error,
                    "error_pct_diag": c.error_pct_diag,
                    "iterations": int(c.info.get("iterations", 0)),
                }
            )
        return rows

    def __repr__(self) -> str:
        b = self.best
        return (
            f"FitResult({len(self.solutions)} solutions, {len(self.points)} points, "
            f"best: degree {b.degree}, n={b.n_ctrl}, error={b.error:.3g}; "
            f"stopped on {self.stop_reason})"
        )

    def normalised(self, points) -> np.ndarray:
        """``points`` (M, D) mapped into the normalised frame the errors are measured in."""
        return (np.asarray(points, dtype=np.float64) - self.center) / self.scale
