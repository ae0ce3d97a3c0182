"""The paper's cases and their measures: datasets, the symmetric distance, a run, a figure."""

import math

import matplotlib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmcurves_jax.datasets import butterfly_nurbs, circular_arc_points, remove_points
from swarmcurves_jax.paper import (
    FIGURES,
    arc_length_samples,
    hausdorff_distance,
    paper_cases,
    run_case,
    symmetric_distance,
)

matplotlib.use("Agg")


def test_symmetric_distance_of_known_pairs():
    a = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = np.c_[np.cos(a), np.sin(a)]
    assert symmetric_distance(circle, 1.1 * circle, closed=True) == pytest.approx(0.1, rel=1e-4)
    x = np.linspace(0, 1, 300)
    line = np.c_[x, 0 * x]
    assert symmetric_distance(line, line + [0, 0.05]) == pytest.approx(0.05, rel=1e-9)
    # half the segment: one way 0, the other the mean of (x - 1/2) over x in [1/2, 1] weighted
    # by half the length: 1/16; the mean of the two ways: 1/32 ... of the whole: 0.0625
    half = np.c_[np.linspace(0, 0.5, 200), np.zeros(200)]
    assert symmetric_distance(line, half) == pytest.approx(0.0625, rel=1e-3)
    assert symmetric_distance(circle, circle[::-1], closed=True) == pytest.approx(0, abs=1e-12)


def test_hausdorff_distance_of_known_pairs():
    """The largest gap either way: a spike one way, a missing half the other; within the
    spacing of the 10,000 arc-length samples (the spike's tip falls between two)."""
    x = np.linspace(0, 1, 301)
    line = np.c_[x, 0 * x]
    spike = line.copy()
    spike[150, 1] = 0.3  # a spike to (0.5, 0.3): 0.3 from the line, the line 0 from it
    assert hausdorff_distance(line, spike) == pytest.approx(0.3, abs=2e-4)
    assert hausdorff_distance(spike, line) == pytest.approx(0.3, abs=2e-4)
    half = np.c_[np.linspace(0, 0.5, 200), np.zeros(200)]
    assert hausdorff_distance(line, half) == pytest.approx(0.5, rel=1e-12)  # (1, 0) to (0.5, 0)
    a = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = np.c_[np.cos(a), np.sin(a)]
    assert hausdorff_distance(circle, 1.1 * circle, closed=True) == pytest.approx(0.1, rel=1e-4)


@settings(max_examples=8)  # 0.4 s an example; the property is linear in the frame
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.1, 10))
def test_symmetric_distance_is_symmetric_and_moves_with_the_frame(dx, dy, s):
    u = np.linspace(0, 1, 150)
    a = np.c_[u, np.sin(3 * u)]
    b = np.c_[u, np.sin(3 * u) + 0.1 * u**2]
    d = symmetric_distance(a, b)
    assert symmetric_distance(b, a) == pytest.approx(d, rel=1e-9)
    assert symmetric_distance(s * a + [dx, dy], s * b + [dx, dy]) == pytest.approx(s * d, rel=1e-6)


def test_arc_length_samples_are_even():
    pts = arc_length_samples(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]]), 5)
    np.testing.assert_allclose(pts, [[0, 0], [1, 0], [1, 1], [1, 2], [1, 3]], atol=1e-12)


@pytest.mark.parametrize("closed", [False, True])
@pytest.mark.parametrize("fraction", [0.0, 0.5, 0.75, 0.9])
def test_remove_points_keeps_order_count_and_open_ends(fraction, closed):
    pts = np.c_[np.arange(200.0), np.zeros(200)]
    kept = remove_points(pts, fraction, seed=3, closed=closed)
    assert len(kept) == 200 - round(200 * fraction)
    assert np.all(np.diff(kept[:, 0]) > 0)
    if not closed:
        assert kept[0, 0] == 0 and kept[-1, 0] == 199
    np.testing.assert_array_equal(kept, remove_points(pts, fraction, seed=3, closed=closed))


@pytest.mark.parametrize(
    "fraction, message",
    [(1.0, r"fraction must be in \[0, 1\), got 1.0"), (0.99, "fewer than 3 of 200 points")],
)
def test_remove_points_bad_fraction(fraction, message):
    with pytest.raises(ValueError, match=message):
        remove_points(np.zeros((200, 2)), fraction)


def test_arc_and_butterfly():
    arc = circular_arc_points(math.pi / 2, 50)
    np.testing.assert_allclose(np.linalg.norm(arc, axis=1), 1.0)
    np.testing.assert_allclose(arc[0], [-arc[-1, 0], arc[-1, 1]])  # symmetric about y
    with pytest.raises(ValueError, match="theta must be in"):
        circular_arc_points(7.0)
    b = butterfly_nurbs()
    assert b.closed and b.rational and b.n_ctrl == 16
    p = b.evaluate(np.linspace(0, 1, 401))
    np.testing.assert_allclose(p[0], p[-1], atol=1e-12)
    rows = {(round(x, 9), round(y, 9), w) for (x, y), w in zip(b.control_points, b.weights)}
    assert rows == {(round(-x, 9) + 0.0, y, w) for x, y, w in rows}  # mirrored wings


def test_cases_cover_every_figure_and_skip_missing_outlines(tmp_path, monkeypatch):
    monkeypatch.setenv("SWARMCURVES_DATA", str(tmp_path))
    cases, notes = paper_cases()
    assert {c.figure for c in cases} == set(FIGURES)
    assert len({c.name for c in cases}) == len(cases)
    assert notes and "outlines not found" in notes[0]
    assert not [c for c in cases if "outline" in c.name]
    for c in cases:
        assert c.truth_samples is not None or "noisy" in c.name


def test_run_case_measures_the_conic_and_a_known_curve():
    cases, _ = paper_cases()
    by_name = {c.name: c for c in cases}
    conic = run_case(by_name["fig5 circular arc, rational quadratic"], iterations=200)
    (row,) = conic.rows
    assert row["middle_weight"] == pytest.approx(math.cos(math.pi / 3), abs=1e-4)
    assert row["symmetric_distance"] < 1e-5 and row["error"] < 1e-5
    # 20 exact points of a 6-cp cubic pin it down where the fit finds it: recovered,
    # against the dense clean data too.  It is found from 2 of the seeds 0-3, seed 1 among
    # them; the others fall into a basin 4-8e-3 away.
    sparse = run_case(
        by_name["fig7 sparse, 90 % removed (Fig. 2's cubic)"], iterations=2000, seed=1
    )
    r = sparse.row(3, 6)
    assert len(sparse.case.points) == 20
    assert r["error_vs_clean"] < 1e-4 and r["symmetric_distance"] < 1e-4
    assert sparse.shown.n_ctrl == 6


def test_plot_result_draws_the_paper_layout():
    from swarmcurves_jax import fit
    from swarmcurves_jax.plotting import plot_result

    # the swarm program of the command line's first output test; the layout is what is
    # checked, so no polish
    u = np.linspace(0, 1, 90)
    result = fit(np.c_[u, np.sin(4 * u)], cps=(5, 6), degrees=(2, 3), iterations=50, refine=False)
    curve = result[2, 5]
    fig = plot_result(result, curve, true_control_points=curve.control_points, title="t")
    curve_ax, colour_bar, polygon_ax, error_ax = fig.axes
    assert colour_bar.get_ylabel() == "distance between curve and data, both ways"
    assert "5 control points" in curve_ax.get_title()
    assert f"max deviation {curve.max_deviation_pct_diag:.3g} % of diagonal" in curve_ax.get_title()
    assert [ln.get_label() for ln in polygon_ax.get_lines()][:2] == ["fitted", "true"]
    assert [ln.get_label() for ln in error_ax.get_lines()][:2] == ["degree 2", "degree 3"]
    ringed = error_ax.get_lines()[-1]
    assert list(ringed.get_xdata()) == [5] and ringed.get_ydata()[0] == curve.mean_deviation
