"""Built-in point sets: the paper's analytic curves f1-f5 and random B-splines."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .basis import design_matrix
from .knots import make_knots

__all__ = [
    "ANALYTIC",
    "analytic_points",
    "random_bspline_points",
    "random_nurbs_points",
    "normal_noise",
    "remove_points",
    "circular_arc_points",
    "butterfly_nurbs",
    "outlines_path",
    "read_outlines",
    "SPACINGS",
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


def _random_ctrl_and_basis(n, degree, closed, num_points, dim, rng):
    """Control points U[-1, 1] and the design matrix at evenly spaced parameters."""
    ctrl = rng.uniform(-1, 1, (n, dim))
    u = np.linspace(0, 1, num_points, endpoint=not closed)
    return ctrl, design_matrix(u, make_knots(n, degree, closed), degree, closed=closed)


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
    rng = np.random.default_rng(seed)
    ctrl, b = _random_ctrl_and_basis(n, degree, closed, num_points, dim, rng)
    return b @ ctrl, ctrl


def random_nurbs_points(
    n: int = 6,
    degree: int = 3,
    closed: bool = False,
    num_points: int = 200,
    dim: int = 2,
    seed: int = 0,
    weight_range: tuple[float, float] = (0.3, 3.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of a random NURBS (control points U[-1, 1], weights U[weight_range]) at
    evenly spaced parameters.  Returns ``(points, control_points, weights)``."""
    rng = np.random.default_rng(seed)
    ctrl, b = _random_ctrl_and_basis(n, degree, closed, num_points, dim, rng)
    weights = rng.uniform(*weight_range, n)
    return (b @ (ctrl * weights[:, None])) / (b @ weights)[:, None], ctrl, weights


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


def remove_points(points, fraction: float, seed: int = 0, closed: bool = False) -> np.ndarray:
    """``points`` with ``round(fraction * N)`` of them removed at random, order kept: the
    sparse data of the paper's Fig. 7.  An open curve keeps both end points, so the data
    still span the whole curve."""
    points = np.asarray(points, dtype=np.float64)
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction must be in [0, 1), got {fraction!r}")
    n = len(points)
    keep = n - int(round(fraction * n))
    inner = np.arange(n) if closed else np.arange(1, n - 1)
    fixed = np.array([], dtype=int) if closed else np.array([0, n - 1])
    if keep < len(fixed) + 1:
        raise ValueError(f"fraction {fraction!r} would leave fewer than 3 of {n} points")
    rng = np.random.default_rng(seed)
    chosen = rng.choice(inner, size=keep - len(fixed), replace=False)
    return points[np.sort(np.concatenate([fixed, chosen]))]


def circular_arc_points(theta: float, num_points: int = 200) -> np.ndarray:
    """``num_points`` points of a unit-circle arc of angle ``theta`` (radians, < 2π),
    evenly spaced in angle and symmetric about the y axis (the paper's Fig. 5).  Its exact
    rational quadratic has middle weight ``cos(theta / 2)``."""
    if not 0.0 < theta < 2 * np.pi:
        raise ValueError(f"theta must be in (0, 2π), got {theta!r}")
    a = np.linspace(np.pi / 2 + theta / 2, np.pi / 2 - theta / 2, num_points)
    return np.c_[np.cos(a), np.sin(a)]


#: Right wing of the butterfly stand-in, from the top notch to the bottom one; the left wing
#: mirrors it.  Weights > 1 pull the wing tips out and the notches in.
_WING = np.array(
    [
        (0.0, 0.15, 3.0),
        (0.4, 1.0, 1.0),
        (1.25, 1.2, 2.0),
        (1.4, 0.4, 1.0),
        (0.3, 0.0, 2.5),
        (1.05, -0.5, 1.0),
        (0.95, -1.1, 1.6),
        (0.3, -0.85, 1.0),
        (0.0, -0.3, 2.0),
    ]
)


def butterfly_nurbs():
    """A closed butterfly-shaped cubic NURBS (16 control points, uniform periodic knots).

    A **stand-in** for the paper's "Butterfly" (Fig. 4), whose coordinates are not
    published: two mirrored wings with rounded tips, pinched at the body by two notches.
    """
    from .curves import Curve

    left = _WING[-2:0:-1] * np.array([-1.0, 1.0, 1.0])
    rows = np.vstack([_WING, left])
    return Curve(
        3, rows[:, :2], rows[:, 2], make_knots(len(rows), 3, True), closed=True, rational=True
    )


def outlines_path(data_dir=None) -> Path:
    """Where the benchmark outlines are: ``data_dir/outlines/outlines.npz``, with
    ``data_dir`` defaulting to ``$SWARMCURVES_DATA``, else the first ``shared/data`` found
    beside the working folder or beside this repository (the data are read at run
    time, never copied).  Raises ``FileNotFoundError`` naming the folders tried."""
    if data_dir is not None or os.environ.get("SWARMCURVES_DATA"):
        roots = [Path(data_dir if data_dir is not None else os.environ["SWARMCURVES_DATA"])]
    else:
        roots = [
            Path("..") / "shared" / "data",
            Path(__file__).resolve().parents[2] / "shared" / "data",
        ]
    for root in roots:
        if (root / "outlines" / "outlines.npz").is_file():
            return root / "outlines" / "outlines.npz"
    tried = ", ".join(f"'{r}'" for r in roots)
    raise FileNotFoundError(f"data_dir: no outlines/outlines.npz under {tried}")


#: How the benchmark outlines' points are spaced along their curves: evenly by arc length,
#: or at sorted random arc-length positions (open curves keep both ends).
SPACINGS = {"even": "points", "random": "points_random"}


def read_outlines(data_dir=None, spacing: str = "even") -> dict[str, dict[str, np.ndarray]]:
    """The benchmark outlines by name: ``{"points": (200, 2), "truth": (5000, 2) dense
    samples of the exact curve (``None`` if the file has none), "closed": bool}`` (see
    :func:`outlines_path`), the points spaced as ``spacing`` says (:data:`SPACINGS`)."""
    if spacing not in SPACINGS:
        raise ValueError(f"spacing must be one of {', '.join(SPACINGS)}, got {spacing!r}")
    path = outlines_path(data_dir)
    with np.load(path) as npz:
        names = sorted(k[: -len("_closed")] for k in npz.files if k.endswith("_closed"))
        missing = [n for n in names if f"{n}_{SPACINGS[spacing]}" not in npz.files]
        if missing:
            raise ValueError(
                f"spacing: {path} has no {spacing}-spaced points "
                f"('{missing[0]}_{SPACINGS[spacing]}') for {', '.join(missing)}"
            )
        return {
            name: {
                "points": np.asarray(npz[f"{name}_{SPACINGS[spacing]}"], dtype=np.float64),
                "truth": (
                    np.asarray(npz[f"{name}_truth"], dtype=np.float64)
                    if f"{name}_truth" in npz.files
                    else None
                ),
                "closed": bool(npz[f"{name}_closed"]),
            }
            for name in names
        }


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
