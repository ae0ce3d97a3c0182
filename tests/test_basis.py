"""Basis matrices: against scipy and a naive recursion, plus the B-spline properties."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.interpolate import BSpline

from swarmcurves_jax import clamped_uniform_knots, design_matrix, make_knots, periodic_uniform_knots
from swarmcurves_jax.basis import design_matrices
from swarmcurves_jax.projection import curve_derivatives


def naive(i, k, t, u):
    """Cox-de Boor by the textbook recursion, right end closed."""
    if k == 0:
        last = t[i + 1] == t[-1] and t[i] < t[i + 1]
        return 1.0 if (t[i] <= u < t[i + 1]) or (last and u == t[-1]) else 0.0
    a = 0.0 if t[i + k] == t[i] else (u - t[i]) / (t[i + k] - t[i]) * naive(i, k - 1, t, u)
    b = 0.0
    if t[i + k + 1] != t[i + 1]:
        b = (t[i + k + 1] - u) / (t[i + k + 1] - t[i + 1]) * naive(i + 1, k - 1, t, u)
    return a + b


degree_count = st.integers(1, 5).flatmap(lambda k: st.tuples(st.just(k), st.integers(k + 1, k + 9)))
params = st.lists(st.floats(0, 1), min_size=1, max_size=20)


def test_knot_vectors():
    np.testing.assert_array_equal(
        clamped_uniform_knots(6, 3), [0, 0, 0, 0, 1 / 3, 2 / 3, 1, 1, 1, 1]
    )
    np.testing.assert_allclose(periodic_uniform_knots(4, 2), (np.arange(9) - 2) / 4)
    with pytest.raises(ValueError, match="control-point count must be an integer >= degree"):
        clamped_uniform_knots(3, 3)
    with pytest.raises(ValueError, match="degree must be an integer >= 1"):
        make_knots(4, 0, False)


@given(degree_count, params)
def test_matches_scipy_and_naive(kn, u):
    k, n = kn
    t = clamped_uniform_knots(n, k)
    u = np.asarray(u)
    ours = design_matrix(u, t, k)
    ref = BSpline.design_matrix(u, t, k).toarray()
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    slow = np.array([[naive(i, k, t, x) for i in range(n)] for x in u[:3]])
    np.testing.assert_allclose(ours[:3], slow, atol=1e-12)


@given(degree_count, params, st.integers(1, 3))
def test_derivatives_match_scipy(kn, u, nu):
    k, n = kn
    t = clamped_uniform_knots(n, k)
    u = np.asarray(u)
    u = u[~np.isin(u, t)]  # one-sided at knots; compare away from them
    c = np.eye(n)
    ref = BSpline(t, c, k)(u, nu=nu) if len(u) else np.zeros((0, n))
    np.testing.assert_allclose(design_matrix(u, t, k, nu=nu), ref, atol=1e-8 * max(1, n) ** nu)


@given(degree_count, params, st.booleans(), st.integers(0, 6))
def test_design_matrices_equal_each_design_matrix(kn, u, closed, max_nu):
    """One recursion for all derivatives gives each one's numbers, bit for bit (past the
    degree: zeros), open and periodic."""
    k, n = kn
    t = make_knots(n, k, closed)
    u = np.asarray(u) * (0.999 if closed else 1.0)
    got = design_matrices(u, t, k, max_nu, closed=closed)
    assert len(got) == max_nu + 1
    for nu, b in enumerate(got):
        np.testing.assert_array_equal(b, design_matrix(u, t, k, nu=nu, closed=closed))
    if max_nu > k:
        assert not np.any(got[-1])


@given(degree_count, params, st.booleans())
def test_partition_of_unity_nonnegative_local_support(kn, u, closed):
    k, n = kn
    t = make_knots(n, k, closed)
    b = design_matrix(np.asarray(u), t, k, closed=closed)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(b >= -1e-15)
    assert np.all((b > 1e-15).sum(axis=1) <= k + 1)  # at most k+1 functions are non-zero


@given(degree_count)
def test_clamped_ends_interpolate(kn):
    k, n = kn
    ctrl = np.random.default_rng(n * 10 + k).uniform(-1, 1, (n, 2))
    b = design_matrix([0.0, 1.0], clamped_uniform_knots(n, k), k)
    np.testing.assert_allclose(b @ ctrl, ctrl[[0, -1]], atol=1e-12)


@given(degree_count)
def test_closed_seam_continuity(kn):
    k, n = kn
    t = periodic_uniform_knots(n, k)
    ctrl = np.random.default_rng(n * 10 + k).uniform(-1, 1, (n, 3))
    for nu in range(k):  # C^(k-1) at the seam
        start = design_matrix([0.0], t, k, nu=nu, closed=True) @ ctrl
        end = design_matrix([1.0], t, k, nu=nu, closed=True) @ ctrl
        np.testing.assert_allclose(start, end, atol=1e-9 * n**nu)
    # and the folded matrix is the periodic spline with the first k points repeated
    u = np.linspace(0, 1, 17)
    ext = BSpline(t, np.vstack([ctrl, ctrl[:k]]), k)(u)
    np.testing.assert_allclose(design_matrix(u, t, k, closed=True) @ ctrl, ext, atol=1e-12)


@given(degree_count, st.booleans(), st.floats(0.1, 10))
def test_equal_weights_is_nonrational_and_affine_invariance(kn, closed, w):
    k, n = kn
    rng = np.random.default_rng(7 * n + k)
    ctrl = rng.uniform(-1, 1, (n, 2))
    t = make_knots(n, k, closed)
    u = np.linspace(0, 1, 11)
    plain = design_matrix(u, t, k, closed=closed) @ ctrl
    rational = curve_derivatives(u, ctrl, np.full(n, w), t, k, closed, max_nu=0)[0]
    np.testing.assert_allclose(rational, plain, atol=1e-12)
    a, shift = rng.normal(size=(2, 2)), rng.normal(size=2)
    weights = rng.uniform(0.2, 3, n)
    moved = curve_derivatives(u, ctrl @ a.T + shift, weights, t, k, closed, max_nu=0)[0]
    base = curve_derivatives(u, ctrl, weights, t, k, closed, max_nu=0)[0]
    np.testing.assert_allclose(moved, base @ a.T + shift, atol=1e-10)


def test_rational_derivatives_match_finite_differences():
    rng = np.random.default_rng(3)
    ctrl, w = rng.uniform(-1, 1, (5, 2)), rng.uniform(0.3, 2, 5)
    t = make_knots(5, 3, False)
    u = np.array([0.2, 0.55, 0.8])
    c0, c1, c2 = curve_derivatives(u, ctrl, w, t, 3, False)
    h = 1e-5
    cp, cm = (curve_derivatives(u + s, ctrl, w, t, 3, False, max_nu=1) for s in (h, -h))
    np.testing.assert_allclose(c1, (cp[0] - cm[0]) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(c2, (cp[1] - cm[1]) / (2 * h), atol=1e-5)
