"""fit_many: batched = one by one = sharded = multi-host, bit for bit; buckets; errors."""

import json
import os
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmcurves_jax import Curve, fit, fit_many, fit_stream, make_knots
from swarmcurves_jax.batch import padding_waste
from swarmcurves_jax.datasets import random_bspline_points
from swarmcurves_jax.prepare import bucket_length, polish_length

OPTS = dict(cps=[4, 6], iterations=60, particles=16)


def _sets():
    """Curves of four lengths (three buckets), open and closed, a 3-D one apart."""
    rng = np.random.default_rng(7)
    out = []
    for i, n in enumerate([70, 50, 90, 64]):
        s = np.linspace(0, 1, n)
        out.append(np.c_[s, np.sin(3 * s + i)] + 1e-3 * rng.normal(size=(n, 2)))
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    out.append(np.c_[np.cos(t), 0.6 * np.sin(t)])  # closed
    out.append(np.c_[t, np.cos(t), np.sin(t)])  # 3-D
    return out


CLOSED = [False, False, False, False, True, False]
SEEDS = [0, 1, 2, 3, 4, 5]
#: The curves the subprocess tests run: two programs (open and closed), to compile little.
SOME = [1, 3, 4]


def _some(items):
    return [items[i] for i in SOME]


def _same(a, b):
    assert len(a.solutions) == len(b.solutions)
    for x, y in zip(a.solutions, b.solutions):
        assert np.array_equal(x.control_points, y.control_points)
        assert np.array_equal(x.weights, y.weights) and np.array_equal(x.knots, y.knots)
        assert x.error == y.error and x.info["refined"] == y.info["refined"]
    assert np.array_equal(a.history, b.history)
    assert a.stop_reason == b.stop_reason and a.seed == b.seed


@pytest.fixture(scope="module")
def lone():
    return [fit(p, closed=c, seed=s, **OPTS) for p, c, s in zip(_sets(), CLOSED, SEEDS)]


def test_batched_equals_one_by_one_bit_for_bit(lone):
    seen = []
    many = fit_many(
        _sets(),
        closed=CLOSED,
        seed=SEEDS,
        batch_size=2,
        on_result=lambda i, r: seen.append(i),
        **OPTS,
    )
    assert sorted(seen) == list(range(6))
    for a, b in zip(lone, many):
        _same(a, b)
    assert [r.batch["bucket"] for r in many] == [80, 64, 96, 64, 80, 80]
    assert [r.batch["points"] for r in many] == [70, 50, 90, 64, 80, 80]
    # open 2-D at 64 points: 50 and 64 share one call; the closed and the 3-D curves
    # are programs of their own although their bucket is the same
    calls = [r.batch["call"] for r in many]
    assert calls[1] == calls[3] and len(set(calls)) == 5
    assert padding_waste(many) == pytest.approx(1 - 434 / 464)


def test_a_stream_equals_one_by_one_bit_for_bit(lone):
    """fit_stream reads a generator as it goes: a bucket runs once it holds batch_size
    curves (the rest at the end), and a call's results come while the next call runs;
    every result is the lone fit's."""
    stream = fit_stream(iter(_sets()), closed=iter(CLOSED), seed=SEEDS, batch_size=2, **OPTS)
    got = dict(stream)
    assert sorted(got) == list(range(6))
    for i, a in enumerate(lone):
        _same(a, got[i])
    # the open 2-D curves 1 and 3 share a bucket: the one full call; the others end it
    assert got[1].batch["call"] == got[3].batch["call"] == 0
    read = []

    def same_bucket():  # curves 1 and 3 in turn: calls of two at 2, 4 and 6 read
        for i in range(6):
            read.append(i)
            yield _sets()[1 if i % 2 == 0 else 3]

    stream = fit_stream(same_bucket(), seed=[1, 3] * 3, batch_size=2, **OPTS)
    i, first = next(stream)
    assert read == [0, 1, 2, 3] and i == 0  # call 0 collected once call 1 runs
    _same(lone[1], first)
    for i, result in stream:
        _same(lone[1 if i % 2 == 0 else 3], result)
    assert read == list(range(6)) and i == 5


def test_a_lone_curve_polishes_as_in_a_batch():
    """A near-exact fit (fitness 8e-8, at float32's limit) polished alone and beside
    another curve: the same bits (a lone polish once ran a loop XLA removed, and
    rounded differently).  The points lie at uneven parameters: at even ones the float64
    least-squares seed is exact and is reported instead of the polish."""
    ctrl = random_bspline_points(6, 3, num_points=60, seed=60)[1]
    first = Curve(3, ctrl, np.ones(6), make_knots(6, 3, False)).evaluate(
        np.linspace(0, 1, 60) ** 1.3
    )
    other = random_bspline_points(6, 3, num_points=64, seed=64)[0]
    lone = fit(first, seed=0, **OPTS)
    assert lone.solutions[1].info["refined"] and lone.solutions[1].info["fitness"] < 1e-7
    _same(lone, fit_many([first, other], seed=[0, 1], **OPTS)[0])


def test_one_compiled_program_per_bucket(compiles_during):
    sets = [np.c_[np.linspace(0, 1, n), np.linspace(0, 1, n) ** 2] for n in (33, 40, 47, 60)]
    # shapes no other test compiles; the swarm's programs are what is counted
    opts = dict(OPTS, particles=12, refine=False)
    many = []
    compiled = compiles_during(lambda: many.extend(fit_many(sets, batch_size=2, **opts)))
    assert {r.batch["bucket"] for r in many} == {48, 64}  # 48: two calls of 2
    assert sum("swarm_program" in m for m in compiled) == 2
    assert [r.batch["call"] for r in many] == [0, 0, 1, 2]


def test_tol_stops_each_curve_as_if_alone():
    """Two curves of 64 points: the programs of :func:`_sets`' bucket of 64."""
    s = np.linspace(0, 1, 64)
    line, wave = np.c_[s, 2 * s], np.c_[s, np.sin(9 * s)]
    opts = dict(OPTS, iterations=400, tol=1e-4)
    many = fit_many([line, wave], **opts)
    for points, result in zip([line, wave], many):
        _same(fit(points, **opts), result)
    assert many[0].stop_reason == "tol" and many[0].history.shape[1] < 400
    assert many[1].stop_reason == "iterations"


def _run_script(code, env_extra, timeout=300):
    env = dict(os.environ, **env_extra)
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def _solutions(results):
    return [[(c.control_points.tolist(), c.error) for c in r.solutions] for r in results]


def _histories(results):
    return [r.history.tolist() for r in results]


def _match_across_devices(got, lone):
    """Bit for bit: the swarm's history and every solution."""
    assert got["histories"] == json.loads(json.dumps(_histories(lone)))
    assert got["solutions"] == json.loads(json.dumps(_solutions(lone)))


def test_sharded_over_forced_host_devices_matches_and_splits_the_work(lone):
    code = """
        import json, jax, numpy as np
        import tests.test_batch as tb
        from swarmcurves_jax import fit_many
        from swarmcurves_jax.devices import Placement
        # batch_size 1 rounds up to a call of 4 (one curve per device): no empty calls
        sets, closed, seeds = (tb._some(x) for x in (tb._sets(), tb.CLOSED, tb.SEEDS))
        many = fit_many(sets, closed=closed, seed=seeds, batch_size=1, **tb.OPTS)
        parts = Placement.over().curves(np.arange(8.0)).addressable_shards
        print(json.dumps({
            "devices": jax.device_count(),
            "shards": [(str(s.device), s.data.tolist()) for s in parts],
            "batch": [r.batch["devices"] for r in many],
            "solutions": tb._solutions(many),
            "histories": tb._histories(many),
        }))
    """
    flags = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4", "PYTHONPATH": os.getcwd()}
    got = json.loads(_run_script(code, flags).splitlines()[-1])
    assert got["devices"] == 4 and got["batch"] == [4] * 3
    assert [data for _, data in got["shards"]] == [[0, 1], [2, 3], [4, 5], [6, 7]]
    assert len({device for device, _ in got["shards"]}) == 4
    _match_across_devices(got, _some(lone))


#: fit calls whose swarms a machine of several CPU devices splits (tests below).
SPLIT = [
    dict(cps=[4, 6], degrees=(2, 3), iterations=60, particles=16, seed=3),
    dict(
        cps=[4, 6],
        degrees=(2, 3),
        iterations=400,
        particles=16,
        # between the 4-cp quadratic's best after 50 and after 100 iterations (1.419e-2,
        # 1.399e-2; the other swarms are below it after 50): its part stops a chunk later
        tol=1.41e-2,
        chunk_size=50,
        refine=False,
    ),
]


def _split_fits():
    """The :data:`SPLIT` fits, and every ``callback(iteration, best)`` of the second."""
    sets, calls = _sets(), []
    first = fit(sets[1], **SPLIT[0])
    second = fit(
        sets[4],
        closed=True,
        callback=lambda at, best: calls.append([at, best.tolist()]),
        **SPLIT[1],
    )
    return [first, second], calls


def test_fit_split_over_cpu_devices_matches_one_program():
    """With several CPU devices fit deals its swarms over them, one program each, and
    refines in one program: every solution, history, stop and callback equals one
    device's (in the tol case one part stops a chunk before the other)."""
    from swarmcurves_jax.dealing import split_swarms, swarm_costs, widen

    # a polygon costs 1.25 a segment, a spline its samples + 5 + spans (k + 3) D / 5:
    # W1's polygons 11.25, quadratics 32 + 5 + 16 = 53, cubics 28 + 5 + 16.8 = 49.8
    w1 = [(k, n) for k in (1, 2, 3) for n in range(4, 11)]
    groups = ((1, 0, 7, 9), (2, 7, 14, 32), (3, 14, 21, 28))
    cost = swarm_costs(w1, groups, False, 2)
    np.testing.assert_allclose(cost[[0, 7, 14]], [11.25, 53.0, 49.8])
    # whole degrees first (the quadratics' 371 to one, the cubics' 348.6 and the polygons'
    # 78.75 to the other), then polygons over while the other stays below: 5 % below to
    # start a group there, then freely (404.75 against 393.6)
    split = [s.tolist() for s in split_swarms(groups, 2, cost)]
    assert split == [[0, 1, 2, *range(7, 14)], [3, 4, 5, 6, *range(14, 21)]]
    # one swarm a device, but two polygons cost less than one spline swarm
    groups = ((1, 0, 3, 8), (2, 3, 6, 12), (3, 6, 9, 12))
    cost = np.r_[np.full(3, 8.0), np.full(6, 22.0)]
    # a swarm left alone in its group runs with a copy (widen), so it costs two: a
    # polygon group shares a set, each spline group splits 1 + 2 at most
    expected = [[0, 1, 2], [3], [4, 5], [6], [7, 8]]
    assert sorted(s.tolist() for s in split_swarms(groups, 20, cost)) == expected
    assert widen(np.array([3, 6]), groups).tolist() == [3, 3, 6, 6]
    assert widen(np.array([0, 4, 5]), ((1, 0, 1, 8), (2, 1, 9, 12))).tolist() == [0, 4, 5]
    split = split_swarms(((3, 0, 7, 28),), 2, np.full(7, 38.0))
    assert [s.tolist() for s in split] == [[3, 4, 5, 6], [0, 1, 2]]
    code = """
        import json, jax
        jax.config.update("jax_num_cpu_devices", 2)
        import tests.test_batch as tb
        from swarmcurves_jax import launch
        from swarmcurves_jax.devices import cpu_devices
        early, make = [], launch._EarlyPolish._make
        launch._EarlyPolish._make = lambda self: early.append(1) or make(self)
        got, calls = tb._split_fits()
        print(json.dumps({"devices": len(cpu_devices()), "stops": [r.stop_reason for r in got],
                          "solutions": tb._solutions(got), "histories": tb._histories(got),
                          "calls": calls, "early": len(early)}))
    """
    got = json.loads(_run_script(code, {"PYTHONPATH": os.getcwd()}).splitlines()[-1])
    lone, calls = _split_fits()
    assert got["devices"] == 2
    # the polished fit's polish made once, while its parts compile and run
    assert got["early"] == 1
    assert got["stops"] == [r.stop_reason for r in lone] == ["iterations", "tol"]
    assert [at for at, _ in calls] == [50, 100] and lone[1].history.shape[1] == 100
    assert got["calls"] == json.loads(json.dumps(calls))
    _match_across_devices(got, lone)


#: The same call on 1, 3 and 4 CPU devices (2: the test above): fit deals its cubics
#: 2 + 1 + 1 or 1 + 1 + 1 + 1 (each lone swarm with a copy), fit_many splits the curves.
#: The swarm alone: fit's polish is one program whatever the devices (the test above
#: checks it split over two), fit_many's is split by curves as its swarm is (the forced
#: host devices and the two processes check it).
DEALT = dict(cps=range(4, 8), degrees=3, iterations=60, particles=16, seed=0, refine=False)


def _dealt_sets():
    """Random cubics of 6 control points, 150 and 156 points: one bucket, so each process
    compiles one set of programs for both."""
    return [random_bspline_points(6, 3, num_points=n, seed=n)[0] for n in (150, 156)]


def test_any_count_of_cpu_devices_gives_the_same_curves():
    """Every swarm's result depends on its swarm and curve alone, not on how the swarms
    or curves are dealt over devices: fit and fit_many on 3 and 4 CPU devices equal one
    device's fit bit for bit."""
    code = """
        import json, sys, jax
        jax.config.update("jax_num_cpu_devices", int(sys.argv[1]))
        import tests.test_batch as tb
        from swarmcurves_jax import fit, fit_many, fit_stream
        from swarmcurves_jax.devices import cpu_devices
        sets = tb._dealt_sets()
        lone = [fit(p, **tb.DEALT) for p in sets]
        many = fit_many(sets, **tb.DEALT) if len(sys.argv) > 2 else []
        print(json.dumps({"devices": len(cpu_devices()),
                          "solutions": tb._solutions(lone + many),
                          "histories": tb._histories(lone + many)}))
    """
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    runs = {
        d: subprocess.Popen(
            [sys.executable, "-c", textwrap.dedent(code), str(d), *(["many"] if d == 3 else [])],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for d in (3, 4)
    }
    lone = [fit(p, **DEALT) for p in _dealt_sets()]
    for d, run in runs.items():
        out, err = run.communicate(timeout=300)
        assert run.returncode == 0, err[-3000:]
        got = json.loads(out.splitlines()[-1])
        assert got["devices"] == d
        _match_across_devices(got, lone * (2 if d == 3 else 1))


def _free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_through_jax_distributed_match_one(lone):
    """The multi-host path on one machine: two processes of two CPU devices each."""
    code = """
        import json, sys, jax
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        pid, port = int(sys.argv[1]), sys.argv[2]
        jax.distributed.initialize(f"localhost:{port}", num_processes=2, process_id=pid)
        import tests.test_batch as tb
        from swarmcurves_jax import fit_many
        sets, closed, seeds = (tb._some(x) for x in (tb._sets(), tb.CLOSED, tb.SEEDS))
        many = fit_many(sets, closed=closed, seed=seeds, **tb.OPTS)
        print(json.dumps({"devices": jax.device_count(), "processes": jax.process_count(),
                          "solutions": tb._solutions(many), "histories": tb._histories(many)}))
    """
    port = str(_free_port())
    env = dict(
        os.environ,
        XLA_FLAGS="--xla_force_host_platform_device_count=2",
        PYTHONPATH=os.getcwd(),
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", textwrap.dedent(code), str(pid), port],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for pid in (0, 1)
    ]
    try:
        outs = [p.communicate(timeout=300) for p in procs]
    finally:
        for p in procs:
            p.kill()
            p.wait()
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
        got = json.loads(out.splitlines()[-1])
        assert got["devices"] == 4 and got["processes"] == 2
        _match_across_devices(got, _some(lone))


@given(st.integers(1, 200_000))
def test_bucket_lengths_bound_the_padding(n):
    b = bucket_length(n)
    assert b >= n and b % 16 == 0
    assert b - n < 16 if n <= 128 else (b - n) / b < 0.125
    assert bucket_length(b) == b  # a bucket is its own bucket
    p = polish_length(b)  # the polish's: the next power of two, a bucket of its own
    assert b <= p < 2 * b and p & (p - 1) == 0 and bucket_length(p) == p


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: fit_many([]), "point_sets is empty"),
        (lambda: fit_many(np.zeros((30, 2))), "got one array of shape (30, 2)"),
        (lambda: fit_many("a.csv"), "point_sets must be a list"),
        (
            lambda: fit_many([np.random.rand(30, 2), np.full((30, 2), np.nan)], cps=4),
            "point_sets[1] must be finite; NaN or inf in row(s) 0, 1, 2, 3, 4, ...",
        ),
        (
            lambda: fit_many([np.random.rand(30, 2), np.random.rand(5, 2)], cps=[4, 8]),
            "point_sets[1]: 5 points are too few for 8 control points",
        ),
        (
            lambda: fit_many([np.random.rand(30, 2)] * 2, closed=[True]),
            "closed must be one value or 2 values (one per point set), got 1",
        ),
        (lambda: fit_many([np.random.rand(30, 2)], closed=["yes"]), "closed[0] must be"),
        (lambda: fit_many([np.random.rand(30, 2)], batch_size=0), "batch_size must be"),
        (lambda: fit_many([np.random.rand(30, 2)], vmap_curves=0), "vmap_curves must be"),
        (lambda: fit_many([np.random.rand(30, 2)], particle=3), "particle"),
        (lambda: fit_many([np.random.rand(30, 2)], devices=[]), "devices must not be empty"),
        (lambda: list(fit_stream("a.csv")), "point_sets must be an iterable of (N, 2)"),
        (
            lambda: list(fit_stream([np.random.rand(30, 2)] * 2, cps=4, closed=[True])),
            "closed ran out at point set 1: give one value per point set",
        ),
        (
            lambda: list(fit_stream(iter([np.random.rand(30, 2), np.random.rand(3, 2)]), cps=4)),
            "point_sets[1]: 3 points are too few for 4 control points",
        ),
    ],
)
def test_bad_input_names_the_argument(call, message):
    with pytest.raises(ValueError) as info:
        call()
    assert message in str(info.value)
