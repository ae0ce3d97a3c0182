"""Conversions: knot insertion, clamped form, Bézier segments, scipy and geomdl.

Pure NumPy on the host; nothing here reads or writes files.  Rational curves are handled
in homogeneous coordinates ``(w P, w)``, so every conversion is exact for NURBS too.
"""

from __future__ import annotations

import numpy as np

from .knots import check_knots

__all__ = ["insert_knot", "clamped_form", "bezier_segments", "to_scipy", "from_scipy", "to_geomdl"]


def insert_knot(t: np.ndarray, k: int, cw: np.ndarray, u: float) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``u`` once into knots ``t`` (Boehm); ``cw`` (n, D+1) homogeneous control points."""
    s = int(np.searchsorted(t, u, side="right") - 1)
    s = min(s, len(t) - k - 2)
    out = np.empty((len(cw) + 1, cw.shape[1]))
    out[: s - k + 1] = cw[: s - k + 1]
    out[s + 1 :] = cw[s:]
    for i in range(s - k + 1, s + 1):
        denom = t[i + k] - t[i]
        alpha = 0.0 if denom == 0 else (u - t[i]) / denom
        out[i] = alpha * cw[i] + (1.0 - alpha) * cw[i - 1]
    return np.insert(t, s + 1, u), out


def _homogeneous(curve) -> np.ndarray:
    return np.c_[curve.control_points * curve.weights[:, None], curve.weights]


def _unwrap(curve) -> tuple[np.ndarray, np.ndarray]:
    """Knots and homogeneous control points of the full basis (closed: first k repeated)."""
    cw = _homogeneous(curve)
    if curve.closed:
        cw = np.vstack([cw, cw[: curve.degree]])
    return curve.knots.copy(), cw


def clamped_form(curve) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same curve on a clamped knot vector: ``(t, control_points, weights)``.

    Open curves are returned as they are.  A closed curve with ``n`` control points
    becomes ``n + degree`` clamped control points on the clamped knots with the same
    interior (the first and last coincide), which is the form CAD formats and geomdl
    expect.
    """
    t, cw = _unwrap(curve)
    k = curve.degree
    if curve.closed:
        for end in (0.0, 1.0):
            for _ in range(k):
                t, cw = insert_knot(t, k, cw, end)
        a = int(np.searchsorted(t, 0.0, side="left"))
        b = int(np.searchsorted(t, 1.0, side="right"))
        t = t[a:b]
        cw = cw[a : a + len(t) - k - 1]
        t[: k + 1], t[-k - 1 :] = 0.0, 1.0  # the clamped ends, free of rounding
    return t, cw[:, :-1] / cw[:, -1:], cw[:, -1].copy()


def bezier_segments(curve) -> list[tuple[np.ndarray, np.ndarray]]:
    """The curve as consecutive Bézier segments: a list of ``(control_points, weights)``,
    each with ``degree + 1`` rows, by inserting every interior knot up to multiplicity k."""
    t, ctrl, w = clamped_form(curve)
    k = curve.degree
    cw = np.c_[ctrl * w[:, None], w]
    for u in np.unique(t[k + 1 : -k - 1]):
        for _ in range(k - int(np.sum(t == u))):
            t, cw = insert_knot(t, k, cw, u)
    segments = []
    for j in range(0, len(cw) - 1, k):
        part = cw[j : j + k + 1]
        segments.append((part[:, :-1] / part[:, -1:], part[:, -1].copy()))
    return segments


def to_scipy(curve):
    """``scipy.interpolate.BSpline(t, c, k)`` with ``c`` of shape (n, D).

    Open curves map directly.  A closed curve keeps its periodic knots: ``c`` holds the
    ``n + degree`` unwrapped control points (the first ``degree`` repeated at the end) and
    ``extrapolate='periodic'``.  scipy has no rational B-spline, so rational curves raise.
    """
    from scipy.interpolate import BSpline

    if curve.rational:
        raise ValueError(
            "to_scipy: scipy's BSpline is not rational; use to_geomdl() or the DXF export for "
            "a NURBS curve"
        )
    t, cw = _unwrap(curve)
    return BSpline(t, cw[:, :-1], curve.degree, extrapolate="periodic" if curve.closed else False)


def from_scipy(spline, curve_cls):
    """A ``Curve`` from a ``BSpline`` on clamped knots over [0, 1], or on periodic knots
    (period 1) with the first ``k`` coefficients repeated at the end."""
    t = np.asarray(spline.t, dtype=np.float64)
    c = np.asarray(spline.c, dtype=np.float64)
    k = int(spline.k)
    if c.ndim != 2 or c.shape[1] not in (2, 3):
        raise ValueError(f"from_scipy: spline.c must have shape (n, 2) or (n, 3), got {c.shape}")
    n, m = len(c), len(c) - k
    if len(t) == n + k + 1 and _valid_knots(t, n, k, closed=False):
        return curve_cls(k, c, np.ones(n), t, closed=False)
    if (
        m >= k + 1
        and len(t) == m + 2 * k + 1
        and _valid_knots(t, m, k, closed=True)
        and np.allclose(c[m:], c[:k], atol=1e-12)
    ):
        return curve_cls(k, c[:m], np.ones(m), t, closed=True)
    raise ValueError(
        "from_scipy: only clamped knots on [0, 1], or periodic knots (period 1) with the first "
        "degree coefficients repeated at the end, describe a swarmcurves_jax Curve"
    )


def _valid_knots(t, n, k, closed) -> bool:
    try:
        check_knots(t, n, k, closed)
    except ValueError:
        return False
    return True


def to_geomdl(curve):
    """A ``geomdl`` curve (``NURBS.Curve`` if rational, else ``BSpline.Curve``) in clamped form."""
    try:
        from geomdl import NURBS
        from geomdl import BSpline as GBSpline
    except ImportError:
        raise ImportError("to_geomdl needs geomdl: pip install geomdl") from None
    t, ctrl, w = clamped_form(curve)
    out = NURBS.Curve() if curve.rational else GBSpline.Curve()
    out.degree = curve.degree
    out.ctrlpts = ctrl.tolist()
    if curve.rational:
        out.weights = w.tolist()
    out.knotvector = t.tolist()
    return out
