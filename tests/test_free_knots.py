"""Free knots: the knot structure, the JAX basis on moved knots, fit(free_knots=True)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from swarmcurves_jax import Curve, design_matrix, fit
from swarmcurves_jax.datasets import analytic_points
from swarmcurves_jax.fitness import foot_samples, point_distances
from swarmcurves_jax.prepare import normalise
from swarmcurves_jax.span_basis import free_knot_basis
from swarmcurves_jax.projection import project_points
from swarmcurves_jax.knots import (
    MIN_SPAN_FRACTION,
    check_knots,
    knots_from_widths,
    span_widths,
)
from swarmcurves_jax.refine import Problem, levenberg_marquardt


@given(
    logits=st.lists(st.floats(-3, 3), min_size=1, max_size=12),
    k=st.integers(1, 5),
    closed=st.booleans(),
)
def test_any_logits_give_a_valid_sorted_knot_vector(logits, k, closed):
    logits = np.array(logits)
    spans = len(logits)
    n = spans if closed else spans + k
    if closed and n < k + 1:
        return
    w = span_widths(logits, spans)
    assert np.all(w >= MIN_SPAN_FRACTION / spans - 1e-15)
    assert abs(w.sum() - 1) <= 1e-12
    t = knots_from_widths(w, spans, k, closed)
    check_knots(t, n, k, closed)  # raises if not valid


@pytest.mark.parametrize("closed,k,n", [(False, 3, 8), (True, 3, 8), (False, 2, 6), (True, 5, 9)])
def test_jax_basis_on_moved_knots_matches_the_host_basis(closed, k, n):
    """The span polynomials built in JAX from knot logits are the curve on those knots,
    on each span and (through the jump rows) across into its neighbours."""
    spans = n if closed else n - k
    logits = np.random.default_rng(n).uniform(-2, 2, spans)
    basis = jax.jit(free_knot_basis, static_argnums=(2, 3, 4, 5))  # one program, not op by op
    got = basis(jnp.asarray(logits, jnp.float32), spans, k, closed, 4 * spans, n)
    w = span_widths(logits, spans)
    t = knots_from_widths(w, spans, k, closed)
    ctrl = np.random.default_rng(k).uniform(-1, 1, (n, 2))
    coef = np.einsum("srn,nc->src", np.asarray(got.table), ctrl)
    breaks = np.r_[0.0, np.cumsum(w)]
    for s in range(spans):
        tau = np.linspace(float(got.lo[s]), float(got.hi[s]), 17)
        poly = sum(coef[s, p] * tau[:, None] ** p for p in range(k + 1))
        poly += coef[s, k + 1] * (np.maximum(tau - 1, 0) ** k)[:, None]
        poly += coef[s, k + 2] * (np.minimum(tau, 0) ** k)[:, None]
        u = breaks[s] + tau * w[s]  # span s's units also past its ends
        want = design_matrix(u % 1.0 if closed else u, t, k, closed=closed) @ ctrl
        np.testing.assert_allclose(poly, want, atol=1e-4 * max(1.0, np.abs(want).max()))  # float32
    # the search samples: 4 per span at the same fractions of each span
    frac = (np.arange(4 * spans) % 4 + 0.5) / 4
    u = breaks[np.arange(4 * spans) // 4] + frac * w[np.arange(4 * spans) // 4]
    np.testing.assert_allclose(
        np.asarray(got.sample_value), design_matrix(u, t, k, closed=closed), atol=1e-5
    )


def _non_uniform_cubic():
    t = np.r_[0, 0, 0, 0, 0.1, 0.2, 0.3, 1, 1, 1, 1.0]
    ctrl = np.random.default_rng(3).uniform(-1, 1, (7, 2))
    return design_matrix(np.linspace(0, 1, 200), t, 3) @ ctrl


def test_refinement_moves_knots_towards_the_true_ones():
    """Gradient through the JAX basis: from uniform knots and the true control points,
    Levenberg-Marquardt over control points and knot logits lowers the fitness 50-fold."""
    pts = jnp.asarray(_non_uniform_cubic(), jnp.float32)
    ctrl = np.random.default_rng(3).uniform(-1, 1, (7, 2))

    def parts(x):
        return x[:14].reshape(7, 2), free_knot_basis(x[14:], 4, 3, False, 64, 7)

    def residuals(x, foot):
        return point_distances(*parts(x)[:1], None, parts(x)[1], pts, foot, degree=3)

    def search(x):
        return foot_samples(parts(x)[0], None, parts(x)[1], pts)

    x0 = jnp.asarray(np.r_[ctrl.ravel(), np.zeros(4)], jnp.float32)
    free = jnp.ones(18).at[jnp.array([0, 1, 12, 13])].set(0.0)
    inf = jnp.full(18, jnp.inf)
    f0 = float(jax.jit(lambda x: jnp.mean(residuals(x, search(x))))(x0))
    problem = Problem(residuals, search, free, -inf, inf)
    x, f, _, _ = jax.jit(lambda x0: levenberg_marquardt(problem, x0))(x0)
    assert float(f) < f0 / 50  # measured: 1.4e-2 -> 1.9e-4
    first = span_widths(np.asarray(x[14:], np.float64), 4)[0]
    assert first < 0.2  # measured 0.17: the true first span is 0.1, the uniform one 0.25


def test_free_knots_beat_uniform_knots_where_curvature_is_uneven():
    """f5's narrow bump: knots seeded where the data turn, then moved by swarm and
    refinement, give a several-fold lower error than uniform knots at equal counts (at 9
    control points and 200 iterations: the free-knot program the open-curve tests below
    share)."""
    pts = analytic_points("f5")
    fixed = fit(pts, cps=[9], iterations=200)
    free = fit(pts, cps=[9], iterations=200, free_knots=True)
    assert free[3, 9].error < fixed[3, 9].error / 2  # measured: 11.6x
    assert np.min(np.diff(free[3, 9].knots[4:-4])) < 0.5 / 6  # knots gathered: 0.048


def test_free_knot_curves_round_trip_and_export(tmp_path):
    # the program of the open reversed-input test below
    curve = fit(_non_uniform_cubic(), cps=[9], iterations=200, free_knots=True)[3, 9]
    again = Curve.from_dict(curve.to_dict())
    np.testing.assert_array_equal(again.knots, curve.knots)
    u = np.linspace(0, 1, 50)
    np.testing.assert_allclose(curve.to_scipy()(u), curve.evaluate(u), atol=1e-12)
    np.testing.assert_allclose(Curve.from_scipy(curve.to_scipy()).evaluate(u), curve.evaluate(u))


@pytest.mark.parametrize("closed", [False, True])
def test_a_reversed_input_returns_the_curve_that_was_measured(closed):
    """Input whose reverse the swarm fits (it sees the lexicographically first order): the
    curve comes back traversed like the input, so on free knots the knot vector is
    mirrored with the control points.  The returned curve's own distances to the data
    must be the ones it reports, and its foot parameters must rise along the input.  A
    closed curve's knots stay periodic: its clamped form is the same curve."""
    if closed:
        theta = np.linspace(0, 2 * np.pi, 200, endpoint=False)
        pts = np.c_[np.cos(theta) * (1 + 0.3 * np.cos(3 * theta)), np.sin(theta)]
    else:
        pts = _non_uniform_cubic()
    pts = pts[::-1] if tuple(pts[0]) < tuple(pts[-1]) else pts  # the swarm fits the reverse
    curve = fit(pts, cps=[9], closed=closed, iterations=200, free_knots=True)[3, 9]
    check_knots(curve.knots, 9, 3, closed)
    dist, foot = project_points(pts, curve.control_points, curve.weights, curve.knots, 3, closed)
    scale = normalise(pts)[2]  # curve.error is in the normalised frame
    np.testing.assert_allclose(dist.mean() / scale, curve.error, rtol=1e-6)
    assert np.sum(np.sign((np.diff(foot) + 0.5) % 1.0 - 0.5 if closed else np.diff(foot))) > 0
    if closed:
        u = np.linspace(0, 1, 40)
        np.testing.assert_allclose(curve.to_clamped().evaluate(u), curve.evaluate(u), atol=1e-9)
        assert curve.error < 2e-2


def test_curve_rejects_knots_of_the_wrong_structure():
    with pytest.raises(ValueError, match="knots must be non-decreasing"):
        Curve(3, np.zeros((5, 2)), np.ones(5), [0, 0, 0, 0, 0.6, 0.4, 1, 1, 1])
    with pytest.raises(ValueError, match=r"knots of an open curve must start with 4 zeros"):
        Curve(3, np.zeros((5, 2)), np.ones(5), [0, 0, 0, 0.1, 0.5, 1, 1, 1, 1])
    with pytest.raises(ValueError, match=r"knots must be 9 finite numbers"):
        Curve(3, np.zeros((5, 2)), np.ones(5), [0, 0, 0, 0, 1, 1, 1, 1])


@given(
    logits=st.lists(st.floats(-3, 3), min_size=14, max_size=14),
    n=st.integers(4, 15),
    k=st.integers(1, 3),
    seed=st.integers(0, 2**16),
)
def test_a_positions_open_knots_end_exactly_at_one_and_project_exactly(logits, n, k, seed):
    """The widths sum to 1 only to rounding; the host's knot vector still ends exactly at
    1 (an end of 1 + 2e-16 once left the last span out of the domain the measures sample,
    and its points were projected onto the wrong span).  Projections then agree with a
    brute-force sampling of the curve."""
    from scipy.interpolate import BSpline

    from swarmcurves_jax.layout import Layout, knot_vector

    assume(n > k)
    space = Layout(n_pad=15, dim=2, rational=False, num_knots=15 - k, closed=False)
    rng = np.random.default_rng(seed)
    q = np.concatenate([rng.uniform(-1, 1, 30), logits[: 15 - k]])
    t = knot_vector(q, k, n, space)
    check_knots(t, n, k, False)
    assert np.all(t[n:] == 1.0) and np.all(t[: k + 1] == 0.0)
    ctrl = q[:30].reshape(15, 2)[:n]
    points = BSpline(t, ctrl, k)(np.linspace(0, 1, 40)) + rng.normal(0, 0.02, (40, 2))
    dist, _ = project_points(points, ctrl, np.ones(n), t, k, False)
    dense = BSpline(t, ctrl, k)(np.linspace(0, 1, 200_001))
    brute = np.min(np.linalg.norm(points[:, None] - dense[None], axis=2), axis=1)
    assert np.all(dist <= brute + 1e-12)  # the exact minimum, never above a sampled one
    gap = np.max(np.linalg.norm(np.diff(dense, axis=0), axis=1))
    assert np.all(brute - dist <= 0.5 * gap + 1e-12)  # and below it by half a sample gap
