"""All swarms of a call are one compiled program; equal shapes never compile again."""

import importlib

import jax
import numpy as np

from swarmcurves_jax import compile_cache, design_matrix, fit, make_knots
from swarmcurves_jax.datasets import analytic_points


def test_mixed_degrees_and_counts_compile_one_program_once(compiles_during):
    u = np.linspace(0, 1, 120)
    pts = design_matrix(u, make_knots(6, 3, False), 3) @ np.random.default_rng(0).uniform(
        -1, 1, (6, 2)
    )
    # the swarm's program is what is counted (the polish's: the test below)
    kwargs = dict(cps=range(4, 9), degrees=(1, 2, 3), iterations=40, chunk_size=20, refine=False)
    first = compiles_during(lambda: fit(pts, **kwargs))
    assert sum("swarm_program" in m for m in first) == 1  # 15 swarms, one swarm program
    second = compiles_during(lambda: fit(pts + 1.0, seed=5, **kwargs))
    assert second == []  # same shapes: nothing at all is compiled again


def test_a_call_of_the_same_kind_compiles_nothing(compiles_during):
    """What varies from call to call on the same kind of data compiles nothing: the seed,
    the values, the iteration count (the program skips the steps past it), ``tol``, and
    the point count within a bucket (146 and 150 points are both padded to 160)."""
    u = np.linspace(0, 1, 150)
    coef = np.random.default_rng(1).uniform(-1, 1, (6, 2))
    pts = design_matrix(u, make_knots(6, 3, False), 3) @ coef
    kwargs = dict(cps=range(4, 7), degrees=(2, 3), particles=16)
    first = compiles_during(lambda: fit(pts, iterations=60, **kwargs))
    assert sum("swarm_program" in m for m in first) == 1
    assert sum("polish_program" in m for m in first) == 1  # made early, in a thread, once
    fewer = np.linspace(0, 1, 146)
    again = {
        "seed": lambda: fit(pts, iterations=60, seed=7, **kwargs),
        "values": lambda: fit(pts * 3.0 + 1.0, iterations=60, **kwargs),
        "iterations": lambda: fit(pts, iterations=45, **kwargs),
        "more iterations": lambda: fit(pts, iterations=250, **kwargs),
        "tol": lambda: fit(pts, iterations=60, tol=1e-4, **kwargs),
        "points": lambda: fit(
            design_matrix(fewer, make_knots(6, 3, False), 3) @ coef, iterations=60, **kwargs
        ),
    }
    for name, call in again.items():
        assert compiles_during(call) == [], name


def test_a_new_bucket_within_the_polish_length_compiles_only_the_swarm(compiles_during):
    """180 and 200 points run the swarm in buckets of 192 and 208, the polish in one of 256
    (``prepare.polish_length``): the second count compiles a swarm program, and the polish
    it needs is the one the first made."""
    kwargs = dict(cps=range(4, 7), particles=16, iterations=40, chunk_size=20, seed=1)
    first = compiles_during(lambda: fit(analytic_points("f4", 200), **kwargs))
    assert sum("polish_program" in m for m in first) == 1
    second = compiles_during(lambda: fit(analytic_points("f1", 180), **kwargs))
    assert sum("swarm_program" in m for m in second) == 1
    assert not any("polish_program" in m for m in second), second


def test_random_keys_draws_and_the_data_polyline_are_made_on_the_host(tmp_path, compiles_during):
    """The call compiles the swarm and the polish alone.  The initial draws (threefry) are
    made on the host (:mod:`swarmcurves_jax.draws`): compiled into every swarm program they
    cost each about 1 s, as a program of their own 0.5 CPU-s per shape.  So is the data
    polyline (``excursions.data_segments``, the only user of ``tan`` and ``acos``):
    compiled into the swarm and the polish, it cost 0.5 CPU-s."""
    u = np.linspace(0, 1, 80)
    pts = np.c_[u, np.sin(3 * u)]
    jax.config.update("jax_dump_ir_to", str(tmp_path))
    try:
        first = compiles_during(
            lambda: fit(pts, cps=range(4, 7), degrees=(2, 3), iterations=20, seed=3)
        )
    finally:
        jax.config.update("jax_dump_ir_to", "")
    assert sorted(m.split()[4] for m in first) == ["jit(polish_program)", "jit(swarm_program)"]
    programs = {p.name: p.read_text() for p in tmp_path.glob("*.mlir")}
    swarm = [text for name, text in programs.items() if "swarm_program" in name]
    polish = [text for name, text in programs.items() if "polish_program" in name]
    assert swarm and polish
    for text in swarm + polish:
        assert "threefry2x32" not in text
        assert ".tan " not in text and ".acos " not in text


class _LowerFor:
    """A jitted program that also lowers each new trace for ``platform``, keeping the text."""

    def __init__(self, jitted, platform, texts):
        self.jitted, self.platform, self.texts, self.seen = jitted, platform, texts, set()

    def trace(self, *args, **kwargs):
        traced = self.jitted.trace(*args, **kwargs)
        shapes = str(jax.tree_util.tree_map(np.shape, (args, kwargs)))
        if shapes not in self.seen:
            self.seen.add(shapes)
            self.texts.append(traced.lower(lowering_platforms=(self.platform,)).as_text())
        return traced

    def __call__(self, *args, **kwargs):
        self.trace(*args, **kwargs)
        return self.jitted(*args, **kwargs)


def test_the_programs_a_gpu_runs_lower_for_cuda(monkeypatch):
    """No GPU in CI: ``fit`` builds its programs as it would on a GPU (JAX's default backend
    says "gpu": one device, the search fused into the Newton loop) and each lowers for CUDA,
    with every matrix product in float32 (XLA:GPU's default is TF32, which undercut the
    true distance on an H100, ``span_basis.PRECISION``).  They run on the CPU here."""
    launch_module = importlib.import_module("swarmcurves_jax.launch")
    u = np.linspace(0, 1, 60)
    pts = np.c_[u, np.sin(3 * u)]
    kwargs = dict(cps=(5, 6), degrees=(1, 3), particles=8, iterations=10)

    def lowered(backend, platform, refine):
        names = ("swarm_program",) + ("polish_program",) * refine
        texts = {name: [] for name in names}
        programs = [getattr(launch_module, name) for name in texts]
        try:
            with monkeypatch.context() as patch:
                patch.setattr(jax, "default_backend", lambda: backend)
                # The programs as traced here, not exported ones read from the cache.
                patch.setattr(compile_cache, "cache_dir", lambda: None)
                for program, found in zip(programs, texts.values()):
                    patch.setattr(
                        launch_module, program.__name__, _LowerFor(program, platform, found)
                    )
                result = fit(pts, refine=refine, **kwargs)
        finally:  # the backend is read while tracing: no trace made here may be reused
            for program in programs:
                program.clear_cache()
        assert all(texts.values()), texts
        return result, {name: "\n".join(found) for name, found in texts.items()}

    gpu, cuda = lowered("gpu", "cuda", refine=True)
    cpu, host = lowered("cpu", "cpu", refine=False)
    # Refined, the GPU's curves are no worse than the CPU's swarm alone.
    assert all(g.error <= c.error * (1 + 1e-5) for g, c in zip(gpu.solutions, cpu.solutions))
    for text in cuda.values():
        dots = [line for line in text.splitlines() if "dot_general" in line]
        assert all("precision = [HIGHEST, HIGHEST]" in line for line in dots), dots
    # The CPU's swarm runs the search in a branch of its own; a GPU's keeps it fused.
    assert "stablehlo.case" in host["swarm_program"]
    assert "stablehlo.case" not in cuda["swarm_program"]
    assert cuda["swarm_program"].count("dot_general") >= 4
