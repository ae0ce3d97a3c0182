"""Built-in point sets: the paper's analytic curves (SPEC §4) and random B-splines."""

from __future__ import annotations

import numpy as np

from .basis import design_matrix
from .knots import make_knots

__all__ = [
    "ANALYTIC",
    "analytic_points",
    "random_bspline_points",
    "normal_noise",
    "builtin",
    "BUILTIN_NAMES",
]

#: name -> (function of x, x range); each curve is (x, f(x)) sampled evenly in x.
ANALYTIC = {
    "f1": (lambda x: 10 * x / (1 + 100 * x**2), (-2.0, 2.0)),
    "f2": (lambda x: np.exp(-0.5 * x) * np.sin(5 * x), (0.0, 4 * np.pi)),
    "f3": (
        lambda x: 100 / (55 * np.exp(np.abs(10 * x - 5))) + (10 * x - 5) ** 5 / 27500 - 0.8,
        (0.0, 1.0),
    ),
    "f4": (lambda x: 0.5 * np.sin(x) + np.exp(-30 * x**2), (-2.0, 2.0)),
    "f5": (lambda x: 0.5 * np.sin(2 * x) + np.exp(-36 * x**2) + 1, (-2.0, 2.0)),
}


def analytic_points(name: str, num_points: int = 200) -> np.ndarray:
    """``num_points`` points of the analytic curve ``name`` (f1..f5), evenly spaced in x."""
    if name not in ANALYTIC:
        raise ValueError(f"analytic curve must be one of {', '.join(ANALYTIC)}, got {name!r}")
    fn, (a, b) = ANALYTIC[name]
    x = np.linspace(a, b, num_points)
    return np.c_[x, fn(x)]


def random_bspline_points(
    n: int = 6,
    degree: int = 3,
    closed: bool = False,
    num_points: int = 200,
    dim: int = 2,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Points of a random B-spline (control points U[-1, 1]) at evenly spaced parameters.

    Returns ``(points, control_points)``.
    """
    ctrl = np.random.default_rng(seed).uniform(-1, 1, (n, dim))
    u = np.linspace(0, 1, num_points, endpoint=not closed)
    return design_matrix(u, make_knots(n, degree, closed), degree, closed=closed) @ ctrl, ctrl


def normal_noise(points, sigma: float, seed: int = 0, closed: bool = False) -> np.ndarray:
    """``points`` moved by Gaussian offsets (standard deviation ``sigma``) along the curve
    normal, the noise model of the paper's Fig. 7 (2D; normals from central differences)."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got {points.shape}")
    if closed:
        tangent = np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0)
    else:
        tangent = np.gradient(points, axis=0)
    normal = np.c_[-tangent[:, 1], tangent[:, 0]]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offsets = np.random.default_rng(seed).normal(0.0, sigma, len(points))
    return points + offsets[:, None] * normal


BUILTIN_NAMES = (*ANALYTIC, "random_open", "random_closed")


def builtin(name: str, num_points: int = 200) -> tuple[np.ndarray, bool]:
    """A built-in dataset by name: ``(points, closed)``."""
    if name in ANALYTIC:
        return analytic_points(name, num_points), False
    if name in ("random_open", "random_closed"):
        closed = name == "random_closed"
        pts, _ = random_bspline_points(8 if closed else 6, closed=closed, num_points=num_points)
        return pts, closed
    raise ValueError(f"dataset must be one of {', '.join(BUILTIN_NAMES)}, got {name!r}")
