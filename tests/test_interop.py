"""Conversions to scipy, geomdl, the clamped form and Bézier segments agree to 1e-6."""

from math import comb

import numpy as np
import pytest

from swarmcurves_jax import Curve, make_knots
from swarmcurves_jax.interop import bezier_segments

U = np.linspace(0, 1, 1000)
CASES = [
    (k, closed, rational, dim)
    for k in (1, 2, 3, 5)
    for closed in (False, True)
    for rational in (False, True)
    for dim in (2, 3)
]


def random_curve(k, closed, rational, dim, seed=0):
    rng = np.random.default_rng(seed + 10 * k + 2 * closed + rational)
    n = k + 3
    w = rng.uniform(0.3, 2.0, n) if rational else np.ones(n)
    return Curve(
        k,
        rng.uniform(-5, 5, (n, dim)),
        w,
        make_knots(n, k, closed),
        closed=closed,
        rational=rational,
    )


@pytest.mark.parametrize("k,closed,rational,dim", CASES)
def test_clamped_form_and_geomdl_are_the_same_curve(k, closed, rational, dim):
    curve = random_curve(k, closed, rational, dim)
    clamped = curve.to_clamped()
    assert not clamped.closed and clamped.n_ctrl == curve.n_ctrl + (k if closed else 0)
    np.testing.assert_allclose(clamped.evaluate(U), curve.evaluate(U), atol=1e-9)
    g = curve.to_geomdl()
    np.testing.assert_allclose(np.array(g.evaluate_list(list(U))), curve.evaluate(U), atol=1e-6)


@pytest.mark.parametrize(
    "k,closed,dim", [(k, c, d) for k in (1, 2, 3, 5) for c in (False, True) for d in (2, 3)]
)
def test_scipy_round_trip(k, closed, dim):
    curve = random_curve(k, closed, False, dim)
    spl = curve.to_scipy()
    assert spl.c.shape == (curve.n_ctrl + (k if closed else 0), dim)
    np.testing.assert_allclose(spl(U), curve.evaluate(U), atol=1e-6)
    back = Curve.from_scipy(spl)
    assert back.closed == closed and back.n_ctrl == curve.n_ctrl
    np.testing.assert_allclose(back.evaluate(U), curve.evaluate(U), atol=1e-12)


def test_scipy_refuses_what_it_cannot_hold():
    from scipy.interpolate import BSpline

    with pytest.raises(ValueError, match="scipy's BSpline is not rational"):
        random_curve(3, False, True, 2).to_scipy()
    t = np.r_[0, 0, 0, 0, 0.3, 2, 2, 2, 2]  # clamped, but not on [0, 1]
    with pytest.raises(ValueError, match=r"only clamped knots on \[0, 1\]"):
        Curve.from_scipy(BSpline(t, np.zeros((5, 2)), 3))


def test_scipy_non_uniform_clamped_knots_round_trip():
    from scipy.interpolate import BSpline

    t = np.r_[0, 0, 0, 0, 0.3, 1, 1, 1, 1]
    c = np.random.default_rng(0).uniform(-1, 1, (5, 2))
    curve = Curve.from_scipy(BSpline(t, c, 3))
    u = np.linspace(0, 1, 30)
    np.testing.assert_allclose(curve.evaluate(u), BSpline(t, c, 3)(u), atol=1e-14)
    np.testing.assert_array_equal(curve.to_scipy().t, t)


@pytest.mark.parametrize(
    "k,closed,rational",
    [(k, c, r) for k in (1, 2, 3, 5) for c in (False, True) for r in (False, True)],
)
def test_bezier_segments_reproduce_the_curve(k, closed, rational):
    curve = random_curve(k, closed, rational, 2)
    segs = bezier_segments(curve)
    spans = curve.n_ctrl if closed else curve.n_ctrl - k
    assert len(segs) == spans and all(len(c) == k + 1 for c, _ in segs)
    s = np.linspace(0, 1, 50)
    basis = np.stack([comb(k, i) * s**i * (1 - s) ** (k - i) for i in range(k + 1)], axis=1)
    for j, (ctrl, w) in enumerate(segs):
        pts = (basis @ (ctrl * w[:, None])) / (basis @ w)[:, None]
        np.testing.assert_allclose(pts, curve.evaluate((j + s) / spans), atol=1e-9)
