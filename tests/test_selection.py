"""FitResult model selection: sparsest, knee, information criteria, on known curves."""

import numpy as np
import pytest

from swarmcurves_jax import fit, normalise
from swarmcurves_jax.datasets import normal_noise, random_bspline_points


@pytest.fixture(scope="module")
def six_point_cubic():
    """A 6-cp cubic with small noise (σ = 0.005 of the half-size) fitted at 4..9 cp."""
    pts = random_bspline_points(6, 3, False, seed=101)[0]
    norm, center, scale = normalise(pts)
    noisy = center + scale * normal_noise(norm, 0.005, seed=1)
    return fit(noisy, cps=range(4, 10), iterations=800)


def test_criteria_and_knee_find_the_true_count(six_point_cubic):
    result = six_point_cubic
    assert result.select("bic").n_ctrl == 6
    assert result.knee().n_ctrl == 6
    assert result.select("aic").n_ctrl >= 6
    rows = result.table()
    assert all("bic" in row and "aic" in row for row in rows)
    bic = [row["bic"] for row in rows]
    assert int(np.argmin(bic)) == 2  # n = 6


def test_sparsest_by_absolute_or_relative_error(six_point_cubic):
    result = six_point_cubic
    errors = {c.n_ctrl: c.error for c in result}
    assert errors[6] < 0.01 < errors[5]
    assert result.sparsest(max_error=0.01).n_ctrl == 6
    assert result.sparsest(max_error=1e-12) is None
    pct = result[3, 6].error_pct_diag
    assert result.sparsest(max_error_pct_diag=pct).n_ctrl == 6


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
