"""Compiled programs are kept across processes by default, read back, and a damaged entry
costs a compilation, not the fit."""

import json
import os
import subprocess
import sys
import textwrap

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


#: A call of every program kind: the draws, the swarm and the polish.
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
    assert {"jit_swarm_program", "jit_polish_program", "jit_initial_draws"} <= set(
        entries(folder)
    )
    other = tmp_path / "other"
    second, _ = run_fresh({"JAX_COMPILATION_CACHE_DIR": str(folder)}, other)
    assert second["folder"] == str(folder) and not (other / "home-cache").exists()
    assert second["hits"] >= 3  # the draws, the swarm and the polish
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
