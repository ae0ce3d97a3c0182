"""Compiled programs are kept across processes by default, read back, and a damaged entry
costs a compilation, not the fit."""

import gc
import json
import os
import subprocess
import sys
import textwrap
import threading
import time

import jax
import numpy as np
import pytest

from swarmcurves_jax import compile_cache, fit

# A fresh process fits a short call (its keywords: JSON in the first argument) and prints
# how many programs it read back from the persistent cache, the folder JAX used, and the
# curves (their control points).
SCRIPT = textwrap.dedent(
    """
    import json, logging, sys
    import numpy as np
    from swarmcurves_jax import compile_cache, fit

    hits = []
    class Hits(logging.Handler):
        def emit(self, record):
            if "Persistent compilation cache hit" in record.getMessage():
                hits.append(record.getMessage())
    logger = logging.getLogger("jax._src.compiler")
    logger.addHandler(Hits())
    logger.setLevel(logging.DEBUG)
    u = np.linspace(0, 1, 70)
    result = fit(np.c_[u, np.sin(4 * u)], **json.loads(sys.argv[1]))
    print(json.dumps({
        "hits": len(hits),
        "folder": str(compile_cache.cache_dir()),
        "curves": [s.control_points.tolist() for s in result.solutions],
    }))
    """
)


#: A call of every program kind: the swarm and the polish.
CALL = dict(cps=[5, 6], particles=8, iterations=20)


def run_fresh(env_changes, tmp_path, call=CALL):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "SWARMCURVES_"))}
    env.update(XDG_CACHE_HOME=str(tmp_path / "home-cache"), **env_changes)
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, json.dumps(call)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


def entries(folder):
    return sorted(p.name.split("-")[0] for p in folder.glob("*-cache"))


def test_programs_are_kept_in_the_users_cache_read_back_and_survive_damage(tmp_path):
    """A fresh process keeps its programs in the per-user cache folder; a second one
    (here through JAX's own setting, which is kept) reads them back and computes the same
    curves; damaged entries (e.g. a process killed while writing) are made again."""
    first, _ = run_fresh({}, tmp_path)
    folder = tmp_path / "home-cache" / "swarmcurves_jax" / "xla"
    assert first["hits"] == 0 and first["folder"] == str(folder)
    assert {"jit_swarm_program", "jit_polish_program"} <= set(entries(folder))
    other = tmp_path / "other"
    second, _ = run_fresh({"JAX_COMPILATION_CACHE_DIR": str(folder)}, other)
    assert second["folder"] == str(folder) and not (other / "home-cache").exists()
    assert second["hits"] >= 2  # the swarm and the polish
    assert second["curves"] == first["curves"]  # the same executables: the same curves
    exported = sorted((folder / "exported").glob("*.jaxexport"))
    assert {p.name.split("-")[0] for p in exported} == {"swarm_program", "polish_program"}
    for entry in [*folder.glob("*-cache"), *exported]:
        entry.write_bytes(entry.read_bytes()[:100])
    third, stderr = run_fresh({}, tmp_path)
    assert "Error reading persistent compilation cache entry" in stderr
    assert "unreadable exported program" in stderr
    assert third["curves"] == first["curves"]
    assert all(len(p.read_bytes()) > 100 for p in exported)  # made again, whole


def test_off_keeps_nothing(tmp_path):
    # a polygon's swarm alone: what is checked is where programs go, not which
    call = dict(cps=[5], degrees=1, particles=8, iterations=20, refine=False)
    off, _ = run_fresh({compile_cache.ENV: "off"}, tmp_path, call)
    assert off["folder"] == "None" and not (tmp_path / "home-cache").exists()


def test_an_exported_program_computes_the_traced_programs_curves(monkeypatch):
    """Exported or traced in this process, a program gives the same curves bit for bit
    (a 3D curve here, at the shapes and options of tests/test_batch.py's 3D curve, whose
    exported program the run may hold already; the same-curves test, recorded with traced
    programs, checks every other kind of call through exported ones)."""
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    pts = np.c_[np.cos(t), np.sin(2 * t), 0.3 * np.sin(3 * t)]
    kwargs = dict(cps=[4, 6], particles=16, iterations=60)
    exported = fit(pts, **kwargs)
    monkeypatch.setattr(compile_cache, "cache_dir", lambda: None)
    traced = fit(pts, **kwargs)
    for a, b in zip(exported.solutions, traced.solutions, strict=True):
        np.testing.assert_array_equal(a.control_points, b.control_points)
        assert a.error == b.error


def test_use_cache_names_the_folder_and_off_turns_it_off(tmp_path, monkeypatch):
    saved = {
        name: getattr(jax.config, name)
        for name in (
            "jax_compilation_cache_dir",
            "jax_enable_compilation_cache",
            "jax_compilation_cache_max_size",
            "jax_persistent_cache_min_compile_time_secs",
        )
    }
    monkeypatch.setattr(compile_cache, "_decided", False)
    try:
        assert compile_cache.use_cache(tmp_path / "a") == tmp_path / "a"
        assert compile_cache.cache_dir() == tmp_path / "a" and (tmp_path / "a").is_dir()
        assert compile_cache.use_cache("off") is None
        assert compile_cache.cache_dir() is None
        monkeypatch.setenv(compile_cache.ENV, str(tmp_path / "b"))
        assert compile_cache.default_dir() == tmp_path / "b"
        monkeypatch.setenv(compile_cache.ENV, " OFF ")
        assert compile_cache.default_dir() is None
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)


@pytest.mark.parametrize("value", ["off", "none", "0", "false", ""])
def test_every_spelling_of_off_is_off(monkeypatch, value):
    monkeypatch.setenv(compile_cache.ENV, value)
    assert compile_cache.default_dir() is None


def _exported(folder, name, size, age):
    """A file shaped like an exported program, last used ``age`` seconds ago."""
    path = folder / name
    path.write_bytes(b"x" * size)
    used = time.time() - age
    os.utime(path, (used, used))
    return path


@pytest.fixture
def cache_bound():
    """Sets JAX's cache bound for the test, and restores it after."""
    saved = jax.config.jax_compilation_cache_max_size
    yield lambda size: jax.config.update("jax_compilation_cache_max_size", size)
    jax.config.update("jax_compilation_cache_max_size", saved)


def test_exported_programs_beyond_their_share_go_least_recently_used_first(tmp_path, cache_bound):
    """Every edit of the package and every JAX upgrade makes new exported programs: the
    folder keeps EXPORTED_SHARE of JAX's bound, the programs used longest ago removed
    first (a read counts as a use), and a killed write's temporary file once it is old."""
    folder = tmp_path / "exported"
    folder.mkdir()
    real = jax.export.export(jax.jit(lambda x: x + 1))(jax.ShapeDtypeStruct((3,), np.float32))
    oldest = folder / "oldest.jaxexport"
    oldest.write_bytes(real.serialize())
    size = oldest.stat().st_size
    os.utime(oldest, (time.time() - 400,) * 2)
    older = _exported(folder, "older.jaxexport", size, 300)
    old = _exported(folder, "old.jaxexport", size, 200)
    stale = _exported(folder, ".old.jaxexport.1.2", 10, 2 * compile_cache.STALE_SECONDS)
    writing = _exported(folder, ".new.jaxexport.3.4", 10, 1)
    assert compile_cache._read(oldest).in_avals == real.in_avals  # read: now the newest
    cache_bound(int(3.5 * size / compile_cache.EXPORTED_SHARE))  # room for three
    compile_cache._write(folder / "new.jaxexport", b"y" * size)
    left = sorted(p.name for p in folder.iterdir())
    assert left == [writing.name, "new.jaxexport", old.name, oldest.name]
    assert not older.exists() and not stale.exists()


def test_an_unbounded_cache_keeps_every_exported_program(tmp_path, cache_bound):
    folder = tmp_path / "exported"
    folder.mkdir()
    kept = [_exported(folder, f"p{i}.jaxexport", 1000, 100 * i) for i in range(4)]
    cache_bound(-1)
    compile_cache._write(folder / "new.jaxexport", b"y" * 1000)
    assert all(p.exists() for p in kept) and (folder / "new.jaxexport").exists()


# A fresh process of two CPU devices fits two curves, one per device (a mesh), and prints
# how many programs it exported and the curves.
MESH_SCRIPT = textwrap.dedent(
    """
    import json
    import jax
    import numpy as np
    from swarmcurves_jax import fit_many

    made = []
    export = jax.export.export
    jax.export.export = lambda f, **kw: made.append(f.__name__) or export(f, **kw)
    u = np.linspace(0, 1, 70)
    sets = [np.c_[u, np.sin(4 * u)], np.c_[u, np.cos(3 * u)]]
    results = fit_many(sets, cps=[5, 6], particles=8, iterations=20)
    print(json.dumps({
        "devices": jax.device_count(),
        "exported": sorted(made),
        "curves": [[s.control_points.tolist() for s in r.solutions] for r in results],
    }))
    """
)


def test_a_mesh_of_devices_keeps_its_programs_exported_too(tmp_path):
    """fit_many over several devices (a mesh): its swarm and polish are exported once,
    and a later process reads them back instead of tracing, for the same curves."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "SWARMCURVES_"))}
    env.update(
        XDG_CACHE_HOME=str(tmp_path / "home-cache"),
        XLA_FLAGS="--xla_force_host_platform_device_count=2",
    )
    runs = []
    for _ in range(2):
        command = [sys.executable, "-c", MESH_SCRIPT]
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    first, second = runs
    assert first["devices"] == 2 and first["exported"] == ["polish_program", "swarm_program"]
    assert second["exported"] == [] and second["curves"] == first["curves"]
    folder = tmp_path / "home-cache" / "swarmcurves_jax" / "xla" / "exported"
    compile_cache._register_trees()  # our NamedTuples, as a fit registers them
    programs = [jax.export.deserialize(bytearray(p.read_bytes())) for p in folder.iterdir()]
    assert sorted(p.nr_devices for p in programs) == [2, 2]


@pytest.mark.parametrize(
    "method, error, warning, files",
    [
        # a full or read-only disk: the program is exported and used, not kept
        ("write_bytes", OSError(28, "No space"), "could not keep the exported program", 0),
        # a file this process may not read (another user's folder): exported again
        ("read_bytes", PermissionError(13, "Permission denied"), "unreadable exported", 1),
    ],
)
def test_a_folder_that_fails_a_read_or_write_costs_a_warning_not_the_fit(
    tmp_path, monkeypatch, method, error, warning, files
):
    monkeypatch.setattr(compile_cache, "cache_dir", lambda: tmp_path)
    monkeypatch.setattr(compile_cache, "_programs", {})  # none made in this process yet

    def fail(self, *args):
        raise error

    monkeypatch.setattr(compile_cache.Path, method, fail)

    def plus_one(x):
        return x + 1

    with pytest.warns(RuntimeWarning, match=f"{warning} .*{error.strerror}"):
        call = compile_cache.program(jax.jit(plus_one), {}, np.zeros(3, np.float32))
    np.testing.assert_array_equal(call(np.zeros(3, np.float32)), np.ones(3, np.float32))
    written = [p.name.split("-")[0] for p in (tmp_path / "exported").iterdir()]
    assert written == ["plus_one"] * files


def test_the_collector_is_held_off_while_programs_are_made_and_restored_after():
    """Held off while any holder is inside, by two threads at once too; back as it was."""
    entered, leave = threading.Barrier(2), threading.Event()

    def hold():
        with compile_cache.collector_off():
            entered.wait()
            leave.wait()

    assert gc.isenabled()
    thread = threading.Thread(target=hold)
    thread.start()
    with compile_cache.collector_off():
        entered.wait()
        assert not gc.isenabled()
    assert not gc.isenabled()  # the thread still holds it
    leave.set()
    thread.join()
    assert gc.isenabled()
    gc.disable()
    try:
        with compile_cache.collector_off():
            pass
        assert not gc.isenabled()  # left off, as it was
    finally:
        gc.enable()
    with pytest.raises(RuntimeError, match="inside"):
        with compile_cache.collector_off():
            raise RuntimeError("inside")
    assert gc.isenabled()


def test_a_fit_makes_its_programs_with_the_collector_off(monkeypatch):
    """Every program of a fit is traced and lowered with the collector held off, and the
    collector is on again after the fit."""
    seen = []
    trace = jax.stages.Traced.lower

    def lower(self, *args, **kwargs):
        seen.append(gc.isenabled())
        return trace(self, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Traced, "lower", lower)
    u = np.linspace(0, 1, 50)
    fit(np.c_[u, u**2], cps=[5], particles=8, iterations=20, seed=2)
    assert seen and not any(seen)
    assert gc.isenabled()
