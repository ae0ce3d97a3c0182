"""All swarms of a call are one compiled program; equal shapes never compile again."""

import logging

import jax
import numpy as np

from swarmcurves_jax import design_matrix, fit, make_knots
from swarmcurves_jax.fit import _swarm_program


class _Count(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names = []

    def emit(self, record):
        msg = record.getMessage()
        if "Compiling" in msg or "compiling" in msg:
            self.names.append(msg)


def compiles_during(fn):
    handler = _Count()
    logger = logging.getLogger("jax")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles(True):
            fn()
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
    return handler.names


def test_mixed_degrees_and_counts_compile_one_program_once():
    u = np.linspace(0, 1, 120)
    pts = design_matrix(u, make_knots(6, 3, False), 3) @ np.random.default_rng(0).uniform(
        -1, 1, (6, 2)
    )
    before = _swarm_program._cache_size()
    kwargs = dict(cps=range(4, 9), degrees=(1, 2, 3), iterations=40, chunk_size=20)
    first = compiles_during(lambda: fit(pts, **kwargs))
    assert _swarm_program._cache_size() == before + 1  # 15 swarms, one swarm program
    assert sum("_swarm_program" in m for m in first) == 1
    second = compiles_during(lambda: fit(pts + 1.0, seed=5, **kwargs))
    assert second == []  # same shapes: nothing at all is compiled again


def test_random_keys_and_draws_compile_apart(tmp_path):
    """The initial draws are a small program of their own (``fit._initial_draws``, compiled
    once per shape): threefry compiled into every swarm program cost each about 1 s."""
    u = np.linspace(0, 1, 80)
    pts = np.c_[u, np.sin(3 * u)]
    jax.config.update("jax_dump_ir_to", str(tmp_path))
    try:
        first = compiles_during(
            lambda: fit(pts, cps=range(4, 7), degrees=(2, 3), iterations=20, seed=3, refine=False)
        )
    finally:
        jax.config.update("jax_dump_ir_to", "")
    assert sum("_initial_draws" in m for m in first) == 1
    programs = {p.name: p.read_text() for p in tmp_path.glob("*.mlir")}
    swarm = [text for name, text in programs.items() if "_swarm_program" in name]
    draws = [text for name, text in programs.items() if "_initial_draws" in name]
    assert swarm and draws
    assert all("threefry2x32" not in text for text in swarm)
    assert all("threefry2x32" in text for text in draws)
