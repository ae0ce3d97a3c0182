"""B-spline basis (design) matrices and their derivatives, in float64 NumPy.

These run on the host, once per (degree, count, knot type): the swarm receives them as
precomputed arrays, and returned curves evaluate through them.  The recursion is
Cox–de Boor over the whole knot vector, vectorised over the parameters, with ``0/0 := 0``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["design_matrix", "find_span", "basis_functions"]


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
    if nu > 0:
        lower = basis_functions(u, t, p - 1, nu - 1, span, xp)
        a = p * _safe_inv(t[p : m - 1] - t[: m - 1 - p], xp)[None, :]
        b = p * _safe_inv(t[p + 1 :] - t[1 : m - p], xp)[None, :]
        return lower[:, :-1] * a - lower[:, 1:] * b
    basis = (span[:, None] == xp.arange(m - 1)[None, :]).astype(u.dtype)
    uu, tt = u[:, None], t[None, :]
    for q in range(1, p + 1):
        left = (uu - tt[:, : m - 1 - q]) * _safe_inv(tt[:, q : m - 1] - tt[:, : m - 1 - q], xp)
        right = (tt[:, q + 1 :] - uu) * _safe_inv(tt[:, q + 1 :] - tt[:, 1 : m - q], xp)
        basis = left * basis[:, :-1] + right * basis[:, 1:]
    return basis


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
    span = find_span(u, t, k)
    basis = basis_functions(u, t, k, nu, span)
    if closed:
        n = basis.shape[1] - k
        basis[:, :k] += basis[:, n:]
        basis = basis[:, :n]
    return basis
