"""FitResult model selection: sparsest, knee, information criteria, on known curves."""

import numpy as np
import pytest

from swarmcurves_jax import Curve, FitResult, fit, make_knots, normalise
from swarmcurves_jax.datasets import normal_noise, random_bspline_points


@pytest.fixture(scope="module")
def six_point_cubic():
    """A 6-cp cubic with small noise (σ = 0.005 of the half-size) fitted at 4..8 cp (the
    program of tests/test_fit.py's recovery of the same cubic)."""
    pts = random_bspline_points(6, 3, False, seed=101)[0]
    norm, center, scale = normalise(pts)
    noisy = center + scale * normal_noise(norm, 0.005, seed=1)
    return fit(noisy, cps=range(4, 9), iterations=800)


def test_criteria_and_knee_find_the_true_count(six_point_cubic):
    result = six_point_cubic
    assert result.select("bic").n_ctrl == 6
    assert result.knee().n_ctrl == 6
    assert result.select("aic").n_ctrl >= 6
    rows = result.table()
    assert all("bic" in row and "aic" in row for row in rows)
    bic = [row["bic"] for row in rows]
    assert int(np.argmin(bic)) == 2  # n = 6


def test_sparsest_by_a_tolerance_on_the_largest_deviation(six_point_cubic):
    """A CAD tolerance: the largest deviation between curve and data, both ways, in the
    points' units or as % of the diagonal."""
    result = six_point_cubic
    worst = {c.n_ctrl: c.max_deviation * result.scale for c in result}
    assert worst[6] < worst[5] and worst[6] < worst[4]
    assert result.sparsest(worst[6]).n_ctrl == 6
    assert result.sparsest(0.999 * min(worst.values())) is None
    pct = result[3, 6].max_deviation_pct_diag
    assert result.sparsest(pct_diag=pct).n_ctrl == 6
    assert result.best.mean_deviation == min(c.mean_deviation for c in result)
    with pytest.raises(ValueError, match="give tolerance .* or pct_diag, not both"):
        result.sparsest(1.0, pct_diag=1.0)
    with pytest.raises(ValueError, match="tolerance must be a number >= 0, got -1"):
        result.sparsest(-1)


def test_selection_errors_name_what_was_expected(six_point_cubic):
    with pytest.raises(ValueError, match=r"criterion must be 'bic' or 'aic', got 'mdl'"):
        six_point_cubic.select("mdl")
    with pytest.raises(ValueError, match=r"degree must be one of \[3\], got 2"):
        six_point_cubic.knee(degree=2)
    two = fit(random_bspline_points(6, seed=1)[0], cps=[5, 6], iterations=50, refine=False)
    with pytest.raises(
        ValueError, match="knee needs at least 3 control-point counts of degree 3, got 2"
    ):
        two.knee()


@pytest.mark.parametrize("data_crosses, kept", [(False, 6), (True, 5)])
def test_sparsest_passes_over_a_curve_that_crosses_itself_where_the_data_do_not(
    data_crosses, kept
):
    """Two solutions within the tolerance: 5 control points whose curve crosses itself
    once (a loop can stay within a coarse tolerance: f4's cubic at 5, 4.4 % of the
    diagonal) and 6 that does not.  Over an arc of data the 6 is the sparsest; over a
    figure of eight, which crosses itself once, the 5."""
    t = np.linspace(0.3, 2 * np.pi + 0.2, 200)
    points = np.c_[np.sin(2 * t), np.sin(t)] if data_crosses else np.c_[np.cos(t / 2), t]
    curves = [
        Curve(3, np.zeros((n, 2)), np.ones(n), make_knots(n, 3, False), mean_deviation=1e-3,
              max_deviation=1e-2, max_deviation_pct_diag=0.5, info={"self_crossings": x})
        for n, x in ((5, 1), (6, 0))
    ]
    result = FitResult(curves, points, np.zeros(2), 1.0, np.zeros((2, 1)), "iterations", 0, 0.0)
    assert result.sparsest(pct_diag=1.0).n_ctrl == kept
    assert result.sparsest(0.02).n_ctrl == kept


@pytest.mark.parametrize(
    "data_crosses, crossing, picked",
    [
        (False, (6, 9), {"best": 8, "knee": 7, "bic": 8}),  # the loops passed over
        (True, (6, 9), {"best": 9, "knee": 6, "bic": 9}),  # as often as the data: kept
        (False, range(4, 10), {"best": 9, "knee": 6, "bic": 9}),  # every curve loops
    ],
)
def test_the_helpers_pass_over_curves_that_cross_themselves_where_the_data_do_not(
    data_crosses, crossing, picked
):
    """Solutions at 4-9 control points whose deviation drops to a knee at 6; the ones at 6
    (the knee) and 9 (the lowest deviation and BIC) cross themselves once, as a loop in a
    corner of sparse data does.  Over data that do not cross themselves ``best`` and
    ``select`` take the next lowest (8), ``knee`` the next count up (7); over a figure of
    eight, which crosses itself once, or where every curve crosses itself, the loops."""
    t = np.linspace(0.3, 2 * np.pi + 0.2, 200)
    points = np.c_[np.sin(2 * t), np.sin(t)] if data_crosses else np.c_[np.cos(t / 2), t]
    means = dict(zip(range(4, 10), (1e-1, 3e-2, 3e-3, 2e-3, 1.5e-3, 1e-3)))
    curves = [
        Curve(3, np.zeros((n, 2)), np.ones(n), make_knots(n, 3, False), rms_error=m,
              mean_deviation=m, info={"self_crossings": int(n in crossing), "rms_excursion": 0.0})
        for n, m in means.items()
    ]
    result = FitResult(curves, points, np.zeros(2), 1.0, np.zeros((6, 1)), "iterations", 0, 0.0)
    chosen = {"best": result.best, "knee": result.knee(), "bic": result.select("bic")}
    assert {name: c.n_ctrl for name, c in chosen.items()} == picked
    assert len(result.untangled()) == (6 if data_crosses else 6 - len(crossing))
