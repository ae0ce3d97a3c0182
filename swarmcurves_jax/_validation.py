"""Checks at the public boundary: every message names the argument and what was expected."""

from __future__ import annotations

import difflib
import numbers
from collections.abc import Iterable

import numpy as np


class UnknownArgumentError(TypeError, ValueError):
    """An unknown keyword argument: a ``ValueError`` like every input error, and the
    ``TypeError`` Python raises for one."""


def check_no_unknown(unknown: dict, known, caller: str = "fit") -> None:
    if unknown:
        name = sorted(unknown)[0]
        near = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean '{near[0]}'?)" if near else ""
        raise UnknownArgumentError(f"{caller}() got an unexpected keyword argument '{name}'{hint}")


def check_bool(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_points(points) -> np.ndarray:
    """``points`` as a finite float64 array of shape (N, 2) or (N, 3)."""
    try:
        arr = np.asarray(points)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"points must be an array-like of shape (N, 2) or (N, 3): {exc}") from None
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        if np.issubdtype(arr.dtype, np.complexfloating):
            raise ValueError("points must be real numbers, got a complex array")
        raise ValueError(f"points must be numbers of shape (N, 2) or (N, 3), got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        hint = ""
        if arr.ndim == 2 and arr.shape[0] in (2, 3) and arr.shape[1] > 3:
            hint = f"; it looks transposed (D, N): pass points.T, of shape {arr.shape[::-1]}"
        raise ValueError(
            f"points must have shape (N, 2) or (N, 3), one point per row, got {arr.shape}{hint}"
        )
    if arr.shape[0] == 0:
        raise ValueError("points is empty: give at least as many points as control points")
    arr = arr.astype(np.float64)
    bad = ~np.all(np.isfinite(arr), axis=1)
    if np.any(bad):
        rows = np.flatnonzero(bad)
        listed = ", ".join(str(r) for r in rows[:5]) + (", ..." if len(rows) > 5 else "")
        raise ValueError(f"points must be finite; NaN or inf in row(s) {listed}")
    return arr


def _int_list(value, name: str) -> list[int]:
    items = [value] if isinstance(value, numbers.Integral) else value
    if isinstance(items, (str, bytes)) or not isinstance(items, Iterable):
        raise ValueError(f"{name} must be an int or an iterable of ints, got {value!r}")
    out = []
    for item in items:
        if isinstance(item, bool) or not isinstance(item, numbers.Integral):
            raise ValueError(f"{name} must hold integers, got {item!r}")
        out.append(int(item))
    if not out:
        raise ValueError(f"{name} must not be empty")
    if len(set(out)) != len(out):
        raise ValueError(f"{name} must not repeat a value, got {out}")
    return out


def check_pairs(cps, degrees, closed: bool) -> list[tuple[int, int]]:
    """Every (degree, n) pair, ordered by degree then n, each valid."""
    ns = _int_list(cps, "cps")
    ks = _int_list(degrees, "degrees")
    for k in ks:
        if k < 1:
            raise ValueError(f"degrees must be >= 1 (1 is a polygon), got {k}")
    for n in ns:
        if n < 2:
            raise ValueError(f"cps must be >= 2, got {n}")
    pairs = sorted((k, n) for k in ks for n in ns)
    for k, n in pairs:
        if n < k + 1:
            kind = "a closed" if closed else "an open"
            raise ValueError(
                f"cps: {n} control points are too few for {kind} curve of degree {k} "
                f"(needs >= {k + 1}); use cps >= {k + 1} or a lower degree"
            )
    return pairs


def check_positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def check_tol(tol) -> float | None:
    if tol is None:
        return None
    if (
        isinstance(tol, bool)
        or not isinstance(tol, numbers.Real)
        or not np.isfinite(tol)
        or tol < 0
    ):
        raise ValueError(f"tol must be None or a finite number >= 0, got {tol!r}")
    return float(tol)


def check_weight_bounds(bounds) -> tuple[float, float]:
    try:
        lo, hi = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"weight_bounds must be a pair (low, high), got {bounds!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"weight_bounds must satisfy 0 < low < high (finite), got ({lo}, {hi})")
    return lo, hi


def check_params(params):
    """A ``PSOParams`` whose fields are finite (``patience`` may be inf) and sensible."""
    from .pso import PSOParams

    if not isinstance(params, PSOParams):
        raise ValueError(f"params must be a PSOParams, got {type(params).__name__}")
    for name in ("inertia", "cognitive", "social", "v_max"):
        value = np.asarray(getattr(params, name), dtype=float)
        if value.shape != () or not np.isfinite(value):
            raise ValueError(
                f"params.{name} must be a finite number, got {getattr(params, name)!r}"
            )
    if not float(params.v_max) > 0:
        raise ValueError(f"params.v_max must be > 0, got {params.v_max!r}")
    patience = np.asarray(params.patience, dtype=float)
    if patience.shape != () or np.isnan(patience) or patience < 1:
        raise ValueError(
            f"params.patience must be >= 1 (inf: never restart), got {params.patience!r}"
        )
    return params
