"""B-spline basis (design) matrices and their derivatives, in float64 NumPy.

These run on the host, once per (degree, count, knot type): the swarm receives them as
precomputed arrays, and returned curves evaluate through them.  The recursion is
Cox–de Boor over the whole knot vector, vectorised over the parameters, with ``0/0 := 0``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["design_matrix", "design_matrices", "find_span", "basis_functions", "derivative_bases"]


def find_span(u: np.ndarray, t: np.ndarray, k: int) -> np.ndarray:
    """Index ``s`` with ``t[s] <= u < t[s+1]``, kept in ``[k, len(t)-k-2]``.

    The right end of the domain belongs to the last non-empty span, so ``u = t[-k-1]``
    evaluates like scipy's ``BSpline`` (left-continuous there).
    """
    num_basis = len(t) - k - 1
    s = np.searchsorted(t, u, side="right") - 1
    return np.clip(s, k, num_basis - 1)


def _safe_inv(d, xp=np):
    """``1 / d`` where ``d > 0``, else 0 (the recursion's ``0/0 := 0``); gradient-safe."""
    ok = d > 0
    return xp.where(ok, 1.0 / xp.where(ok, d, 1.0), 0.0)


def basis_functions(u, t, p: int, nu: int, span, xp=np):
    """``nu``-th derivative of all degree-``p`` basis functions on ``t``: (len(u), len(t)-p-1).

    ``span[i]`` is the knot index ``s`` with ``t[s] <= u[i] < t[s+1]``.  Written against an
    array module ``xp`` (NumPy, or ``jax.numpy`` where the knots themselves are optimised
    and must carry gradients).
    """
    m = t.shape[0]
    if nu > p:
        return xp.zeros((u.shape[0], m - p - 1), dtype=u.dtype)
    return _differentiate(_values(u, t, span, xp, {p - nu})[p - nu], t, p, nu, xp)


def derivative_bases(u, t, p: int, max_nu: int, span, xp=np) -> list:
    """``[basis_functions(u, t, p, nu, span) for nu in range(max_nu + 1)]`` from one
    Cox–de Boor pass (each derivative starts from a lower degree's values, which the pass
    makes on its way): the same numbers, for about half the work at ``max_nu`` 2."""
    m = t.shape[0]
    values = _values(u, t, span, xp, {p - nu for nu in range(min(max_nu, p) + 1)})
    return [
        _differentiate(values[p - nu], t, p, nu, xp)
        if nu <= p
        else xp.zeros((u.shape[0], m - p - 1), dtype=u.dtype)
        for nu in range(max_nu + 1)
    ]


def _values(u, t, span, xp, keep: set) -> dict:
    """The basis functions' values at the degrees in ``keep``, by degree."""
    m = t.shape[0]
    basis = (span[:, None] == xp.arange(m - 1)[None, :]).astype(u.dtype)
    out = {0: basis} if 0 in keep else {}
    uu, tt = u[:, None], t[None, :]
    for q in range(1, max(keep) + 1):
        left = (uu - tt[:, : m - 1 - q]) * _safe_inv(tt[:, q : m - 1] - tt[:, : m - 1 - q], xp)
        right = (tt[:, q + 1 :] - uu) * _safe_inv(tt[:, q + 1 :] - tt[:, 1 : m - q], xp)
        basis = left * basis[:, :-1] + right * basis[:, 1:]
        if q in keep:
            out[q] = basis
    return out


def _differentiate(lower, t, p: int, nu: int, xp):
    """The ``nu``-th derivative of the degree-``p`` basis from the degree-``(p - nu)``
    values ``lower``: ``nu`` steps of the derivative recursion."""
    m = t.shape[0]
    for q in range(p - nu + 1, p + 1):
        a = q * _safe_inv(t[q : m - 1] - t[: m - 1 - q], xp)[None, :]
        b = q * _safe_inv(t[q + 1 :] - t[1 : m - q], xp)[None, :]
        lower = lower[:, :-1] * a - lower[:, 1:] * b
    return lower


def design_matrix(
    u: np.ndarray, t: np.ndarray, k: int, *, nu: int = 0, closed: bool = False
) -> np.ndarray:
    """Matrix ``B`` with ``C^(nu)(u) = B @ ctrl`` for control points ``ctrl``.

    Parameters
    ----------
    u : array_like, shape (m,)
        Curve parameters inside the knot domain ``[t[k], t[-k-1]]``.
    t : ndarray, shape (n + k + 1,) open, or (n + 2k + 1,) closed
        Knot vector (see :mod:`swarmcurves_jax.knots`).
    k : int
        Degree.
    nu : int, optional
        Derivative order (0 for values).
    closed : bool, optional
        If true, ``t`` is periodic and the last ``k`` basis functions are folded onto
        the first ``k`` so that ``B`` has one column per distinct control point.

    Returns
    -------
    B : ndarray, shape (m, n)
    """
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    t = np.asarray(t, dtype=np.float64)
    return _fold(basis_functions(u, t, k, nu, find_span(u, t, k)), k, closed)


def design_matrices(
    u: np.ndarray, t: np.ndarray, k: int, max_nu: int, *, closed=False, span=None
) -> list:
    """``[design_matrix(u, t, k, nu=nu, closed=closed) for nu in range(max_nu + 1)]``, the
    same numbers from one recursion (:func:`derivative_bases`): a curve's point and
    derivatives, as the host's projections need them at every Newton step.  ``span``:
    each parameter's knot span (default :func:`find_span`), to evaluate a span's
    polynomial at its right end, where ``find_span`` gives the next span."""
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    t = np.asarray(t, dtype=np.float64)
    span = find_span(u, t, k) if span is None else span
    return [_fold(b, k, closed) for b in derivative_bases(u, t, k, max_nu, span)]


def _fold(basis: np.ndarray, k: int, closed: bool) -> np.ndarray:
    """A periodic basis's last ``k`` columns folded onto its first ``k``."""
    if closed:
        n = basis.shape[1] - k
        basis[:, :k] += basis[:, n:]
        basis = basis[:, :n]
    return basis
