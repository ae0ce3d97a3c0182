"""FitResult model selection: sparsest, knee, information criteria, on known curves."""

import numpy as np
import pytest

from swarmcurves_jax import fit, normalise
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
