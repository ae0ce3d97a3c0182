"""A Dask cluster (a LocalCluster of two worker processes): the same curves as local fits."""

import csv

import numpy as np
import pytest
from distributed import Client, LocalCluster

from swarmcurves_jax import fit, fit_many
from swarmcurves_jax.cluster import fit_on_cluster
from swarmcurves_jax.datasets import random_bspline_points
from swarmcurves_jax.run import main

OPTS = dict(cps=[4, 6], iterations=60, particles=16)


def _sets():
    """Open 2-D curves of two buckets (64 and 80 points), a closed one and a 3-D one."""
    out = [random_bspline_points(6, 3, num_points=n, seed=n)[0] for n in (60, 64, 70, 75, 50)]
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    return out + [np.c_[np.cos(t), 0.6 * np.sin(t)], np.c_[t, np.cos(t), np.sin(t)]]


CLOSED = [False] * 5 + [True, False]


@pytest.fixture(scope="module")
def client():
    with (
        # ":0": a free port. With None the scheduler's HTTP server still takes 8787, and
        # a cluster of the other test worker then fails to start.
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _same(a, b):
    for x, y in zip(a.solutions, b.solutions, strict=True):
        assert np.array_equal(x.control_points, y.control_points)
        assert np.array_equal(x.weights, y.weights) and x.error == y.error
    assert np.array_equal(a.history, b.history) and a.stop_reason == b.stop_reason


def test_a_cluster_fits_the_same_curves_as_one_process(client):
    """Tasks of whole bucket calls (two curves at most) over two workers: every result
    equals the lone fit's bit for bit; at most two tasks out at once."""
    seeds = list(range(7))
    got = dict(
        fit_on_cluster(
            client, iter(_sets()), closed=CLOSED, seed=seeds, batch_size=2, in_flight=2, **OPTS
        )
    )
    assert sorted(got) == list(range(7))
    for i, (points, closed) in enumerate(zip(_sets(), CLOSED)):
        _same(fit(points, closed=closed, seed=i, **OPTS), got[i])
    assert len(client.scheduler_info()["workers"]) == 2


def test_a_bad_point_set_is_named_before_its_task_is_sent(client):
    sets = [_sets()[0], np.random.default_rng(0).random((3, 2))]
    with pytest.raises(ValueError, match=r"point_sets\[1\]: 3 points are too few"):
        list(fit_on_cluster(client, sets, **OPTS))


def test_the_command_line_fits_a_batch_on_the_scheduler(client, tmp_path):
    """Two curves of each bucket: calls of two, the programs of the test above."""
    np.savez(tmp_path / "set.npz", **{f"c{i}": p for i, p in enumerate(_sets()[:4])})
    (tmp_path / "job.yaml").write_text("figures: []\nexports: [npz]\n")
    args = [str(tmp_path / "job.yaml"), "--input", str(tmp_path / "set.npz"), "--quiet"]
    args += ["--cps", "4,6", "--iterations", "60", "--particles", "16"]
    address = client.scheduler.address
    assert main([*args, "--scheduler", address, "--out", str(tmp_path / "far")]) == 0
    local = fit_many(_sets()[:4], **OPTS)
    for i, result in enumerate(local):
        with np.load(tmp_path / "far" / f"c{i}" / "solutions.npz") as npz:
            for c in result.solutions:
                assert np.array_equal(npz[f"d3_n{c.n_ctrl}_control_points"], c.control_points)
    rows = list(csv.DictReader((tmp_path / "far" / "summary.csv").read_text().splitlines()))
    assert [r["input"] for r in rows] == [f"c{i}" for i in range(4)]
